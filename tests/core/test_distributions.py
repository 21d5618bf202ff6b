"""calib.core.distributions against scipy.stats, the implementation it stands in for: the same numbers to the last
bit over the statistics and degrees of freedom the diagnosis and the calibration meet (chi-square tests of a few
to ~10^4 degrees of freedom, p-values down to the underflow, one-sided F tests), and 1 below the support."""
import numpy as np
from scipy import stats

from calib.core import distributions


def test_chi2_sf_is_scipy_stats_to_the_bit():
    x = np.concatenate([[0.0, 1e-12, 0.5, 1.0], np.logspace(-3, 4, 57), [2e3, 5e3, 1e4, 3e4]])
    for df in (0.5, 1, 2, 3, 4.5, 9, 24, 71.3, 340, 2299, 10_000):
        for v in x:
            got, want = distributions.chi2_sf(float(v), df), float(stats.chi2.sf(v, df))
            assert got == want, (v, df, got, want)
    assert distributions.chi2_sf(-1e-9, 3) == 1.0 and distributions.chi2_sf(-5.0, 1) == 1.0


def test_f_sf_is_scipy_stats_to_the_bit():
    for dfn, dfd in ((1, 1), (2, 10), (3, 7), (12, 40), (100, 300), (2.5, 9.5)):
        for v in np.concatenate([[0.0, 1e-9], np.logspace(-3, 3, 41)]):
            got, want = distributions.f_sf(float(v), dfn, dfd), float(stats.f.sf(v, dfn, dfd))
            assert got == want, (v, dfn, dfd, got, want)
    assert distributions.f_sf(-0.1, 3, 7) == 1.0
