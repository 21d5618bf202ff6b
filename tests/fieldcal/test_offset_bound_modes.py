"""The Cramér–Rao bound of the field calibration's gyro bias in the bias modes ``initial`` (the mean of the initial
rest) and ``estimate`` (the bias estimated with the gravity-direction parameters from the motions), as ``calib
fieldcal`` reports it: on a synthetic session with a known bias and known white noise, the closed form of a mean of
n white samples, and the spread of the bias estimates over noise seeds against the bound of one seed's recording."""
from __future__ import annotations

import copy
import math
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import session

from calib import fieldcal
from calib.fieldcal import bound as fb
from calib.fieldcal.results import BIAS_NAMES, GYRO_NAMES
from calib.io import recording

GYRO_NOISE, ACCEL_NOISE = 5e-4, 3e-3   # per sample [rad s-1], [m s-2]
N_SEEDS = 40


@pytest.fixture(scope="module")
def runs():
    """14 poses after a 30 s rest, hand-like turns about random axes, the truth (bias included) fixed and only the
    white noise redrawn: ``calib fieldcal``'s result in modes ``initial`` and ``estimate`` for each of 40 seeds."""
    clean = session(3, n_poses=14, gyro_noise=0.0, accel_noise=0.0)
    n = len(clean["accel"])
    out = {"initial": [], "estimate": [], "bias_true": clean["gyro"][:100].mean(axis=0)}
    for k in range(N_SEEDS):
        rng = np.random.default_rng([21, k])
        a = clean["accel"] + ACCEL_NOISE * rng.standard_normal((n, 3))
        g = clean["gyro"] + GYRO_NOISE * rng.standard_normal((n, 3))
        ds = recording.make_dataset(a, g, sample_rate_hz=clean["fs"], latitude_deg=45.0, accel_units="m s-2",
                                    gyro_units="rad s-1", gravity_m_s2=clean["gravity"], source="synthetic")
        for mode in ("initial", "estimate"):
            out[mode].append(fieldcal.fieldcal_recording(ds, {"gyro": {"bias": mode}}))
        if k == 0:
            out["accel"], out["gyro"] = a, g
    return out


def _bound(res):
    b = res.summary()["gyro_sigma_crb"]
    return b, np.array([b["sigma"][nm] for nm in BIAS_NAMES], dtype=float)


def test_initial_rest_bias_bound_is_the_closed_form(runs):
    """Mode ``initial``: the bias is the mean of the initial rest's n samples, so its bound is sigma / sqrt(n) per
    axis with sigma the white noise measured on the static intervals; the reported n is the number of samples the
    estimator averages (the bias equals their mean), sigma is the simulated one (5 %: a few thousand static
    samples), and over 40 seeds the means scatter as the bound says (the std of a std over 40 seeds is 11 %: the
    band [0.7, 1.3] is three of them; the mean of white samples is efficient)."""
    res = runs["initial"][0]
    a, b = res.gyro.extra["bias_span"]
    np.testing.assert_array_equal(res.gyro.bias, runs["gyro"][a:b].mean(axis=0))
    blk, sig = _bound(res)
    assert not any(nm in blk["why_none"] for nm in BIAS_NAMES)
    assert sig == pytest.approx(np.asarray(blk["noise_sigma_per_sample"]) / math.sqrt(b - a), rel=1e-12)
    assert sig == pytest.approx(GYRO_NOISE / math.sqrt(b - a), rel=0.05)
    # the fit reports the standard error of that mean: its ratio to the bound is one within the noise's scatter
    assert all(abs(blk["se_over_crb"][nm] - 1.0) < 0.1 for nm in BIAS_NAMES)
    est = np.array([r.gyro.bias for r in runs["initial"]])
    assert np.all(np.abs(est.mean(axis=0) - runs["bias_true"]) < 4 * sig / math.sqrt(N_SEEDS))   # unbiased
    ratio = est.std(axis=0, ddof=1) / sig
    assert np.all((ratio >= 0.7) & (ratio <= 1.3)), ratio.round(3)


def test_estimated_bias_spread_over_seeds_matches_the_bound(runs):
    """Mode ``estimate``: the bias is estimated with the 6 misalignments and 3 gains from the integrated motions
    (its start, the initial-rest mean, does not enter the estimate); its bound is the bias rows of the inverse of
    the motions' and accel means' information (the pose directions and the accel calibration profiled out). The
    std of the estimates over 40 seeds lies within [0.7, 1.5] of the bound from one seed's recording: below, three
    times the 11 % sampling scatter of a std over 40 seeds; above, as much again for the fit being sequential (the
    accel calibration and pose directions taken as exact in the gyro fit) and unweighted."""
    blk, sig = _bound(runs["estimate"][0])
    assert not any(nm in blk["why_none"] for nm in BIAS_NAMES)
    assert "motions" in blk["model"] and blk["direction"]["motions"] == len(runs["estimate"][0].intervals) - 1
    # the motions carry less about the bias than the static samples do: the bound is above the initial rest's
    _, sig_init = _bound(runs["initial"][0])
    assert np.all(sig > sig_init)
    assert all(blk["se_over_crb"][nm] is not None and blk["se_over_crb"][nm] > 0 for nm in BIAS_NAMES + GYRO_NAMES)
    est = np.array([r.gyro.bias for r in runs["estimate"]])
    ratio = est.std(axis=0, ddof=1) / sig
    assert np.all((ratio >= 0.7) & (ratio <= 1.5)), ratio.round(3)


def test_initial_bias_without_its_samples_gets_no_number():
    """A gyro fit that does not say which samples its initial-rest bias averages gets no number for it, and the
    reason; a mode the bound does not know gets none either."""
    rng = np.random.default_rng(2)
    g = 1e-3 * rng.standard_normal((4000, 3))
    iv = np.array([[k * 1000, k * 1000 + 500] for k in range(4)])
    fit = SimpleNamespace(names=GYRO_NAMES + BIAS_NAMES)
    out = fb.gyro_offset_bound(fit, g, None, iv, "initial")
    assert all(out["sigma"][nm] is None and "bias_span" in out["why_none"][nm] for nm in BIAS_NAMES)
    out = fb.gyro_offset_bound(fit, g, None, iv, "initial", (0, 900))
    assert [out["sigma"][nm] for nm in BIAS_NAMES] == pytest.approx(
        np.asarray(out["noise_sigma_per_sample"]) / 30.0, rel=1e-12)
    out = fb.gyro_offset_bound(fit, g, None, iv, "other")
    assert all(out["sigma"][nm] is None and out["why_none"][nm] for nm in BIAS_NAMES)



def test_a_bias_axis_the_fit_holds_keeps_the_initial_rest_bound(runs):
    """Mode ``estimate`` with a bias axis the fit holds at nominal (no correction: the initial-rest mean stays its
    value): that axis's bound is the initial-rest mean's, sigma / sqrt(n), not the motions'; the other axes keep
    a bound from the motions."""
    res = runs["estimate"][0]
    acc_fit, fit = copy.deepcopy(res.accel), copy.deepcopy(res.gyro)
    a, b = fit.extra["bias_span"]
    g = runs["gyro"]
    fit.bias[0] = fit.values[9] = g[a:b, 0].mean()          # bias_x held at its start
    fit.determination.held = ("bias_x",)
    fb.attach(acc_fit, fit, runs["accel"], g, runs["accel"], res.intervals, res.gravity_m_s2)
    blk = fit.extra["sigma_crb"]
    closed = blk["noise_sigma_per_sample"][0] / math.sqrt(b - a)
    assert blk["sigma"]["bias_x"] == pytest.approx(closed, rel=1e-12) and "bias_x" not in blk["why_none"]
    assert res.summary()["gyro_sigma_crb"]["sigma"]["bias_x"] > 1.5 * closed   # the motions' bound, not held
    assert blk["sigma"]["bias_y"] is not None and blk["sigma"]["bias_z"] is not None
    assert "held" in blk["model"] and blk["direction"]["held_at_nominal"] == ["bias_x"]
