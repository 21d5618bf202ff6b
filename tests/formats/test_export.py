"""Calibrations out: an exported IMU-TK / imucal calibration, read back with the tools' own documented formulas
(written out here, independently of calib), gives the same corrected samples as ``calib apply``, and those are the
simulated truth: exactly for the calibrate stage's result with a known model, within the noise for a field
calibration of a simulated hand-held session."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from calib.cli import main
from calib.core import triad
from calib.core.earth import STANDARD_GRAVITY
from calib.io import recording
from calib.io.netcdf import write_netcdf

G = 9.81


def run(*argv) -> int:
    return main([str(a) for a in argv])


# ----------------------------------------------------------------------------- the tools' documented formulas


def imutk_read(path):
    """IMU-TK's CalibratedTriad_::load: 9 numbers (misalignment T, row major), 9 (scale K), 3 (bias B)."""
    v = np.array(Path(path).read_text().split(), dtype=float)
    assert v.size == 21
    return v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:21]


def imutk_unbias_normalize(path, X):
    """X' = T K (X - B) (CalibratedTriad_::unbiasNormalize), X rows of samples."""
    T, K, B = imutk_read(path)
    return (X - B) @ (T @ K).T


def imucal_calibrate(path, acc, gyr):
    """imucal FerrarisCalibrationInfo: acc = inv(R_a) inv(K_a) (acc - b_a) [m/s^2];
    gyr = inv(R_g) inv(K_g) (gyr - K_ga acc_calibrated - b_g) [deg/s]."""
    c = json.loads(Path(path).read_text())
    assert c["cal_type"] == "Ferraris" and c["_format_version"] == "2.0.0"
    assert (c["acc_unit"], c["gyr_unit"]) == ("m/s^2", "deg/s")
    K_a, R_a, b_a = (np.array(c[k]) for k in ("K_a", "R_a", "b_a"))
    K_g, R_g, K_ga, b_g = (np.array(c[k]) for k in ("K_g", "R_g", "K_ga", "b_g"))
    assert np.allclose(K_a, np.diag(np.diag(K_a))) and np.allclose(np.linalg.norm(R_a, axis=1), 1.0)
    a = (np.linalg.inv(R_a) @ np.linalg.inv(K_a) @ (acc - b_a).T).T
    g = (np.linalg.inv(R_g) @ np.linalg.inv(K_g) @ (gyr - (K_ga @ a.T).T - b_g).T).T
    return a, g


# ----------------------------------------------------------------------------- the calibrate stage (exact truth)


def test_calibrate_result_exports_and_apply_give_the_true_inputs(tmp_path):
    """The Liu 2021 model as a default_calibration.nc; count increments made from known inputs with it."""
    acc_m, gyr_m = triad.liu2021_model("accel"), triad.liu2021_model("gyro")
    cal = tmp_path / "default_calibration.nc"
    write_netcdf(xr.Dataset({"accel": (("parameter",), acc_m.to_vector()), "gyro": (("parameter",), gyr_m.to_vector())},
                            coords={"parameter": list(triad.PARAM_NAMES)},
                            attrs={"frame": "body", "accel_units": "count s-1 per g",
                                   "gyro_units": "count s-1 per deg/h"}), cal)
    rng = np.random.default_rng(0)
    n, fs = 2000, 100.0
    f_true = rng.normal(0.0, 5.0, (n, 3)) + [0.0, 0.0, G]          # m s-2
    w_true = rng.normal(0.0, 0.5, (n, 3))                            # rad s-1
    N_a = acc_m.forward(f_true / STANDARD_GRAVITY)                   # count s-1 (input in g)
    N_g = gyr_m.forward(w_true / (math.pi / 180.0 / 3600.0))         # count s-1 (input in deg/h)
    ds = recording.make_dataset(N_a / fs, N_g / fs, sample_rate_hz=fs, latitude_deg=30.58, accel_units="count",
                                gyro_units="count", accel_kind="increment", gyro_kind="increment")
    rec = recording.write(ds, tmp_path / "raw.nc")
    out = tmp_path / "calibrated.nc"
    assert run("apply", cal, rec, out, "--force") == 0
    c = recording.load(out)
    np.testing.assert_allclose(c["accel"].values, f_true, rtol=0, atol=1e-9)
    np.testing.assert_allclose(c["gyro"].values, w_true, rtol=0, atol=1e-12)
    assert c["accel"].attrs["units"] == "m s-2" and c["gyro"].attrs["units"] == "rad s-1"
    assert c.attrs["calibration_file"] == str(cal) and c.attrs["source_file"] == str(rec)
    assert c.attrs["calib_version"] and c.attrs["made_by_rule"] == "apply"
    rate_a, rate_g = N_a, N_g   # the rate readings: increments x sample rate
    assert run("export", cal, "--format", "imutk", "--out", tmp_path / "liu") == 0
    np.testing.assert_allclose(imutk_unbias_normalize(tmp_path / "liu_acc.calib", rate_a), c["accel"].values,
                               rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(imutk_unbias_normalize(tmp_path / "liu_gyro.calib", rate_g), c["gyro"].values,
                               rtol=1e-12, atol=1e-13)
    assert "count s-1" in (tmp_path / "liu_calib.txt").read_text()
    assert run("export", cal, "--format", "imucal", "--out", tmp_path / "liu.json") == 0
    a, g = imucal_calibrate(tmp_path / "liu.json", rate_a, rate_g)
    np.testing.assert_allclose(a, c["accel"].values, rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(np.radians(g), c["gyro"].values, rtol=1e-12, atol=1e-13)


# ----------------------------------------------------------------------------- a field calibration (noisy truth)


def _rot(axis, angle):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def misalignment(yz, zy, zx, xz=0.0, xy=0.0, yx=0.0):
    """IMU-TK's T (calibration.h): [[1, -yz, zy], [xz, 1, -zx], [-xy, yx, 1]]."""
    return np.array([[1.0, -yz, zy], [xz, 1.0, -zx], [-xy, yx, 1.0]])


def hand_session(seed, fs=100.0, n_poses=20, g_sens=None):
    """Rest, then static poses joined by smooth turns about random axes. Truth (IMU-TK's models):
    a = T_a K_a (N_a - b_a), w = T_g K_g (N_g - b_g - G a); returns raw N, the true f, w and the truth."""
    rng = np.random.default_rng(seed)
    Ta, Ka = misalignment(*(0.005 * rng.standard_normal(3))), np.diag(1 + 0.01 * rng.standard_normal(3))
    Tg, Kg = misalignment(*(0.005 * rng.standard_normal(6))), np.diag(1 + 0.01 * rng.standard_normal(3))
    ba, bg = 0.05 * rng.standard_normal(3), 0.01 * rng.standard_normal(3)
    Gs = np.zeros((3, 3)) if g_sens is None else np.asarray(g_sens)
    C, f, w = np.eye(3), [], []
    gn = np.array([0.0, 0.0, G])

    def hold(dur):
        k = int(round(dur * fs))
        f.append(np.tile(C.T @ gn, (k, 1)))
        w.append(np.zeros((k, 3)))

    hold(20.0)
    for _ in range(n_poses - 1):
        e = rng.standard_normal(3)
        e /= np.linalg.norm(e)
        th = np.radians(rng.uniform(40, 120)) * rng.choice([-1, 1])
        tt = np.arange(int(1.5 * fs)) / fs
        phi = th / 1.5 * (tt - 1.5 / (2 * np.pi) * np.sin(2 * np.pi * tt / 1.5))
        f.append(np.array([(C @ _rot(e, p)).T @ gn for p in phi]))
        w.append((th / 1.5 * (1 - np.cos(2 * np.pi * tt / 1.5)))[:, None] * e)
        C = C @ _rot(e, th)
        hold(3.0 + rng.uniform(0, 1))
    f, w = np.concatenate(f), np.concatenate(w)
    n = len(f)
    N_a = f @ np.linalg.inv(Ta @ Ka).T + ba + 0.003 * rng.standard_normal((n, 3))
    N_g = w @ np.linalg.inv(Tg @ Kg).T + bg + f @ Gs.T + 5e-4 * rng.standard_normal((n, 3))
    return {"accel": N_a, "gyro": N_g, "f": f, "w": w, "fs": fs}


def _session_file(tmp_path, s, name):
    ds = recording.make_dataset(s["accel"], s["gyro"], sample_rate_hz=s["fs"], latitude_deg=45.0, gravity_m_s2=G,
                                accel_units="m s-2", gyro_units="rad s-1", source="synthetic")
    return recording.write(ds, tmp_path / name)


@pytest.mark.parametrize("g_sensitive", [False, True])
def test_field_calibration_exports_match_apply_and_truth(tmp_path, g_sensitive):
    s = hand_session(3, g_sens=[[2e-4, 0, 1e-4], [0, -1e-4, 0], [1e-4, 0, 3e-4]] if g_sensitive else None)
    rec = _session_file(tmp_path, s, "hand.nc")
    settings = tmp_path / "fc.yaml"
    settings.write_text(f"gravity_m_s2: {G}\ngyro: {{bias: {'g_sensitive' if g_sensitive else 'initial'}}}\n")
    fc = tmp_path / "fieldcal.nc"
    assert run("fieldcal", rec, "--settings", settings, "--out", fc) == 0
    out = tmp_path / "calibrated.nc"
    assert run("apply", fc, rec, out) == 0
    c = recording.load(out)
    a_cal, w_cal = c["accel"].values, c["gyro"].values
    # truth: within the simulated noise (3 mm s-2, 0.5 mrad s-1) plus what 20 poses leave of the model
    err_a = np.sqrt(np.mean((a_cal - s["f"]) ** 2))
    err_w = np.sqrt(np.mean((w_cal - s["w"]) ** 2))
    print("rms error vs truth", err_a, err_w)
    assert err_a < 0.006 and err_w < 0.001, (err_a, err_w)
    # imucal's formulas on the raw readings give calib apply's samples
    assert run("export", fc, "--format", "imucal", "--out", tmp_path / "cal.json") == 0
    a, g = imucal_calibrate(tmp_path / "cal.json", s["accel"], s["gyro"])
    np.testing.assert_allclose(a, a_cal, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.radians(g), w_cal, rtol=0, atol=1e-12)
    # calib's own JSON applies to the same samples
    assert run("export", fc, "--format", "json", "--out", tmp_path / "calib.json") == 0
    assert run("apply", tmp_path / "calib.json", rec, tmp_path / "again.nc") == 0
    np.testing.assert_array_equal(recording.load(tmp_path / "again.nc")["gyro"].values, w_cal)
    code = run("export", fc, "--format", "imutk", "--out", tmp_path / "tk")
    if g_sensitive:   # IMU-TK's CalibratedTriad has no g-sensitivity: refused, nothing written
        assert code == 2 and not (tmp_path / "tk_acc.calib").exists()
        return
    assert code == 0
    T, K, _ = imutk_read(tmp_path / "tk_acc.calib")
    assert np.allclose(np.tril(T, -1), 0.0) and np.allclose(np.diag(T), 1.0)   # IMU-TK's accelerometer frame
    np.testing.assert_allclose(imutk_unbias_normalize(tmp_path / "tk_acc.calib", s["accel"]), a_cal, atol=1e-12)
    np.testing.assert_allclose(imutk_unbias_normalize(tmp_path / "tk_gyro.calib", s["gyro"]), w_cal, atol=1e-12)


def test_apply_refuses_a_recording_of_other_units(tmp_path, capsys):
    acc_m, gyr_m = triad.liu2021_model("accel"), triad.liu2021_model("gyro")
    cal = tmp_path / "default_calibration.nc"
    write_netcdf(xr.Dataset({"accel": (("parameter",), acc_m.to_vector()), "gyro": (("parameter",), gyr_m.to_vector())},
                            coords={"parameter": list(triad.PARAM_NAMES)}), cal)
    s = hand_session(4, n_poses=3)
    rec = _session_file(tmp_path, s, "si.nc")
    assert run("apply", cal, rec, tmp_path / "x.nc") == 2
    assert "applies to count (increment), count s-1 (rate)" in capsys.readouterr().err
    assert not (tmp_path / "x.nc").exists()
    assert run("export", rec, "--format", "json", "--out", tmp_path / "r.json") == 2   # a recording is no calibration


def test_apply_streams_a_long_recording_without_time_coordinate(tmp_path):
    """Files written chunk by chunk (t0_s + sample_rate_hz, no time variable) are calibrated chunk by chunk."""
    acc_m, gyr_m = triad.liu2021_model("accel"), triad.liu2021_model("gyro")
    cal = tmp_path / "default_calibration.nc"
    write_netcdf(xr.Dataset({"accel": (("parameter",), acc_m.to_vector()), "gyro": (("parameter",), gyr_m.to_vector())},
                            coords={"parameter": list(triad.PARAM_NAMES)}), cal)
    rng = np.random.default_rng(5)
    n, fs = 3000, 100.0
    f_true = rng.normal(0.0, 1.0, (n, 3)) + [0.0, 0.0, G]
    w_true = rng.normal(0.0, 1e-3, (n, 3))
    N_a = acc_m.forward(f_true / STANDARD_GRAVITY) / fs
    N_g = gyr_m.forward(w_true / (math.pi / 180.0 / 3600.0)) / fs
    rec = tmp_path / "long.nc"
    with recording.LongRecordingWriter(rec, n, fs, latitude_deg=30.58, accel_units="count", gyro_units="count",
                                       chunk_samples=1000, temperature=True) as w:
        for i in range(0, n, 1000):
            w.append(N_a[i:i + 1000], N_g[i:i + 1000], np.full(1000, 21.5))
    assert not recording.read_header(rec).has_time
    out = tmp_path / "cal.nc"
    assert run("apply", cal, rec, out, "--force") == 0
    c = recording.load(out)
    np.testing.assert_allclose(c["accel"].values, f_true, rtol=0, atol=1e-9)
    np.testing.assert_allclose(c["gyro"].values, w_true, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(c["temperature"].values, 21.5)
    assert c.attrs["calibration_file"] == str(cal) and c.attrs["made_by_rule"] == "apply"


def test_an_imutk_export_interrupted_after_its_first_file_writes_none(tmp_path, monkeypatch, capsys):
    """IMU-TK's three files are one set: an interrupt once the first is written leaves none of them."""
    from calib.io import atomic

    cal = tmp_path / "default_calibration.nc"
    write_netcdf(xr.Dataset({"accel": (("parameter",), triad.liu2021_model("accel").to_vector()),
                             "gyro": (("parameter",), triad.liu2021_model("gyro").to_vector())},
                            coords={"parameter": list(triad.PARAM_NAMES)},
                            attrs={"frame": "body", "accel_units": "count s-1 per g",
                                   "gyro_units": "count s-1 per deg/h"}), cal)
    real, written = atomic.write_text, []

    def interrupted_after_one(path, text, **kw):
        if written:
            raise KeyboardInterrupt
        written.append(path)
        return real(path, text, **kw)

    monkeypatch.setattr("calib.io.export_formats.write_text", interrupted_after_one)
    assert run("export", cal, "--format", "imutk", "--out", tmp_path / "liu") == 130
    capsys.readouterr()
    assert len(written) == 1 and sorted(p.name for p in tmp_path.iterdir()) == ["default_calibration.nc"]
