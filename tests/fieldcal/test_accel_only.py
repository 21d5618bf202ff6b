"""An accelerometer-only record (1200 Hz, m s-2) as a MATLAB tutorial ships it, written in the test as a v5 .mat
file: ``calib import`` -> ``calib validate`` -> ``calib fieldcal`` with exit 0, the known bias, gains and
misalignments recovered within the noise of the pose means, the gyro part skipped with a one-line note; a three-pose
record is refused by name (the poses it lacks). The samples are made from the accelerometer model's definition
(raw = K^-1 T^-1 a + b, a = gravity in the body frame of each pose), not by the fit under test."""
from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io
import xarray as xr
import yaml

from calib import cli
from calib.io import recording

FS = 1200.0
G = 9.80665
NOISE = 0.02          # white accel noise per sample [m s-2]
REST_S = 4.0
BIAS = np.array([0.12, -0.08, 0.20])        # m s-2
GAIN = np.array([1.02, 0.985, 1.01])        # m s-2 out per m s-2 in
MIS = {"mis_yz": 2e-3, "mis_zy": -1.5e-3, "mis_zx": 1e-3}


def accel_matrix():
    """T K of the calibration a = T K (N - b) (calib.fieldcal's accelerometer model, IMU-TK's layout)."""
    T = np.array([[1.0, -MIS["mis_yz"], MIS["mis_zy"]], [0.0, 1.0, -MIS["mis_zx"]], [0.0, 0.0, 1.0]])
    return T @ np.diag(GAIN)


def record(directions, seed=3):
    """Raw samples of static poses (gravity along each unit ``direction`` in the body frame) joined by shaky moves,
    the first rest twice as long."""
    rng = np.random.default_rng(seed)
    rest, move = int(REST_S * FS), int(1.5 * FS)
    rows, prev = [], None
    for i, u in enumerate(directions):
        if prev is not None:
            s = np.linspace(0.0, 1.0, move)[:, None]
            v = (1 - s) * prev + s * u
            rows.append(G * v / np.linalg.norm(v, axis=1)[:, None] + 0.5 * rng.standard_normal((move, 3)))
        rows.append(G * u + NOISE * rng.standard_normal(((2 if i == 0 else 1) * rest, 3)))
        prev = u
    a = np.concatenate(rows)
    return np.linalg.solve(accel_matrix(), a.T).T + BIAS


def poses(n, seed=5):
    """``n`` gravity directions spread over the sphere (a Fibonacci lattice, turned by a fixed random rotation)."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5**0.5) * k
    u = np.column_stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z])
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    return u @ q.T


def import_settings(tmp_path, name):
    s = {"format": "matlab", "file": f"{name}.mat", "data_dir": ".", "sample_rate_hz": FS, "latitude_deg": 52.0, "gravity_m_s2": G,
         "accel": {"variable": "imu.acc", "units": "m s-2", "sample_kind": "rate"}}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(s))
    return path


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_accel_only_mat_record_through_import_validate_fieldcal(tmp_path, capsys, caplog):
    raw = record(poses(12))
    scipy.io.savemat(tmp_path / "acc12.mat", {"imu": {"acc": raw}})
    settings = import_settings(tmp_path, "acc12")
    rec, out = tmp_path / "acc12.nc", tmp_path / "cal.nc"
    code, _, err = run(capsys, "import", settings, rec)
    assert code == 0 and "a partial record: accelerometers only" in err
    code, text, err = run(capsys, "validate", rec)
    assert code == 0, err
    assert "no gyro (partial record" in text
    code, text, err = run(capsys, "fieldcal", rec, "--out", out)
    assert code == 0, err
    summary = json.loads(text)
    assert summary["n_static_intervals"] >= 12
    assert any("accelerometer only" in n and "gyro calibration" in n for n in summary["notes"])
    said = [r.getMessage() for r in caplog.records if "accelerometer only" in r.getMessage()]
    assert len(said) == 1 and "\n" not in said[0]   # the one-line note of the command
    with xr.open_dataset(out) as cal:
        bias = cal["accel_bias"].values
        params = dict(zip(cal["parameter"].values.tolist(), cal["value"].values))
    # a pose mean's noise: NOISE / sqrt(samples); the 9 parameters from 12 poses: within 10 of it
    tol = 10 * NOISE / np.sqrt(REST_S * FS)
    np.testing.assert_allclose(bias, BIAS, atol=tol)
    np.testing.assert_allclose([params[f"accel.gain_{a}"] for a in "xyz"], GAIN, atol=tol / G)
    for k, v in MIS.items():
        assert params[f"accel.{k}"] == pytest.approx(v, abs=tol / G)
    # the calibration applied to the record: the static specific force is gravity
    code, _, err = run(capsys, "apply", out, rec, tmp_path / "calibrated.nc")
    assert code == 0, err
    cal_acc = recording.load(tmp_path / "calibrated.nc")["accel"].values
    rest = cal_acc[: int(2 * REST_S * FS)]   # the first rest
    assert np.linalg.norm(rest.mean(axis=0)) == pytest.approx(G, abs=tol)


def test_three_pose_accel_record_is_refused_naming_the_poses_it_lacks(tmp_path, capsys):
    raw = record(np.eye(3))   # x up, y up, z up: 3 norm equations for the 9-parameter model
    scipy.io.savemat(tmp_path / "acc3.mat", {"imu": {"acc": raw}})
    rec = tmp_path / "acc3.nc"
    assert run(capsys, "import", import_settings(tmp_path, "acc3"), rec)[0] == 0
    assert run(capsys, "validate", rec)[0] == 0
    code, _, err = run(capsys, "fieldcal", rec, "--out", tmp_path / "cal.nc")
    assert code == 3, err
    assert "distinct static poses" in err and "9-parameter accelerometer model" in err and "Traceback" not in err
    assert "gyro" not in err.split("error")[-1].split("fix")[0] or "accelerometer only" in err
