"""Allan deviation against closed forms: white rate noise (ADEV = sigma / sqrt(tau fs)) and a discrete
random walk (AVAR = q^2 (2 m^2 + 1) / (6 m), slope +1/2)."""
import numpy as np
import pytest

from calib.core import distributions
from calib.signal import allan


def test_white_noise_adev_matches_closed_form_within_ci():
    rng = np.random.default_rng(11)
    fs, sigma = 100.0, 2.0
    y = rng.normal(0.0, sigma, size=(2**17, 3))
    r = allan.adev(y, fs, confidence=0.99)
    expected = sigma / np.sqrt(r.tau * fs)
    assert r.tau[0] == pytest.approx(1.0 / fs)
    assert np.all(np.diff(np.log2(r.tau)) == pytest.approx(1.0))  # octave spacing
    inside = (r.lo <= expected[:, None]) & (expected[:, None] <= r.hi)
    assert inside.mean() >= 0.95
    # the shortest taus have > 20000 degrees of freedom (relative std < 0.5 %): tight agreement there
    assert np.all(r.edf[:4] > 20000)
    assert np.allclose(r.adev[:4] / expected[:4, None], 1.0, atol=0.02)


def test_sigma_of_mean_is_adev_at_segment_duration_for_white_noise():
    rng = np.random.default_rng(12)
    fs, sigma = 50.0, 1.5
    # 24 "static segments" of 60 s at different levels (the level must not matter), pooled
    recs = [c + rng.normal(0.0, sigma, size=(3000, 3)) for c in np.linspace(-1e4, 1e4, 24)]
    r = allan.adev_pooled(recs, fs)
    assert r.tau[-1] == pytest.approx(30.0)  # no record supports tau > T/2
    # inside the measured range: the model is the white-noise law
    assert np.allclose(r.sigma_of_mean(10.0), sigma / np.sqrt(10.0 * fs), rtol=0.08)
    # at tau = T (extrapolated one octave with the non-rising terms)
    s60 = r.sigma_of_mean(60.0)
    assert np.allclose(s60, sigma / np.sqrt(60.0 * fs), rtol=0.2)
    # and the empirical scatter of 60 s means agrees with it
    means = np.array([rr.mean(axis=0) - c for rr, c in zip(recs, np.linspace(-1e4, 1e4, 24))])
    assert np.std(means) == pytest.approx(sigma / np.sqrt(60.0 * fs), rel=0.3)


def test_sigma_of_mean_extrapolates_a_visible_random_walk():
    rng = np.random.default_rng(15)
    fs, sigma, q = 50.0, 1.5, 0.01
    recs = [rng.normal(0.0, sigma, size=(3000, 3)) + np.cumsum(rng.normal(0.0, q, size=(3000, 3)), axis=0)
            for _ in range(24)]
    r = allan.adev_pooled(recs, fs)
    m = 3000  # tau = 60 s
    exact = np.sqrt(sigma**2 / m + q**2 * (2 * m**2 + 1) / (6 * m))
    assert np.allclose(r.sigma_of_mean(60.0), exact, rtol=0.25)
    assert np.all(r.sigma_of_mean(60.0) > 3 * sigma / np.sqrt(m))  # far above the white-noise value


def test_random_walk_slope_and_level():
    rng = np.random.default_rng(13)
    fs, q = 100.0, 0.01
    y = np.cumsum(rng.normal(0.0, q, size=(2**17, 4)), axis=0)
    r = allan.adev(y, fs)
    m = r.tau * fs
    exact = np.sqrt(q**2 * (2 * m**2 + 1) / (6 * m))
    sel = r.tau <= r.tau[-1] / 16
    ratio = r.adev[sel].mean(axis=1) / exact[sel]
    assert np.all((ratio > 0.8) & (ratio < 1.25))
    big = (m >= 8) & sel
    slope = np.polyfit(np.log(r.tau[big]), np.log(r.adev[big].mean(axis=1)), 1)[0]
    assert slope == pytest.approx(0.5, abs=0.06)


def test_noise_model_recovers_white_and_random_walk_coefficients():
    rng = np.random.default_rng(14)
    fs, n_arw, k_rrw = 100.0, 0.5, 0.002  # N [unit s^0.5], K [unit s^-0.5]
    n = 2**18
    white = rng.normal(0.0, n_arw * np.sqrt(fs), size=(n, 1))
    rw = np.cumsum(rng.normal(0.0, k_rrw / np.sqrt(fs), size=(n, 1)), axis=0)
    r = allan.adev(white + rw, fs)
    m = r.noise_model()
    assert m.N[0] == pytest.approx(n_arw, rel=0.1)
    assert m.K[0] == pytest.approx(k_rrw, rel=0.35)


def test_flat_data_is_an_error():
    with pytest.raises(allan.AllanError, match="flat"):
        allan.adev(np.full((1000, 3), 7.0), 10.0)
    with pytest.raises(allan.AllanError):
        allan.adev(np.ones(2), 10.0)
    r = allan.adev(np.random.default_rng(0).normal(size=100), 10.0)
    with pytest.raises(allan.AllanError):
        r.sigma_of_mean(-1.0)


def _avar_sums_numpy(y, fs, ms):
    """The numpy implementation ``avar_sums`` had before its compiled loops (cumsum of the centred rates, one
    ``einsum`` per cluster size)."""
    y = np.asarray(y, dtype=np.float64).reshape(len(y), -1)
    n = y.shape[0]
    theta = np.zeros((n + 1, y.shape[1]))
    np.cumsum((y - y.mean(axis=0)) / fs, axis=0, out=theta[1:])
    N = n + 1
    sumsq = np.zeros((len(ms), y.shape[1]))
    nterms = np.zeros(len(ms), dtype=np.int64)
    for i, m in enumerate(ms):
        k = N - 2 * m
        if k >= 1:
            d = theta[2 * m:] - 2.0 * theta[m:N - m] + theta[:k]
            sumsq[i] = np.einsum("ij,ij->j", d, d)
            nterms[i] = k
    return sumsq, nterms


def _avar_sums_direct(y, fs, ms):
    """Eq. (2) of the module docstring in exact rational arithmetic: phase theta_k = sum_{j<k} y_j / fs, sum of the
    squared second differences (no centring: the second difference removes a constant rate exactly)."""
    from fractions import Fraction

    y = np.asarray(y, dtype=np.float64).reshape(len(y), -1)
    n, k = y.shape
    out = np.zeros((len(ms), k))
    for c in range(k):
        theta = [Fraction(0)]
        for v in y[:, c]:
            theta.append(theta[-1] + Fraction(float(v)) / Fraction(fs))
        for i, m in enumerate(ms):
            if n + 1 - 2 * m >= 1:
                out[i, c] = float(sum((theta[j + 2 * m] - 2 * theta[j + m] + theta[j]) ** 2
                                      for j in range(n + 1 - 2 * m)))
    return out


@pytest.mark.parametrize("k", [1, 2, 3, 4, 6])
def test_avar_sums_equals_the_numpy_implementation_and_the_definition(k):
    """The compiled ``avar_sums`` gives the numpy implementation's numbers to the last bit (it sums in the same
    order), for any layout of the input, and eq. (2) to rounding."""
    rng = np.random.default_rng(100 + k)
    for trial in range(6):
        n = int(rng.integers(3, 5000))
        y = rng.normal(rng.uniform(-1e6, 1e6), rng.uniform(0.1, 1e3), size=(n, k))
        if trial % 2:
            y = np.cumsum(y, axis=0)  # a random walk: large phase excursions
        if trial == 2:
            y = np.round(y)  # counts
        ms = np.concatenate([allan.octave_clusters(n), [n // 2 + 1, n, n + 3]]).astype(np.int64)
        for yy in (y, np.asfortranarray(y), y[::-1][::2], y[:, ::-1]):
            s, c = allan.avar_sums(yy, 100.0, ms)
            s0, c0 = _avar_sums_numpy(yy, 100.0, ms)
            np.testing.assert_array_equal(c, c0)
            np.testing.assert_array_equal(s, s0)
        s, c = allan.avar_sums(y, 100.0, ms)
        assert np.array_equal(c, np.maximum(n + 1 - 2 * ms, 0))
    # eq. (2) exactly, on records whose level is comparable to their noise (centring in floating point costs
    # eps x level / noise of relative accuracy, in either implementation)
    for trial in range(3):
        n = int(rng.integers(3, 300))
        y = rng.normal(rng.uniform(-3.0, 3.0), 1.0, size=(n, k)) * 10.0 ** rng.integers(-3, 6)
        if trial == 1:
            y = np.cumsum(y, axis=0)
        ms = np.concatenate([allan.octave_clusters(n), [n // 2 + 1, n]]).astype(np.int64)
        s, c = allan.avar_sums(y, 100.0, ms)
        ok = c > 0
        np.testing.assert_allclose(s[ok], _avar_sums_direct(y, 100.0, ms)[ok], rtol=1e-12)
    y1d = rng.normal(size=1000)
    np.testing.assert_array_equal(allan.avar_sums(y1d, 10.0, [1, 4])[0], _avar_sums_numpy(y1d, 10.0, [1, 4])[0])


def test_avar_sums_of_a_long_triad_record_is_the_numpy_result():
    """A 2 h triad record at 100 Hz of pulse counts (the z-score study's long static record): same bits."""
    rng = np.random.default_rng(7)
    y = np.floor(np.cumsum(rng.normal(0.0, 3.0, size=(720_000, 3)), axis=0) * 0.01 + rng.random((720_000, 3)))
    y = (np.diff(y, axis=0, prepend=0.0) + 2.0e6) * 100.0
    ms = allan.octave_clusters(len(y))
    s, c = allan.avar_sums(y, 100.0, ms)
    s0, c0 = _avar_sums_numpy(y, 100.0, ms)
    np.testing.assert_array_equal(c, c0)
    np.testing.assert_array_equal(s, s0)


def test_chi2_quantiles_are_scipy_stats_to_the_bit():
    """The confidence intervals use scipy.stats.chi2.ppf's own special function without importing scipy.stats: the
    same numbers to the last bit over the degrees of freedom the estimators give (edf_white, a few samples to a
    240 h record at every octave cluster) and the quantiles of the 68/90/95/99 % intervals."""
    from scipy import stats

    N = np.array([5, 7, 16, 33, 100, 601, 6001, 360001, 86_400_001], dtype=float)
    m = 2.0 ** np.arange(0, 26)
    edf = allan.edf_white(N[:, None], m[None, :]).ravel()
    edf = np.concatenate([edf, [1.0, 1.5, 2.0, 3.7, 1e3, 1e6]])
    for conf in (0.68, 0.90, 0.95, 0.99):
        a = 1.0 - conf
        for q in (a / 2.0, 1.0 - a / 2.0):
            assert np.array_equal(distributions.chi2_ppf(q, edf), stats.chi2.ppf(q, edf))


# an AVAR curve dominated by the rate ramp (six decades over eleven octaves), with the weights of the noise-model fit:
# scipy's NNLS stops at its default iteration limit (3 per unknown) on all five terms of eq. (4)
RAMP_AVAR = np.array([4.359831914074004e-07, 1.023874884415979e-06, 5.531561912756206e-06, 1.2432195905469483e-05,
                      4.849817306550437e-05, 0.0003175007319624079, 0.0013544398813521528, 0.0037158885170477407,
                      0.02141087815713679, 0.054163801777238486, 0.32171505102747755, 1.174881897222426])
RAMP_TAU = 0.02 * 2.0 ** np.arange(12)
RAMP_EDF = np.linspace(1000.0, 2.0, 12)


def _exact_nnls(M, v):
    """The NNLS minimiser by its definition: the least-residual least-squares solution, over every support, whose
    coefficients are all positive (the optimum is the unconstrained solution on its own support)."""
    import itertools

    best = (float(v @ v), np.zeros(M.shape[1]))
    for k in range(1, M.shape[1] + 1):
        for S in itertools.combinations(range(M.shape[1]), k):
            cs = np.linalg.lstsq(M[:, S], v, rcond=None)[0]
            if np.all(cs > 0):
                c = np.zeros(M.shape[1])
                c[list(S)] = cs
                r = float(np.sum((M @ c - v) ** 2))
                if r < best[0]:
                    best = (r, c)
    return best[1]


def test_nnls_reaches_the_optimum_where_the_default_iteration_limit_stops():
    from scipy import optimize

    w = np.sqrt(RAMP_EDF / 2.0) / RAMP_AVAR
    M, v = allan._basis(RAMP_TAU) * w[:, None], RAMP_AVAR * w
    with pytest.raises(RuntimeError):   # the case is the hard one: scipy's default limit stops short here
        optimize.nnls(M, v)
    c, exact = allan.nnls(M, v), _exact_nnls(M, v)
    assert np.all(c >= 0)
    np.testing.assert_allclose(c, exact, rtol=1e-6, atol=1e-12 * np.abs(exact).max())
    assert np.sum((M @ c - v) ** 2) <= np.sum((M @ exact - v) ** 2) * (1 + 1e-9)
    # and the whole noise-model fit of that curve: finite, non-negative terms, the ramp R the largest contribution
    # at the longest tau (the curve climbs as tau^2 there)
    a = np.sqrt(RAMP_AVAR)[:, None]
    res = allan.AllanResult(tau=RAMP_TAU, adev=a, lo=a, hi=a, edf=RAMP_EDF, nterms=np.ones(12), fs=50.0,
                            confidence=0.95)
    m = res.noise_model()
    terms = allan._basis(RAMP_TAU[-1:])[0] * np.array([m.Q[0], m.N[0], m.B[0], m.K[0], m.R[0]]) ** 2
    assert np.all(np.isfinite(terms)) and np.all(terms >= 0) and np.argmax(terms) == 4
