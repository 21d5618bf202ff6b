"""A recording that starts in motion, with no initial rest: ``calib fieldcal`` without detection settings puts the
thresholds of its candidate detections on the noise floor (there is no rest to take them from) and calibrates the
poses, exit 0.

The recording is a static-pose protocol of ``conftest.protocol_session`` (known truth) with its initial rest cut
off: the samples up to the end of the first true static hold are dropped, so that the record begins with the first
turn. Checked against the generator's truth, not against the code's output: the accel gains of the written
calibration, and the calibrated specific force of every true static hold, whose norm is gravity. An
accelerometer-only record takes its candidates' thresholds from the protocol's initial rest when one is declared,
from the noise floor when there is none.
"""
from __future__ import annotations

import inspect
import json

import numpy as np
import xarray as xr
from conftest import MEMS_ACCEL_NOISE, protocol_dataset, protocol_session

from calib import cli
from calib.fieldcal import default_detection
from calib.io import recording
from calib.signal import detect

SEED = 10031          # the generator's draws of gains, biases, misalignments and turns
N_POSES = 16
NOISE = 1.0           # x MEMS_ACCEL_NOISE [m s-2] per sample
MIN_WAIT_S = 3.0      # each pose held 3-5 s


def session_without_rest():
    """A protocol session (SI units) and its recording with the initial rest, the first true static hold, cut off."""
    s = protocol_session(SEED, n_poses=N_POSES, noise=NOISE, min_wait_s=MIN_WAIT_S, units="SI")
    cut = int(s["intervals"][0][1])
    s = {**s, "accel": s["accel"][cut:], "gyro": s["gyro"][cut:], "intervals": s["intervals"][1:] - cut}
    return s, protocol_dataset(s)


def test_fieldcal_calibrates_a_recording_without_initial_rest(tmp_path, capsys):
    s, ds = session_without_rest()
    fs, g = s["fs"], s["gravity"]
    # the record begins with a turn: the first static hold starts a second or more in, the gyro turns before it
    assert s["intervals"][0][0] >= fs
    assert np.abs(s["gyro"][: s["intervals"][0][0]]).max() > 0.1   # rad s-1
    rec, out = tmp_path / "no_rest.nc", tmp_path / "cal.nc"
    recording.write(ds, rec)
    code = cli.main(["fieldcal", str(rec), "--out", str(out)])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    summary = json.loads(cap.out)
    assert summary["n_static_intervals"] >= N_POSES
    with xr.open_dataset(out) as cal:
        params = dict(zip(cal["parameter"].values.tolist(), cal["value"].values))
        matrix, bias = cal["accel_matrix"].values, cal["accel_bias"].values
    # a pose mean's noise: sigma / sqrt(samples), at least MIN_WAIT_S s of samples per pose; the 9 parameters from
    # 16 poses are within 10 of it (the tolerance of tests/fieldcal/test_accel_only.py)
    tol = 10 * MEMS_ACCEL_NOISE * NOISE / np.sqrt(MIN_WAIT_S * fs)   # m s-2
    # truth of protocol_session: a = T_a K_a (N - b_a), K_a = 1 / accel_scale_factors (m s-2 per m s-2 in SI)
    gain_true = 1.0 / np.asarray(s["accel_scale_factors"])
    np.testing.assert_allclose([params[f"accel.gain_{a}"] for a in "xyz"], gain_true, atol=tol / g)
    # every true static hold, calibrated (input factor 1: the record is in m s-2), reads gravity
    means = np.array([s["accel"][a:b].mean(axis=0) for a, b in s["intervals"]])
    norms = np.linalg.norm((means - bias) @ matrix.T, axis=1)
    np.testing.assert_allclose(norms, g, atol=tol)


def test_accel_only_candidates_take_the_declared_initial_rest():
    """An accelerometer-only record whose protocol declares its initial rest: the variance-rule candidates take
    their thresholds from that rest (``init_s``), as with a gyro; without a rest, from the noise floor. Every
    candidate's detection is settings of :func:`calib.signal.detect.detect_static` (its rule aside)."""
    rest_s = 20.0
    s = protocol_session(SEED, n_poses=N_POSES, noise=NOISE, min_wait_s=MIN_WAIT_S, units="SI", rest_s=rest_s)
    settings = set(inspect.signature(detect.detect_static).parameters) - {"accel", "gyro", "fs", "stat_accel",
                                                                          "stat_gyro"}
    with_rest = [c.detection for c in default_detection.candidates(
        s["accel"], None, s["fs"], default_detection.Protocol(initial_rest_s=rest_s)) if c.rule == "detect"]
    assert with_rest and all(d.get("init_s") == rest_s and d["use_gyro"] is False for d in with_rest)
    cut = int(s["intervals"][0][1])
    no_rest = [c.detection for c in default_detection.candidates(
        s["accel"][cut:], None, s["fs"], default_detection.Protocol()) if c.rule == "detect"]
    assert no_rest and all("threshold" in d and "init_s" not in d for d in no_rest)
    for d in with_rest + no_rest:
        assert set(d) - {"rule"} <= settings, d
