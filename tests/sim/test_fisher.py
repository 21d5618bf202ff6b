"""Fisher bounds of the generative model (calib.sim.fisher) against closed forms: white noise, a Gauss-Markov
bias, and a parameter no session can tell from the scale factors (a wrong local g)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from calib.sim import effects as sim_effects
from calib.sim import fisher
from calib.sim.calibration_session import build_calibration_simulator
from calib.sim.counts_engine import temperature_profile

SHORT = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1, "conceal": True}


def _sim(**noise):
    base = {"accel_vrw_ug_rthz": 10.0, "accel_bias_instability_ug": 0.0, "accel_bias_corr_time_s": 300.0,
            "gyro_arw_deg_rth": 0.002, "gyro_bias_instability_deg_h": 0.0, "gyro_bias_corr_time_s": 600.0,
            "bias_model": "gauss_markov", "quantize": False}
    base.update(noise)
    K = SimpleNamespace(K=np.array([1000.0, 1100.0, 1200.0]))
    return SimpleNamespace(sample_rate_hz=100.0, noise=base, accel=K, gyro=SimpleNamespace(K=np.full(3, 500.0)))


def test_white_noise_information_is_the_sum_of_squares():
    sim = _sim()
    n = 4000
    rng = np.random.default_rng(3)
    d = np.zeros((n, 6))
    d[:, 1] = rng.standard_normal(n)
    J = fisher.information([d], fisher.noise_spectrum(sim, n))
    sigma = 1100.0 * 10e-6 * math.sqrt(0.01)       # K sigma_w per sample [count]
    assert abs(J[0, 0] / (d[:, 1] @ d[:, 1] / sigma ** 2) - 1.0) < 1e-10


def test_gauss_markov_information_of_a_constant_matches_the_ar1_closed_form():
    """For an AR(1) noise with coefficient a and innovation variance s2, 1' Sigma^-1 1 = (2 (1 - a) + (n - 2)
    (1 - a)^2) / s2 (exact); Whittle's approximation drops the end terms, O(1/n)."""
    sim = _sim(accel_vrw_ug_rthz=0.0, accel_bias_instability_ug=5.0, accel_bias_corr_time_s=0.5)
    n = 20000
    d = np.zeros((n, 6))
    d[:, 0] = 1.0
    J = fisher.information([d], fisher.noise_spectrum(sim, n))[0, 0]
    a = math.exp(-0.01 / 0.5)
    s2 = (1000.0 * 0.01 * 5e-6) ** 2 * (1.0 - a * a)
    exact = (2.0 * (1.0 - a) + (n - 2) * (1.0 - a) ** 2) / s2
    assert abs(J / exact - 1.0) < 5.0 / n * (1.0 + a) / (1.0 - a)


def test_a_wrong_local_g_is_not_determined_but_a_quadratic_nonlinearity_is():
    """A wrong g scales every accelerometer input alike, which the scale factors absorb exactly: no session
    determines it (seed 000's norm cannot either). A quadratic nonlinearity is determined on this path."""
    cfg = {**SHORT, "effects": {}}
    b = fisher.bounds(cfg, "gravity_error", {"delta_g_m_s2": 5e-4})
    assert b == {"delta_g_m_s2": None}
    q = fisher.bounds(cfg, "accel_quadratic_nonlinearity")
    assert set(q) == {"k2_ug_per_g2[x]", "k2_ug_per_g2[y]", "k2_ug_per_g2[z]"}
    assert all(v is not None and 0.0 < v < 50.0 for v in q.values())
    # holding parameters at their truth can only tighten a bound
    J, names = fisher.information_for(cfg, "accel_quadratic_nonlinearity")
    one = fisher.bounds_from(J, names, free={"k2_ug_per_g2[x]"})
    assert set(one) == {"k2_ug_per_g2[x]"} and one["k2_ug_per_g2[x]"] <= q["k2_ug_per_g2[x]"] * (1 + 1e-12)


def test_derivatives_of_the_affine_effects_are_the_central_differences(monkeypatch):
    """The physical path is affine in every size parameter of one effect (all but the clock offset), so the
    derivative columns taken as one difference from zero equal the central differences at the true values."""
    sim = build_calibration_simulator({**SHORT, "effects": {}}, 0)
    clean = sim.clean_increments()
    temp = temperature_profile((np.arange(len(clean)) + 0.5) / sim.sample_rate_hz, sim.temperature)
    for eid in ("accel_lever_arm", "accel_scale_asymmetry", "gyro_scale_nonlinearity"):  # kinematics, transfer, rate
        assert eid in fisher.AFFINE_EFFECTS
        params = {k: v for k, v in sim_effects.resolve({eid: {}})[eid].items() if k != "enabled"}
        n1, c1 = fisher._effect_columns({}, sim, clean, eid, params, temp)
        with monkeypatch.context() as m:
            m.setattr(fisher, "AFFINE_EFFECTS", frozenset())
            n2, c2 = fisher._effect_columns({}, sim, clean, eid, params, temp)
        assert n1 == n2 and n1
        for a, b in zip(c1, c2):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-6 * np.abs(b).max())


def test_kept_nuisance_spectra_give_the_information_of_all_columns():
    """The base model's nuisance columns, kept as spectra for the sessions that share a noise-free signal, give the
    same information matrix as all columns transformed together."""
    sim = build_calibration_simulator({**SHORT, "effects": {}}, 0)
    clean = sim.clean_increments()
    n = len(clean)
    e = np.zeros((n, 6))
    e[:, 1] = np.sin(np.arange(n) / 500.0)
    e[:, 4] = np.arange(n) / n
    _, ncols = fisher._nuisance_columns(sim, clean)
    S = fisher.noise_spectrum(sim, n)
    J_all = fisher.information([e] + ncols, S)
    J_kept = fisher.information([e], S, fixed=fisher._nuisance_spectra(sim, clean))
    np.testing.assert_allclose(J_kept, J_all, rtol=1e-10, atol=1e-12 * np.abs(J_all).max())
    assert fisher._nuisance_spectra(sim, clean.copy()) is fisher._nuisance_spectra(sim, clean)   # kept by content
