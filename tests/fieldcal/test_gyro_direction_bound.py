"""The Cramér–Rao bound of the field calibration's gyro gravity-direction parameters
(:func:`calib.fieldcal.bound.gyro_direction_bound`): on a synthetic session with known white noise and fixed poses,
the spread of the gyro misalignments and gains over noise seeds against the bound from one seed's fits, poses and
measured noise; parameters the motions do not determine get no number, with the reason."""
from __future__ import annotations

import numpy as np
import pytest

from calib.fieldcal import bound as fb
from calib.fieldcal.accelerometer import fit_accel_norm
from calib.fieldcal.gyroscope import fit_gyro_directions
from calib.fieldcal.results import GYRO_NAMES
from calib.signal import detect

G = 9.81
GYRO_NOISE, ACCEL_NOISE = 5e-4, 3e-3   # per sample [rad s-1], [m s-2]
N_SEEDS = 40


def _fits(accel, gyro, iv, fs, **kw):
    """The field calibration's two fits on fixed intervals: the gravity-norm accel fit, then the gravity-direction
    gyro fit with the constant bias of the statics (the ``statics`` bias mode)."""
    af = fit_accel_norm(accel, iv, G, input_units="m s-2")
    ac = af.apply(accel)
    b0 = np.concatenate([gyro[a:b] for a, b in iv]).mean(axis=0)
    gf = fit_gyro_directions(gyro, ac, iv, np.full(len(gyro), 1.0 / fs), bias=b0, input_units="rad s-1",
                             sample_dt=1.0 / fs, **kw)
    return af, ac, gf


def test_spread_of_the_gyro_direction_fit_over_seeds_matches_the_bound(synthetic_session):
    """14 poses, hand-like turns about random axes, the truth fixed and only the white noise redrawn: the std of
    every gyro misalignment and gain over 40 seeds lies within [0.6, 2] sigma_crb (the std of a std over 40 seeds:
    11 %; the fits are sequential and unweighted, so a spread somewhat above the bound is expected)."""
    clean = synthetic_session(3, n_poses=14, gyro_noise=0.0, accel_noise=0.0)
    fs, n = clean["fs"], len(clean["accel"])

    def noisy(k):
        rng = np.random.default_rng([7, k])
        return (clean["accel"] + ACCEL_NOISE * rng.standard_normal((n, 3)),
                clean["gyro"] + GYRO_NOISE * rng.standard_normal((n, 3)))

    a0, g0 = noisy(0)
    iv = detect.detect_static(a0, g0, fs).intervals
    est, crb = [], None
    for k in range(N_SEEDS):
        a, g = noisy(k)
        af, ac, gf = _fits(a, g, iv, fs)
        if k == 0:
            crb = fb.gyro_direction_bound(gf, g, a, af, ac, iv, G)
        est.append(gf.values[:9])
    assert not crb["why_none"] and crb["motions"] == len(iv) - 1
    # the noise the bound measured is the session's
    assert np.allclose(crb["gyro_noise_sigma_per_sample"], GYRO_NOISE, rtol=0.05)
    assert np.allclose(crb["accel_noise_sigma_per_sample"], ACCEL_NOISE, rtol=0.05)
    bound = np.array([crb["sigma"][nm] for nm in GYRO_NAMES])
    ratio = np.std(est, axis=0, ddof=1) / bound
    assert np.all((ratio >= 0.6) & (ratio <= 2.0)), dict(zip(GYRO_NAMES, ratio.round(3)))


def test_turns_about_one_axis_leave_parameters_without_a_number(synthetic_session):
    """Every turn about body z with the unit tilted 60 deg: the gravity directions lie on a cone, the turns say
    nothing about the gyro's x and y axes. The parameters the fit leaves not determined (or holds at nominal) get
    None and a reason, never a number."""
    s = synthetic_session(4, n_poses=14, axes=[0.0, 0.0, 1.0],
                          start=np.array([[1.0, 0.0, 0.0], [0.0, 0.5, -np.sqrt(0.75)], [0.0, np.sqrt(0.75), 0.5]]))
    fs = s["fs"]
    iv = detect.detect_static(s["accel"], s["gyro"], fs).intervals
    for hold in (True, False):
        af, ac, gf = _fits(s["accel"], s["gyro"], iv, fs, hold_undetermined=hold)
        crb = fb.gyro_direction_bound(gf, s["gyro"], s["accel"], af, ac, iv, G)
        assert set(crb["why_none"]) == {nm for nm, v in crb["sigma"].items() if v is None}
        assert set(gf.determination.not_determined) <= set(crb["why_none"])
        assert all(crb["why_none"][nm] for nm in crb["why_none"])
        if hold:
            assert all("held at nominal" in crb["why_none"][nm] for nm in gf.determination.held)
        else:
            assert all("do not see" in crb["why_none"][nm] for nm in gf.determination.not_determined)


def test_the_bound_scales_with_the_noise(synthetic_session):
    """Doubling both white noises doubles every bound (the information is J^T C^-1 J with C proportional to the
    noise variance): the bound follows the noise measured on the recording, not a setting."""
    clean = synthetic_session(5, n_poses=10, gyro_noise=0.0, accel_noise=0.0)
    fs, n = clean["fs"], len(clean["accel"])
    rng = np.random.default_rng(11)
    za, zg = rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
    out, scale = {}, 2.0
    for f in (1.0, scale):
        a, g = clean["accel"] + f * ACCEL_NOISE * za, clean["gyro"] + f * GYRO_NOISE * zg
        iv = detect.detect_static(clean["accel"] + ACCEL_NOISE * za, clean["gyro"] + GYRO_NOISE * zg, fs).intervals
        af, ac, gf = _fits(a, g, iv, fs)
        out[f] = fb.gyro_direction_bound(gf, g, a, af, ac, iv, G)["sigma"]
    for nm in GYRO_NAMES:
        assert out[scale][nm] == pytest.approx(scale * out[1.0][nm], rel=0.02)
