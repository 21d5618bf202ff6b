"""The proof's efficiency bounds: the exact stream information and the information of the diagnosis's window
reductions against dense linear algebra on the noise covariance written out sample by sample."""
import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats
from scipy.linalg import toeplitz

from calib.diagnosis.geometry import Window
from calib.sim import fisher
from calib.studies import diagnosis_efficiency as de


def _sim(quantize=True, bias_model="gauss_markov", tc=(3.0, 5.0), rate=10.0):
    """A unit small enough for dense matrices: K of a few counts per input unit, a bias correlation time of a few
    dozen samples (so that it spans windows and the session's ends)."""
    noise = {"accel_vrw_ug_rthz": 2e5, "accel_bias_instability_ug": 3e5, "accel_bias_corr_time_s": tc[0],
             "gyro_arw_deg_rth": 0.5, "gyro_bias_instability_deg_h": 40.0, "gyro_bias_corr_time_s": tc[1],
             "bias_model": bias_model, "quantize": quantize}
    return SimpleNamespace(noise=noise, sample_rate_hz=rate, accel=SimpleNamespace(K=np.array([3.0, 4.0, 5.0])),
                           gyro=SimpleNamespace(K=np.array([0.5, 0.6, 0.7])))


def _dense_cov(sim, c, n):
    """Sigma of channel c written out: white + carried remainder (1/6, -1/12) + v a^|i-j|."""
    dt = 1.0 / sim.sample_rate_hz
    sig_w, sig_b, tau = fisher.noise_terms(sim.noise, dt)
    K = np.concatenate([sim.accel.K, sim.gyro.K])
    acf = np.zeros(n)
    acf[0] = (K[c] * sig_w[c]) ** 2
    if sim.noise["quantize"]:
        acf[0] += 1.0 / 6.0
        acf[1] -= 1.0 / 12.0
    acf += (K[c] * dt * sig_b[c]) ** 2 * math.exp(-dt / tau[c]) ** np.arange(n)
    return toeplitz(acf)


def _columns(n, rng):
    t = np.arange(n) / n
    slow = np.exp(-3.0 * t)                        # as slow as the session: a warm-up
    cols = []
    for shape in (slow, np.sin(40 * t), rng.standard_normal(n), np.ones(n)):
        d = np.zeros((n, 6))
        d[:, 0] = shape
        d[:, 4] = 0.5 * shape + 0.1
        cols.append(d)
    return cols


@pytest.mark.parametrize("quantize", [True, False])
def test_exact_information_is_the_dense_gaussian_information(quantize):
    rng = np.random.default_rng(1)
    n = 300
    sim = _sim(quantize)
    cols = _columns(n, rng)
    J = fisher.information_exact(cols, sim)
    ref = np.zeros_like(J)
    for c in range(6):
        D = np.stack([x[:, c] for x in cols], axis=1)
        ref += D.T @ np.linalg.solve(_dense_cov(sim, c, n), D)
    np.testing.assert_allclose(J, ref, rtol=1e-8, atol=1e-10 * np.abs(ref).max())


def test_whittle_overstates_a_slow_signal_the_exact_form_does_not():
    """Why the proof's stream bound is the exact one: the periodic (Whittle) form credits a warm-up-like column
    (next to a bias) with information the finite session does not hold, while it is right for a fast one."""
    n = 300
    sim = _sim(tc=(10.0, 10.0))
    t = np.arange(n) / n
    bias = np.zeros((n, 6))
    bias[:, 0] = 1.0
    ratio = {}
    for label, shape in (("slow", np.exp(-3.0 * t)), ("fast", np.sin(2 * np.pi * 60 * t))):
        d = np.zeros((n, 6))
        d[:, 0] = shape
        Je = fisher.information_exact([d, bias], sim)
        Jw = fisher.information([d, bias], fisher.noise_spectrum(sim, n))
        ratio[label] = fisher.bounds_from(Je, ["a"])["a"] / fisher.bounds_from(Jw, ["a"])["a"]
    assert ratio["slow"] > 1.5
    assert ratio["fast"] == pytest.approx(1.0, abs=0.05)


def _windows(n):
    """Static-like means, a window with three rows and two adjacent windows (sharing a carried remainder)."""
    out = []
    for i0, i1, r in ((5, 60, 1), (80, 170, 3), (170, 200, 1), (230, 295, 1)):
        w = Window("static" if r == 1 else "rotation", "", 0, i0, i1)
        m = i1 - i0
        th = np.linspace(0, 4 * np.pi, m)
        X = np.column_stack([np.ones(m), np.cos(th), np.sin(th)])[:, :r]
        w.W = X @ np.linalg.inv(X.T @ X)
        out.append(w)
    return SimpleNamespace(windows=out)


@pytest.mark.parametrize("quantize", [True, False])
def test_reduction_covariance_and_information_match_dense_algebra(quantize):
    rng = np.random.default_rng(2)
    n = 300
    sim = _sim(quantize)
    geom = _windows(n)
    cols = _columns(n, rng)
    J = de.reduced_information(cols, sim, geom)
    ref = np.zeros_like(J)
    for c in range(6):
        sensor = "accel" if c < 3 else "gyro"
        W = []
        for w in geom.windows:
            for q in range(1 if sensor == "accel" else w.W.shape[1]):
                v = np.zeros(n)
                v[w.i0:w.i1] = w.W[:, q]
                W.append(v)
        W = np.array(W).T
        D = np.stack([x[:, c] for x in cols], axis=1)
        Sr = W.T @ _dense_cov(sim, c, n) @ W
        ref += (W.T @ D).T @ np.linalg.solve(Sr, W.T @ D)
    np.testing.assert_allclose(J, ref, rtol=1e-8, atol=1e-10 * np.abs(ref).max())


def test_single_sample_windows_hold_the_whole_stream():
    """Windows of one sample each over the whole session are the stream itself: the same information."""
    rng = np.random.default_rng(3)
    n = 120
    sim = _sim()
    wins = []
    for i in range(n):
        w = Window("static", "", 0, i, i + 1)
        w.W = np.ones((1, 1))
        wins.append(w)
    cols = _columns(n, rng)
    np.testing.assert_allclose(de.reduced_information(cols, sim, SimpleNamespace(windows=wins)),
                               fisher.information_exact(cols, sim), rtol=1e-8)


def test_random_walk_bias_has_no_exact_form():
    sim = _sim(bias_model="random_walk")
    cols = _columns(50, np.random.default_rng(4))
    assert fisher.information_exact(cols, sim) is None
    assert de.reduced_information(cols, sim, _windows(50)) is None


def test_fisher_detection_scale_is_the_noncentral_chi_square_quantile():
    """One parameter with bound sigma and no nuisance: detected with 80 % power where the noncentral chi-square
    (1 dof, noncentrality (s theta / sigma)^2) exceeds the acceptance threshold with probability 0.8."""
    sigma, theta, n_obs, alpha, mdb = 0.5, 2.0, 360, 1e-3, 2.0
    s = de.fisher_detection_scale(np.array([[1.0 / sigma ** 2]]), ["a"], {"a": theta}, n_obs, alpha, mdb)
    thr = max(math.log(n_obs) + mdb, stats.chi2.isf(alpha, 1))
    assert stats.ncx2.sf(thr, 1, (s * theta / sigma) ** 2) == pytest.approx(0.8, abs=1e-9)
    assert de.fisher_detection_scale(np.array([[1.0]]), ["a"], {"a": 0.0}, n_obs, alpha, mdb) is None


def test_why_above_2_names_the_reduction_loss_and_the_fit():
    assert de.why_above_2("time_offset", "offset_s", 1.9, 1.0, 1.0, 1.5, 1.2) is None
    txt = de.why_above_2("time_offset", "offset_s", 1000.0, 1e-7, 1e-7, 1e-4, 1.0)
    assert "1e+03 x the stream's" in txt and "ramps" in txt and "efficient on the observations" in txt
    assert "Whittle" not in txt
    txt = de.why_above_2("accel_scale_asymmetry", "asym_ppm[x]", 3.0, 1.0, 1.0, 1.1, 2.7)
    assert "1.1 x the stream's" in txt and "unused" in txt
    txt = de.why_above_2("bias_drift", "accel_warmup_ug[x]", 2.2, 1.0, 2.0, 2.1, 1.05)
    assert "2 x Whittle's" in txt and "1.05 x the stream's" in txt


def test_extended_windows_cover_every_sample_once():
    """The extended reduction: the diagnosis's windows and short means of every sample outside them, each sample in
    exactly one window, in time order."""
    n, dt = 300, 0.1
    geom = _windows(n)
    geom.n_samples, geom.dt = n, dt
    ext = de.extended_windows(geom, mean_s=0.5)
    count = np.zeros(n, int)
    for w in ext.windows:
        count[w.i0:w.i1] += 1
        assert w.W.shape[0] == w.n
        if w.kind == "outside":
            assert w.n <= 5 and np.allclose(w.W, 1.0 / w.n)
    assert np.all(count == 1)
    assert [w.i0 for w in ext.windows] == sorted(w.i0 for w in ext.windows)


def test_why_above_2_says_what_the_outside_samples_would_bring():
    txt = de.why_above_2("time_offset", "offset_s", 1000.0, 1e-7, 1e-7, 1e-4, 1.0, extended=1.02e-7)
    assert "0.5-s means would bring it to 1.02 x" in txt
