"""Every example settings file of ``config/import/examples`` (one per reader format) imports a small file written
here in that format: the samples read back are the samples written, in the units and axes the example declares.
The data folder is the test's (the examples' ``data_dir: .`` points at their own folder)."""
from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io

from calib.ingest import importers
from calib.io import recording

from conftest import session, write_bag

EXAMPLES = Path(__file__).resolve().parents[2] / "config" / "import" / "examples"
G = 9.80665


def settings(name, tmp_path):
    s = importers.load_settings(EXAMPLES / f"{name}.yaml")
    s["data_dir"] = str(tmp_path)
    return s


def static(n, seed=0):
    rng = np.random.default_rng(seed)
    acc = np.array([0.02, -0.01, G]) + 0.01 * rng.standard_normal((n, 3))   # m s-2, z up
    gyr = np.array([1e-3, -2e-3, 5e-4]) + 1e-3 * rng.standard_normal((n, 3))  # rad s-1
    return acc, gyr


def test_every_format_has_an_example():
    fmts = {importers.load_settings(p)["format"] for p in EXAMPLES.glob("*.yaml")}
    assert fmts == set(importers.FORMATS)


def test_columns_example(tmp_path):
    n, fs = 1000, 200.0
    acc, gyr = static(n)
    t_ms = 1000.0 * np.arange(n) / fs + 123.0
    temp = 25.0 + 0.001 * np.arange(n)
    header = "t_ms,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,temp_c"
    rows = np.column_stack([t_ms, acc / G, np.degrees(gyr), temp])
    (tmp_path / "logger.csv").write_text("# exported by the logger\n" + header + "\n"
                                         + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    ds = importers.import_dataset(settings("columns", tmp_path))
    np.testing.assert_allclose(ds["accel"].values * G, acc, rtol=1e-12)
    np.testing.assert_allclose(np.radians(ds["gyro"].values), gyr, rtol=1e-12)
    assert ds["accel"].attrs["units"] == "g" and ds["gyro"].attrs["units"] == "deg s-1"
    assert ds.attrs["sample_rate_hz"] == pytest.approx(fs, rel=1e-9)
    np.testing.assert_allclose(ds["temperature"].values, temp)


def test_npz_columns_example(tmp_path):
    n = 800
    acc, gyr = static(n, 1)
    names = ["Time", "Accel. X", "Accel. Y", "Accel. Z", "Gyro. X", "Gyro. Y", "Gyro. Z"]
    np.savez(tmp_path / "session.npz", data=np.column_stack([np.arange(n) / 100.0, acc, gyr]),
             columns=np.array(names))
    ds = importers.import_dataset(settings("npz_columns", tmp_path))
    np.testing.assert_array_equal(ds["accel"].values, acc)
    np.testing.assert_array_equal(ds["gyro"].values, gyr)


def test_mikoff_example(tmp_path):
    acc, gyr = static(600, 2)
    np.savetxt(tmp_path / "imu.log", np.column_stack([acc, gyr]), fmt="%.17g")
    ds = importers.import_dataset(settings("mikoff", tmp_path))
    np.testing.assert_array_equal(ds["accel"].values, acc)
    np.testing.assert_array_equal(ds["gyro"].values, gyr)


def test_imu_tk_example(tmp_path):
    n, fs = 700, 100.0
    acc, gyr = static(n, 3)
    t = 1.5 + np.arange(n) / fs
    acc_counts = np.round(acc / G * 16384.0)
    gyr_counts = np.round(np.degrees(gyr) * 131.0)
    for name, x in (("imu_acc.txt", acc_counts), ("imu_gyro.txt", gyr_counts)):
        np.savetxt(tmp_path / name, np.column_stack([t, x]), fmt="%.17g")
    ds = importers.import_dataset(settings("imu_tk", tmp_path))
    np.testing.assert_array_equal(ds["accel"].values, acc_counts)
    np.testing.assert_array_equal(ds["gyro"].values, gyr_counts)
    assert "passed" in ds.attrs["units_check"]   # the counts-per-g declared: gravity-norm checked


def _rx(axis, angle):
    k = np.zeros(3)
    k[axis] = 1.0
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def test_imucal_example(tmp_path):
    fs = 102.4
    rng = np.random.default_rng(4)
    rows, labels = [], []
    for ax in range(3):   # each axis up (p) then down (a), 3 s each
        for lab, up in (("p", 1.0), ("a", -1.0)):
            f = np.zeros(3)
            f[ax] = up * G
            rows.append(np.column_stack([f + 0.01 * rng.standard_normal((int(3 * fs), 3)),
                                         0.05 * rng.standard_normal((int(3 * fs), 3))]))
            labels += [f"{'xyz'[ax]}_{lab}"] * int(3 * fs)
    for ax in range(3):   # a clockwise (-360 deg) turn about each axis in 4 s, gravity turning in the body frame
        m = int(4 * fs)
        theta = -2 * math.pi * np.arange(m) / m
        up = np.array([0.0, 0.0, G]) if ax != 2 else np.array([G, 0.0, 0.0])
        f = np.array([_rx(ax, th).T @ up for th in theta])
        # a real gyro's noise on the other axes (noise-free rows would repeat: a stuck run, refused at import)
        w = 0.05 * rng.standard_normal((m, 3))
        w[:, ax] = math.degrees(-2 * math.pi / 4.0)   # deg/s
        rows.append(np.column_stack([f, w]))
        labels += [f"{'xyz'[ax]}_rot"] * m
    data = np.concatenate(rows)
    lines = ["n_samples,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z,label"]
    lines += [f"{i}," + ",".join(repr(float(v)) for v in r) + f",{lab}" for i, (r, lab) in enumerate(zip(data, labels))]
    (tmp_path / "ferraris_session.csv").write_text("\n".join(lines) + "\n")
    ds = importers.import_dataset(settings("imucal", tmp_path))
    np.testing.assert_allclose(ds["accel"].values, data[:, :3], rtol=1e-15)
    assert list(ds["segment_label"].values) == ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a", "x_rot", "y_rot", "z_rot"]
    np.testing.assert_allclose(ds["rotation_angle"].values[6:], -360.0)


def test_rosbag_example(tmp_path):
    s = session(5, fs=100.0, duration_s=10.0)
    bag = write_bag("ros1", tmp_path, s)
    assert bag.name == "session.bag"
    ds = importers.import_dataset(settings("rosbag", tmp_path))
    np.testing.assert_allclose(ds["accel"].values, s["accel"], rtol=1e-15)
    np.testing.assert_allclose(ds["gyro"].values, s["gyro"], rtol=1e-15)


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_matlab_example(tmp_path, version):
    n, fs = 900, 200.0
    acc, gyr = static(n, 6)
    t = np.arange(n) / fs
    if version == "v5":
        scipy.io.savemat(tmp_path / "session.mat", {"imu": {"acc": acc, "gyr": gyr, "t": t[:, None]}})
    else:   # MATLAB's v7.3 layout: HDF5 after a 512-byte user block, arrays stored column-major (transposed)
        with h5py.File(tmp_path / "session.mat", "w", userblock_size=512) as f:
            grp = f.create_group("imu")
            for k, v in (("acc", acc), ("gyr", gyr), ("t", t[:, None])):
                grp.create_dataset(k, data=v.T)
        with open(tmp_path / "session.mat", "r+b") as fh:
            fh.write(b"MATLAB 7.3 MAT-file".ljust(116) + b"\x00" * 8 + b"\x00\x02IM")
    ds = importers.import_dataset(settings("matlab", tmp_path))
    np.testing.assert_array_equal(ds["accel"].values, acc)
    np.testing.assert_array_equal(ds["gyro"].values, gyr)
    assert ds.attrs["sample_rate_hz"] == pytest.approx(fs, rel=1e-9)


def test_matlab_accel_only_example(tmp_path):
    acc, _ = static(2400, 7)
    scipy.io.savemat(tmp_path / "poses.mat", {"ax": acc[:, 0], "ay": acc[:, 1], "az": acc[:, 2]})
    out = importers.import_recording(settings("matlab_accel_only", tmp_path), tmp_path / "poses.nc")
    h = recording.validate(out)
    assert h.sensors == ("accel",) and h.absent == ("gyro",) and h.sample_rate_hz == 1200.0
    np.testing.assert_array_equal(recording.load(out)["accel"].values, acc)
