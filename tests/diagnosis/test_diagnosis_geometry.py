"""Windows, observations and the base-model design of the diagnosis (calib.diagnosis.geometry), against a
noise-free simulator session: the true K E, b of the simulated unit reproduce every observation; the
Gauss-Markov covariance of its window means (calib.diagnosis.noise) against the double integral."""
from __future__ import annotations

import numpy as np
import pytest

from calib.diagnosis import geometry, noise
from calib.io import recording
from calib.sim.calibration_session import simulate_calibration_session
from calib.sim.settings import sensor_models

SHORT = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}


def test_geometry_whole_revolutions_and_noise_free_base_model(tmp_path):
    """Noise-free session: windows span whole revolutions (table angle at sample mid-times) and the base model
    with the true K E, b reproduces every observation (mean, cos, sin) to the sample-averaging attenuation
    of the harmonics (sinc of half the angle step, < 2e-6 relative)."""
    quiet = {"accel_vrw_ug_rthz": 0.0, "accel_bias_instability_ug": 0.0, "gyro_arw_deg_rth": 0.0,
             "gyro_bias_instability_deg_h": 0.0, "quantize": False}
    path = simulate_calibration_session({**SHORT, "noise": quiet}, 0, tmp_path / "q.nc")
    ds = recording.load(path)
    geom = geometry.build_geometry(ds)
    for w in geom.rotation:
        step = abs(w.rate_deg_s) * geom.dt
        span = abs(np.degrees(w.theta_mid[-1] - w.theta_mid[0])) + step
        assert span == pytest.approx(360.0 * w.revolutions, abs=1e-6)
    y, _ = geometry.reduce_data(geom, ds)
    xr, ones = geometry.reduced_inputs(geom)
    X = geometry.base_design(geom, xr, ones)
    a, g = sensor_models("liu2021")
    theta = np.concatenate([a.KE.ravel(), a.b, g.KE.ravel(), g.b])
    res = y - X @ theta
    scale = np.abs(y).max()
    assert np.max(np.abs(res)) < 2e-6 * scale


def test_gauss_markov_window_means_are_the_double_integral(tmp_path):
    """Covariance of two static-window means of a unit-variance Gauss-Markov bias: (1 / (T_j T_k)) times the
    double integral of exp(-|s - t| / Tc) over the two windows, here by the midpoint rule on a fine grid."""
    path = simulate_calibration_session(SHORT, 0, tmp_path / "s.nc")
    geom = geometry.build_geometry(recording.load(path))
    tc = 300.0
    A = noise.gm_part(geom, "accel", tc)
    j, k = 0, 3                                  # accel: one row (the mean) per window
    wj, wk = geom.windows[j], geom.windows[k]

    def grid(w, m=4000):
        t0, T = geom.time_s[w.i0], w.n * geom.dt
        return t0 + (np.arange(m) + 0.5) * T / m

    sj, sk = grid(wj), grid(wk)
    var_j = np.mean(np.exp(-np.abs(sj[:, None] - sj[None, :]) / tc))
    cov_jk = np.mean(np.exp(-np.abs(sj[:, None] - sk[None, :]) / tc))
    assert A[j, j] == pytest.approx(var_j, rel=1e-6)
    assert A[j, k] == pytest.approx(cov_jk, rel=1e-6) and A[k, j] == A[j, k]
