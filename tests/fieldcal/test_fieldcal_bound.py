"""The Cramér–Rao bound beside a field calibration's parameters (:mod:`calib.fieldcal.bound`): the closed form of a
static bias (noise density / sqrt(T)), and the spread of the accel fit over noise seeds on a synthetic recording
with known noise against the bound computed from one seed's poses and measured noise."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from calib import fieldcal
from calib.fieldcal import bound as fb
from calib.fieldcal.accelerometer import accel_matrix, fit_accel_norm
from calib.fieldcal.results import BIAS_NAMES, GYRO_NAMES
from calib.io import recording

FS = 100.0


def test_static_bias_bound_is_noise_density_over_sqrt_time():
    """A constant gyro bias from the mean of the static samples: sigma = N / sqrt(T) with the noise density
    N = sigma_sample sqrt(dt) and T the static time; the bound from the measured noise is that within the
    accuracy of the measured sigma (1 / sqrt(2 n) = 0.7 %), and the mean's spread over 400 seeds matches it."""
    sigma, n_iv, n_per = 2e-3, 10, 500
    iv = np.array([[k * 1000, k * 1000 + n_per] for k in range(n_iv)])
    fit = SimpleNamespace(names=GYRO_NAMES + BIAS_NAMES)
    density = sigma * math.sqrt(1.0 / FS)                     # rad s-1 / sqrt(Hz)
    expect = density / math.sqrt(n_iv * n_per / FS)          # T = 50 s of static samples
    est = []
    for k in range(400):
        g = np.random.default_rng([5, k]).standard_normal((n_iv * 1000, 3)) * sigma + [0.01, -0.02, 0.003]
        if k == 0:
            out = fb.gyro_offset_bound(fit, g, None, iv, "statics")
        est.append(np.concatenate([g[a:b] for a, b in iv]).mean(axis=0))
    got = np.array([out["sigma"][n] for n in BIAS_NAMES])
    assert np.allclose(got, expect, rtol=0.03)
    assert np.all(np.abs(np.std(est, axis=0, ddof=1) / got - 1.0) < 0.15)
    # the direction fit's parameters get no number, and say why
    assert all(out["sigma"][n] is None and "not bounded" in out["why_none"][n] for n in GYRO_NAMES)


def test_accel_fit_spread_over_seeds_matches_the_bound():
    """Synthetic static intervals with known T_a K_a, b and white noise: the gravity-norm fit over 200 seeds
    scatters as the bound computed from one seed's fit, poses and measured noise says (within 20 %: the std of a
    std over 200 seeds is 5 %)."""
    rng = np.random.default_rng(1)
    g, sigma, n_per = 9.81, 0.02, 150
    p_true = np.array([2e-3, -1e-3, 1.5e-3, 1.01, 0.99, 1.005, 0.05, -0.03, 0.08])
    u = rng.standard_normal((16, 3))
    x = g * u / np.linalg.norm(u, axis=1, keepdims=True)
    clean = x @ np.linalg.inv(accel_matrix(p_true)).T + p_true[6:9]
    iv = np.column_stack([np.arange(16) * n_per, np.arange(1, 17) * n_per])
    est = []
    for k in range(200):
        a = np.repeat(clean, n_per, axis=0) + sigma * np.random.default_rng([9, k]).standard_normal((16 * n_per, 3))
        f = fit_accel_norm(a, iv, g, input_units="m s-2")
        if k == 0:
            crb = fb.accel_bound(f, a, iv, g)
        est.append(f.values)
    assert not crb["why_none"] and crb["held_at_nominal"] == []
    assert np.allclose(crb["noise_sigma_per_sample"], sigma, rtol=0.05)
    bound = np.array([crb["sigma"][n] for n in f.names])
    ratio = np.std(est, axis=0, ddof=1) / bound
    assert np.all(np.abs(ratio - 1.0) < 0.2), dict(zip(f.names, ratio.round(3)))


def test_fieldcal_report_holds_the_bounds(synthetic_session):
    """``calib fieldcal``'s report (the result's summary) gives sigma_crb beside the accel's 9 parameters, the
    gyro's static bias and the gyro's gravity-direction parameters (:func:`calib.fieldcal.bound.gyro_direction_bound`)."""
    s = synthetic_session(3, n_poses=14)
    ds = recording.make_dataset(s["accel"], s["gyro"], sample_rate_hz=s["fs"], latitude_deg=45.0,
                                accel_units="m s-2", gyro_units="rad s-1", gravity_m_s2=s["gravity"],
                                source="synthetic")
    res = fieldcal.fieldcal_recording(ds, {"gyro": {"bias": "statics"}})
    out = res.summary()
    acc, gyr = out["accel_sigma_crb"], out["gyro_sigma_crb"]
    assert set(acc["sigma"]) == set(res.accel.names) and all(v > 0 for v in acc["sigma"].values())
    # the bias of the statics: the measured white noise over sqrt(number of static samples)
    n_static = sum(int(b - a) for a, b in res.intervals)
    assert [gyr["sigma"][n] for n in BIAS_NAMES] == pytest.approx(
        np.asarray(gyr["noise_sigma_per_sample"]) / math.sqrt(n_static), rel=1e-12)
    assert np.allclose(gyr["noise_sigma_per_sample"], 5e-4, rtol=0.05)   # the session's gyro noise
    assert all(gyr["sigma"][n] > 0 and n not in gyr["why_none"] for n in GYRO_NAMES)
    assert gyr["direction"]["motions"] == len(res.intervals) - 1
