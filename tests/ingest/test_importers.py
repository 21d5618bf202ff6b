"""Importers of the real recordings in ../shared/data into calib-recording-1.

Facts checked come from the data's README (/work/shared/data/README.md), the authors' repositories and
physics (gravity norm, integrated 360 deg turns); reference values are read from the source files
independently of the importers.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib.ingest import common, importers
from calib.io import recording
from calib.ingest.importers import ImportDataError

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
CONFIG = ROOT / "config" / "import"
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared real-data directory {DATA} is missing")

STANDARD_G = 9.80665


def settings(name, **over):
    s = importers.load_settings(CONFIG / f"{name}.yaml")
    s["data_dir"] = str(DATA)
    s.update(over)
    return s


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """Each shipped config imported once, written atomically, then loaded back (which validates)."""
    out = tmp_path_factory.mktemp("imported")
    cache = {}

    def get(name):
        if name not in cache:
            p = importers.import_recording(settings(name), out / f"{name}.nc")
            recording.validate(p)
            cache[name] = recording.load(p, validate_all=False)
        return cache[name]

    return get


def _data_lines(path):
    return [ln for ln in Path(path).read_text().splitlines() if ln.strip()]


# ----------------------------------------------------------------------------- shipped configs


def test_every_shipped_config_points_at_the_shared_data(monkeypatch):
    monkeypatch.delenv("CALIB_DATA", raising=False)
    names = sorted(p.stem for p in CONFIG.glob("*.yaml"))
    assert names == ["imu_tk_xsens", "imucal_ferraris_A", "imucal_ferraris_B", "mikoff_imu0", "mikoff_imu1",
                     "mikoff_imu2", "smac_adis16405"]
    for n in names:
        s = importers.load_settings(CONFIG / f"{n}.yaml")  # no data_dir: the default data root
        assert common.data_dir(s).resolve() == DATA.resolve()
        assert s["format"] in importers.FORMATS and "latitude_deg" in s


# ----------------------------------------------------------------------------- IMU-TK


def test_imu_tk_xsens(written):
    ds = written("imu_tk_xsens")
    acc = np.loadtxt(DATA / "imu_tk_xsens" / "xsens_acc.mat")
    gyr = np.loadtxt(DATA / "imu_tk_xsens" / "xsens_gyro.mat")
    assert ds.sizes["time"] == 51_175 == len(acc)  # README: 51,175 rows
    # the rate is the least-squares clock of the timestamps (100 ppm fast of the nominal 100 Hz), not the median step
    slope = np.polyfit(np.arange(len(acc), dtype=float), acc[:, 0], 1)[0]
    assert ds.attrs["sample_rate_hz"] == pytest.approx(1.0 / slope, rel=1e-9)
    assert ds.attrs["clock_dropped_samples"] == 0
    assert ds.attrs["source"] == "recorded" and ds.attrs["gravity_m_s2"] == 9.81744
    for v in ("accel", "gyro"):
        assert ds[v].attrs["units"] == "count" and ds[v].attrs["sample_kind"] == "rate"
    np.testing.assert_array_equal(ds["time"].values, acc[:, 0])
    np.testing.assert_array_equal(ds["accel"].values, acc[:, 1:])
    np.testing.assert_array_equal(ds["gyro"].values, gyr[:, 1:])
    assert ds["time"].values[-1] - ds["time"].values[0] == pytest.approx(511.7, abs=0.1)  # README: 511.7 s
    # raw 16-bit counts with zero near 32768: the gyro at rest (first 50 s) reads about 32768
    g0 = np.median(ds["gyro"].values[:5000], axis=0)
    assert np.all(np.abs(g0 - 32768) < 1000) and ds["accel"].values.max() < 65536
    assert "xsens_acc.mat=335a2347" in ds.attrs["source_sha256"]  # README's sha256


# ----------------------------------------------------------------------------- imucal


def test_imucal_example_session_segments_and_gravity(written):
    ds = written("imucal_ferraris_A")
    raw = np.loadtxt(DATA / "imucal_ferraris" / "example_ferraris_session.csv", delimiter=",", skiprows=1)
    assert ds.sizes["time"] == len(raw)
    assert ds.attrs["sample_rate_hz"] == 102.4
    assert ds["accel"].attrs["units"] == "m s-2" and ds["gyro"].attrs["units"] == "deg s-1"
    np.testing.assert_array_equal(ds["gyro"].values, raw[:, 1:4])  # header n_samples,gyr_x..z,acc_x..z
    np.testing.assert_array_equal(ds["accel"].values, raw[:, 4:7])
    seglist = json.loads((DATA / "imucal_ferraris" / "example_ferraris_session_list.json").read_text())
    labels = list(ds["segment_label"].values)
    assert sorted(labels) == sorted(seglist)
    idx = ds["segment_index"].values
    for lab, se in seglist.items():  # imucal slices iloc[start:end]: end exclusive
        i = labels.index(lab)
        np.testing.assert_array_equal(np.flatnonzero(idx == i), np.arange(se["start"], se["end"]))
    acc = ds["accel"].values
    norms = []
    for i, lab in enumerate(labels):
        if ds["segment_kind"].values[i] == "static":
            m = acc[idx == i].mean(axis=0)
            norms.append(np.linalg.norm(m))
            ax = "xyz".index(lab[0])
            assert np.argmax(np.abs(m)) == ax and np.sign(m[ax]) == (1 if lab.endswith("_p") else -1)
    assert len(norms) == 6
    assert all(abs(n / 9.81 - 1) < 0.10 for n in norms)  # uncalibrated MEMS: each within 10 %
    assert np.mean(norms) == pytest.approx(9.81, rel=0.02)


def _turn_angles(ds, deg_per_unit):
    """Integrated gyro about each rotation segment's axis, static-segment bias removed, in degrees."""
    idx = ds["segment_index"].values
    gyr = ds["gyro"].values
    fs = ds.attrs["sample_rate_hz"]
    kinds = ds["segment_kind"].values
    static = np.isin(idx, np.flatnonzero(kinds == "static"))
    bias = gyr[static].mean(axis=0)
    out = {}
    for i, k in enumerate(kinds):
        if k == "rotation":
            axis = ds["rotation_axis"].values[i]
            w = (gyr[idx == i] - bias) * deg_per_unit
            out[str(ds["segment_label"].values[i])] = (w.sum(axis=0) / fs, axis)
    return out


def test_imucal_example_turns_are_full_turns_at_102_4_hz(written):
    ds = written("imucal_ferraris_A")
    turns = _turn_angles(ds, 1.0)
    assert set(turns) == {"x_rot", "y_rot", "z_rot"}
    for lab, (ang, axis) in turns.items():
        assert axis["xyz".index(lab[0])] == 1.0
        # one 360 deg turn (README), done clockwise as in imucal's convention: -360 at 102.4 Hz
        assert float(ang @ axis) == pytest.approx(-360.0, abs=20.0)
    rr = ds["rotation_rate"].values[ds["segment_kind"].values == "rotation"]
    assert np.all(rr < 0)
    np.testing.assert_array_equal(ds["rotation_angle"].values[ds["segment_kind"].values == "rotation"], -360.0)


def test_imucal_annotated_positive_turns(written):
    ds = written("imucal_ferraris_B")
    assert ds.sizes["time"] == len(_data_lines(DATA / "imucal_ferraris" / "annotated_session.csv")) - 1
    assert ds.attrs["sample_rate_hz"] == 204.8
    assert ds["accel"].attrs["units"] == "count" and ds["gyro"].attrs["units"] == "count"
    assert np.all(np.diff(ds["time"].values) > 0)  # rows come grouped by label; sorted by sample on import
    labels = list(ds["segment_label"].values)
    assert sorted(labels) == sorted(["x_p", "x_a", "y_p", "y_a", "z_p", "z_a", "x_rot", "y_rot", "z_rot"])
    kinds = ds["segment_kind"].values
    assert set(kinds[[labels.index(l) for l in ("x_rot", "y_rot", "z_rot")]]) == {"rotation"}
    assert np.all(ds["segment_index"].values >= 0)  # every sample is labelled in this file
    # README: the turns are positive right-handed rotations -> positive rates in the segment table
    rot = kinds == "rotation"
    assert np.all(ds["rotation_rate"].values[rot] > 0)
    # ... and the gyro, at 16.4 counts per deg/s (README), integrates to about +360 deg about the labelled axis
    for lab, (ang, axis) in _turn_angles(ds, 1.0 / 16.4).items():
        k = "xyz".index(lab[0])
        assert axis[k] == 1.0
        assert ang[k] == pytest.approx(360.0, abs=15.0)
        assert np.all(np.abs(np.delete(ang, k)) < 25.0)
    # statics: about 2048 counts per g along the labelled axis
    idx = ds["segment_index"].values
    for i, lab in enumerate(labels):
        if kinds[i] == "static":
            m = ds["accel"].values[idx == i].mean(axis=0) / 2048.0
            assert np.linalg.norm(m) == pytest.approx(1.0, abs=0.06)
            assert m["xyz".index(lab[0])] * (1 if lab.endswith("_p") else -1) > 0.95


# ----------------------------------------------------------------------------- mikoff, ADIS


@pytest.mark.parametrize("unit", ["imu0", "imu1", "imu2"])
def test_mikoff(written, unit):
    ds = written(f"mikoff_{unit}")
    raw = np.loadtxt(DATA / "mikoff_mpu9150" / f"{unit}.log")
    assert ds.sizes["time"] == len(raw) and 15_000 < len(raw) < 17_000  # README: about 160 s at 100 Hz
    assert ds.attrs["sample_rate_hz"] == 100.0
    assert ds["accel"].attrs["units"] == "m s-2" and ds["gyro"].attrs["units"] == "rad s-1"
    np.testing.assert_array_equal(ds["accel"].values, raw[:, :3])
    np.testing.assert_array_equal(ds["gyro"].values, raw[:, 3:])
    # mostly standstills (README): the median accel norm is gravity, about 9.81 m s-2 (uncalibrated: 2 %)
    assert np.median(np.linalg.norm(ds["accel"].values, axis=1)) == pytest.approx(9.81, rel=0.02)


def test_adis16405(written):
    ds = written("smac_adis16405")
    with np.load(DATA / "smac_adis16405" / "adis_16405_imu1.npz") as z:
        data, cols = z["data"], [str(c) for c in z["columns"]]
    assert ds.sizes["time"] == 1_000_000 and ds.attrs["sample_rate_hz"] == 100.0
    assert ds["accel"].attrs["units"] == "g" and ds["gyro"].attrs["units"] == "deg s-1"
    for j, ax in enumerate("XYZ"):  # mapped by column name, not by position
        np.testing.assert_array_equal(ds["accel"].values[:, j], data[:, cols.index(f"Accel. {ax}")])
        np.testing.assert_array_equal(ds["gyro"].values[:, j], data[:, cols.index(f"Gyro. {ax}")])
    assert np.median(np.linalg.norm(ds["accel"].values, axis=1)) == pytest.approx(1.0, abs=0.03)  # ~1 g
    # static: the gyro mean is far below 1 deg/s
    assert np.all(np.abs(ds["gyro"].values.mean(axis=0)) < 1.0)


# ----------------------------------------------------------------------------- generic columns reader


def _mikoff_csv(tmp_path, n=3000, rows=None):
    raw = np.loadtxt(DATA / "mikoff_mpu9150" / "imu0.log")[:n]
    t_ms = 1000.0 + 10.0 * np.arange(n)
    lines = ["t_ms,gx,gy,gz,ax,ay,az,temp"]
    for i in range(n):
        lines.append(",".join(f"{v:.6g}" for v in [t_ms[i], *raw[i, 3:], *raw[i, :3], 25.0 + i * 1e-3]))
    if rows is not None:
        lines = rows(lines)
    p = tmp_path / "generic.csv"
    p.write_text("\n".join(lines) + "\n")
    return p, raw, t_ms


def _generic(path, **over):
    s = {"format": "columns", "file": str(path), "delimiter": ",", "header": True,
         "time": {"column": "t_ms", "units": "ms"}, "sample_rate_hz": 100, "latitude_deg": 45.0,
         # a left-handed file frame made right-handed by declaration: x <- ay, y <- ax, z <- -az
         "accel": {"columns": ["ay", "ax", "az"], "sign": [1, 1, -1], "units": "m s-2", "sample_kind": "rate"},
         "gyro": {"columns": ["gy", "gx", "gz"], "sign": [1, 1, -1], "units": "rad s-1", "sample_kind": "rate"},
         "temperature": {"column": "temp"}}
    s.update(over)
    return s


def test_generic_columns_remap_time_and_temperature(tmp_path):
    p, raw, t_ms = _mikoff_csv(tmp_path)
    ds = importers.import_dataset(_generic(p))
    acc_ref = np.column_stack([raw[:, 1], raw[:, 0], -raw[:, 2]])
    np.testing.assert_allclose(ds["accel"].values, acc_ref, rtol=1e-5)
    np.testing.assert_allclose(ds["gyro"].values, np.column_stack([raw[:, 4], raw[:, 3], -raw[:, 5]]),
                               rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(ds["time"].values, t_ms / 1000.0)
    assert ds["temperature"].values[0] == 25.0 and ds.attrs["sample_rate_hz"] == pytest.approx(100.0, rel=1e-12)
    assert "z=-1*1*az" in ds.attrs["accel_column_map"]
    # declared rate contradicting the time column
    with pytest.raises(ImportDataError, match="sample_rate_hz"):
        importers.import_dataset(_generic(p, sample_rate_hz=50))
    # scale declared: counts per g -> g
    s = _generic(p)
    s["accel"] = {"columns": ["ax", "ay", "az"], "scale": 1 / STANDARD_G, "units": "g", "sample_kind": "rate"}
    ds = importers.import_dataset(s)
    np.testing.assert_allclose(ds["accel"].values, raw[:, :3] / STANDARD_G, rtol=1e-5)


def test_generic_time_not_increasing(tmp_path):
    def swap(lines):
        lines[101], lines[102] = lines[102], lines[101]
        return lines

    p, _, _ = _mikoff_csv(tmp_path, rows=swap)
    with pytest.raises(ImportDataError) as e:
        importers.import_dataset(_generic(p))
    # list index 102 is file line 103 (line 1 is the header): its time is earlier than line 102's
    assert "generic.csv" in str(e.value) and "'t_ms'" in str(e.value) and "line 103" in str(e.value)


# ----------------------------------------------------------------------------- bad input


def test_truncated_file(tmp_path):
    lines = _data_lines(DATA / "mikoff_mpu9150" / "imu2.log")
    bad = tmp_path / "imu2.log"
    bad.write_text("\n".join(lines[:-1] + [lines[-1][:15]]) + "\n")  # last row cut mid-write
    with pytest.raises(ImportDataError) as e:
        importers.import_dataset(settings("mikoff_imu2", file=str(bad)))
    msg = str(e.value)
    assert str(bad) in msg and "truncated" in msg and f"line {len(lines)}" in msg and "fix:" in msg
    # the same for one of the IMU-TK pair
    acc = _data_lines(DATA / "imu_tk_xsens" / "xsens_acc.mat")[:2000]
    gyr = _data_lines(DATA / "imu_tk_xsens" / "xsens_gyro.mat")[:2000]
    (tmp_path / "acc.mat").write_text("\n".join(acc[:-1] + [acc[-1][:40]]) + "\n")
    (tmp_path / "gyr.mat").write_text("\n".join(gyr) + "\n")
    s = settings("imu_tk_xsens", files={"accel": str(tmp_path / "acc.mat"), "gyro": str(tmp_path / "gyr.mat")})
    with pytest.raises(ImportDataError, match=r"acc\.mat.*truncated"):
        importers.import_dataset(s)


def test_nan_injected(tmp_path):
    lines = _data_lines(DATA / "mikoff_mpu9150" / "imu0.log")
    f = lines[99].split()
    f[5] = "nan"
    lines[99] = " ".join(f)
    bad = tmp_path / "imu0.log"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(ImportDataError) as e:
        importers.import_dataset(settings("mikoff_imu0", file=str(bad)))
    msg = str(e.value)
    assert str(bad) in msg and "'gz'" in msg and "line 100" in msg and "NaN" in msg


def test_wrong_header(tmp_path):
    src = (DATA / "imucal_ferraris" / "example_ferraris_session.csv").read_text().splitlines()
    src[0] = src[0].replace("acc_y", "accel_y")
    bad = tmp_path / "session.csv"
    bad.write_text("\n".join(src) + "\n")
    s = settings("imucal_ferraris_A", file=str(bad))
    with pytest.raises(ImportDataError) as e:
        importers.import_dataset(s)
    msg = str(e.value)
    assert str(bad) in msg and "'header'" in msg and "acc_y" in msg and "accel_y" in msg


def test_contradictory_units():
    # m s-2 data declared as g: the gravity norm is ~9.8 'g'
    s = settings("mikoff_imu0")
    s["accel"] = dict(s["accel"], units="g")
    with pytest.raises(ImportDataError) as e:
        importers.import_dataset(s)
    assert "imu0.log" in str(e.value) and "accel.units" in str(e.value) and "'m s-2'" in str(e.value)
    # deg s-1 turns declared as rad s-1: 360 deg would be ~21000 deg
    s = settings("imucal_ferraris_A")
    s["gyro"] = dict(s["gyro"], units="rad s-1")
    with pytest.raises(ImportDataError, match=r"gyro\.units.*'deg s-1'"):
        importers.import_dataset(s)
    # imucal's example script passes 204.8 Hz; at that rate the 360 deg turns would be ~180 deg
    with pytest.raises(ImportDataError, match="gyro.units"):
        importers.import_dataset(settings("imucal_ferraris_A", sample_rate_hz=204.8))
    # the wrong sense of turn
    s = settings("imucal_ferraris_B")
    s["rotation"] = dict(s["rotation"], sign=-1)
    with pytest.raises(ImportDataError, match=r"rotation\.sign.*set rotation\.sign: \+1"):
        importers.import_dataset(s)


def test_mismatched_imu_tk_timestamps(tmp_path):
    acc = _data_lines(DATA / "imu_tk_xsens" / "xsens_acc.mat")[:3000]
    gyr = _data_lines(DATA / "imu_tk_xsens" / "xsens_gyro.mat")[:3000]
    f = gyr[999].split()
    f[0] = f"{float(f[0]) + 0.002:e}"
    gyr[999] = "   ".join(f)
    pa, pg = tmp_path / "a.mat", tmp_path / "g.mat"
    pa.write_text("\n".join(acc) + "\n")
    pg.write_text("\n".join(gyr) + "\n")
    s = settings("imu_tk_xsens", files={"accel": str(pa), "gyro": str(pg)})
    with pytest.raises(ImportDataError) as e:
        importers.import_dataset(s)
    msg = str(e.value)
    assert str(pa) in msg and str(pg) in msg and "'timestamp'" in msg and "row 1000" in msg
    # and different lengths
    pg.write_text("\n".join(_data_lines(DATA / "imu_tk_xsens" / "xsens_gyro.mat")[:2999]) + "\n")
    with pytest.raises(ImportDataError, match="row counts differ"):
        importers.import_dataset(s)


def test_settings_errors_and_no_half_written_file(tmp_path):
    with pytest.raises(ImportDataError, match="latitude_deg"):
        s = settings("mikoff_imu0")
        del s["latitude_deg"]
        importers.import_dataset(s)
    with pytest.raises(ImportDataError, match="'sample_rate_hz'"):
        s = settings("mikoff_imu0")
        del s["sample_rate_hz"]
        importers.import_dataset(s)
    with pytest.raises(ImportDataError, match="unknown key"):
        importers.import_dataset(settings("mikoff_imu0", lattitude_deg=45.0))
    with pytest.raises(ImportDataError, match="rotation.rate_deg_s"):
        s = settings("imucal_ferraris_B")
        s["rotation"] = {"angle_deg": 360, "sign": 1}
        importers.import_dataset(s)
    with pytest.raises(ImportDataError) as e:
        importers.import_dataset(settings("mikoff_imu0", file="mikoff_mpu9150/imu9.log"))
    assert "imu9.log" in str(e.value) and "not found" in str(e.value)
    with pytest.raises(ImportDataError, match="Gyro. W"):
        s = settings("smac_adis16405")
        s["gyro"] = dict(s["gyro"], columns=["Gyro. X", "Gyro. Y", "Gyro. W"])
        importers.import_dataset(s)
    # a failed import leaves an existing output untouched and no temporary file behind
    out = tmp_path / "rec.nc"
    out.write_bytes(b"previous")
    s = settings("mikoff_imu0")
    s["accel"] = dict(s["accel"], units="g")
    with pytest.raises(ImportDataError):
        importers.import_recording(s, out)
    assert out.read_bytes() == b"previous" and sorted(p.name for p in tmp_path.iterdir()) == ["rec.nc"]
