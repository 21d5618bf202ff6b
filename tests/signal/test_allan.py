"""Allan deviation against closed forms: white rate noise (ADEV = sigma / sqrt(tau fs)) and a discrete
random walk (AVAR = q^2 (2 m^2 + 1) / (6 m), slope +1/2)."""
import numpy as np
import pytest

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
