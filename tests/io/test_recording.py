"""The calib-recording-1 format: broken files are refused with a message naming the file and the variable;
a written recording reads back unchanged; the long-file writer never leaves a partial file behind; within
``reuse_validation`` an unchanged file is read sample by sample once."""
from __future__ import annotations

import os

import numpy as np
import pytest
import xarray as xr

from calib.io import recording, validation
from calib.io.netcdf import write_netcdf

N = 400
FS = 100.0


def good_dataset(seed=0) -> xr.Dataset:
    rng = np.random.default_rng(seed)
    acc = rng.integers(-200, 200, size=(N, 3)).astype(np.int32)
    gyr = rng.integers(-5000, 5000, size=(N, 3)).astype(np.int32)
    seg_idx = np.full(N, -1)
    seg_idx[10:150] = 0
    seg_idx[200:390] = 1
    segments = {"segment_kind": ["static", "rotation"], "segment_label": ["P1-POS1", "ROT-z+10"],
                "rotation_axis": np.array([[1.0, 0, 0], [0, 0, 1.0]]), "rotation_rate": np.array([0.0, 10.0]),
                "nominal_attitude": np.array([np.eye(3), np.eye(3)])}
    return recording.make_dataset(acc, gyr, sample_rate_hz=FS, latitude_deg=30.58, height_m=12.0,
                                  accel_units="count", gyro_units="count", accel_kind="increment",
                                  gyro_kind="increment", source="synthetic", sensor="test unit",
                                  temperature=np.linspace(20, 21, N), segment_index=seg_idx, segments=segments,
                                  table_angle=np.zeros(N))


def refused(ds, tmp_path, variable, match):
    """Write ``ds`` without validation, then check validate and load both refuse it."""
    path = write_netcdf(ds, tmp_path / "bad.nc")
    for fn in (recording.validate, recording.load):
        with pytest.raises(recording.RecordingError, match=match) as ei:
            fn(path)
        assert ei.value.variable == variable
        assert str(path) in str(ei.value) and f"variable '{variable}'" in str(ei.value)


def test_round_trip(tmp_path):
    ds = good_dataset()
    path = recording.write(ds, tmp_path / "ok.nc", {"made_by_rule": "test", "seed": 3})
    back = recording.load(path)
    for v in ("accel", "gyro"):
        assert back[v].dtype == np.int32
        np.testing.assert_array_equal(back[v].values, ds[v].values)
        assert back[v].attrs["units"] == "count" and back[v].attrs["sample_kind"] == "increment"
    for v in ("temperature", "segment_index", "table_angle", "rotation_axis", "rotation_rate", "nominal_attitude"):
        np.testing.assert_array_equal(back[v].values, ds[v].values)
    assert list(back["segment_label"].values) == ["P1-POS1", "ROT-z+10"]
    np.testing.assert_allclose(back["time"].values, np.arange(N) / FS)
    assert back.attrs["latitude_deg"] == 30.58 and back.attrs["height_m"] == 12.0
    assert back.attrs["made_by_rule"] == "test" and back.attrs["seed"] == 3
    h = recording.read_header(path)
    assert (h.n_samples, h.sample_rate_hz, h.accel_kind, h.gyro_units) == (N, FS, "increment", "count")


def test_missing_variable(tmp_path):
    refused(good_dataset().drop_vars("gyro"), tmp_path, "gyro", "variable missing")


def test_unknown_units(tmp_path):
    ds = good_dataset()
    ds["accel"].attrs["units"] = "furlong"
    refused(ds, tmp_path, "accel", "units='furlong' not allowed")


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_inf_in_accel(tmp_path, bad):
    ds = good_dataset()
    acc = ds["accel"].values.astype(float)
    acc[17, 1] = bad
    ds["accel"] = (("time", "axis"), acc, ds["accel"].attrs)
    refused(ds, tmp_path, "accel", "NaN or Inf at sample 17")


def test_time_not_increasing(tmp_path):
    ds = good_dataset()
    t = ds["time"].values.copy()
    t[10] = t[9]
    ds = ds.assign_coords(time=("time", t, ds["time"].attrs))
    refused(ds, tmp_path, "time", "not strictly increasing at sample 10")


def test_wrong_shape_transposed(tmp_path):
    ds = good_dataset()
    ds["gyro"] = ds["gyro"].transpose("axis", "time")
    refused(ds, tmp_path, "gyro", r"dimensions \('axis', 'time'\), expected \('time', 'axis'\)")


def test_wrong_shape_two_axes(tmp_path):
    ds = good_dataset().isel(axis=slice(0, 2))
    refused(ds, tmp_path, "axis", "length 2, expected 3")


def test_missing_latitude(tmp_path):
    ds = good_dataset()
    del ds.attrs["latitude_deg"]
    refused(ds, tmp_path, "latitude_deg", "required global attribute missing")


@pytest.mark.parametrize("rate", [0.0, np.nan])
def test_rotation_segment_without_rate(tmp_path, rate):
    ds = good_dataset()
    rr = ds["rotation_rate"].values.copy()
    rr[1] = rate
    ds["rotation_rate"] = (("segment",), rr, ds["rotation_rate"].attrs)
    refused(ds, tmp_path, "rotation_rate", "rotation segment 1 has no rate")


def test_rotation_segments_without_rate_variable(tmp_path):
    refused(good_dataset().drop_vars("rotation_rate"), tmp_path, "rotation_rate", "no rates")


@pytest.mark.parametrize("keep", [0.999, 0.5, 0.05])
def test_truncated_file(tmp_path, keep):
    path = recording.write(good_dataset(), tmp_path / "whole.nc")
    blob = path.read_bytes()
    cut = tmp_path / "cut.nc"
    cut.write_bytes(blob[:int(len(blob) * keep)])
    assert len(cut.read_bytes()) < len(blob)
    for fn in (recording.validate, recording.load, recording.read_header):
        with pytest.raises(recording.RecordingError, match="truncated or not netCDF") as ei:
            fn(cut)
        assert str(cut) in str(ei.value)


def _writer(path, n=1000, **kw):
    return recording.LongRecordingWriter(path, n, FS, latitude_deg=30.58, accel_units="m s-1", gyro_units="rad",
                                         chunk_samples=256, **kw)


def test_long_writer_success(tmp_path):
    path = tmp_path / "long.nc"
    rng = np.random.default_rng(1)
    a, g, t = rng.normal(size=(1000, 3)), rng.normal(size=(1000, 3)), rng.normal(25.0, 1.0, 1000)
    with _writer(path, temperature=True) as w:
        for i0 in range(0, 1000, 300):
            w.append(a[i0:i0 + 300], g[i0:i0 + 300], t[i0:i0 + 300])
    h = recording.validate(path)
    assert not h.has_time and h.n_samples == 1000
    ds = recording.load(path)
    np.testing.assert_array_equal(ds["accel"].values, a)
    np.testing.assert_array_equal(ds["gyro"].values, g)
    np.testing.assert_allclose(ds["temperature"].values, t.astype(np.float32))
    np.testing.assert_allclose(ds["time"].values, np.arange(1000) / FS)


def _leftovers(d):
    return sorted(p.name for p in d.iterdir())


def test_long_writer_leaves_no_file_on_exception(tmp_path):
    path = tmp_path / "long.nc"
    with pytest.raises(RuntimeError, match="boom"):
        with _writer(path) as w:
            w.append(np.zeros((100, 3)), np.zeros((100, 3)))
            raise RuntimeError("boom")
    assert _leftovers(tmp_path) == []


def test_long_writer_leaves_no_file_when_short_or_overflowing(tmp_path):
    path = tmp_path / "long.nc"
    with pytest.raises(ValueError, match="closed after 100 of 1000 samples"):
        with _writer(path) as w:
            w.append(np.zeros((100, 3)), np.zeros((100, 3)))
    assert _leftovers(tmp_path) == []
    with pytest.raises(ValueError, match="writer overflow"):
        with _writer(path, n=50) as w:
            w.append(np.zeros((100, 3)), np.zeros((100, 3)))
    assert _leftovers(tmp_path) == []
    with pytest.raises(ValueError, match="temperature"):
        with _writer(path, n=10) as w:
            w.append(np.zeros((10, 3)), np.zeros((10, 3)), np.zeros(10))  # opened without temperature
    assert _leftovers(tmp_path) == []


def test_sample_time_convention(tmp_path):
    """The three declared conventions are read; any other value is refused naming the attribute and the choices."""
    for conv in recording.SAMPLE_TIME_CONVENTIONS:
        ds = good_dataset()
        ds.attrs["sample_time_convention"] = conv
        assert recording.load(recording.write(ds, tmp_path / f"{conv}.nc")).attrs["sample_time_convention"] == conv
    ds = good_dataset()
    ds.attrs["sample_time_convention"] = "middle"
    path = write_netcdf(ds, tmp_path / "bad.nc")
    with pytest.raises(recording.RecordingError, match="interval_start, interval_centre, interval_end"):
        recording.validate(path)


# --------------------------------------------------------------------------- recording.reuse_validation: within the
# block a file is checked sample by sample once, a file that changed since is checked again (and refused when
# broken); outside it every call checks in full


@pytest.fixture
def counted(monkeypatch):
    """Paths whose samples :func:`recording.validate` read, in order."""
    calls = []
    body = validation._validate_body

    def counting(path, h, *rest):
        calls.append(str(path))
        return body(path, h, *rest)

    monkeypatch.setattr(validation, "_validate_body", counting)
    return calls


def test_each_file_is_read_once_within_the_block(tmp_path, counted):
    a = recording.write(good_dataset(1), tmp_path / "a.nc")
    b = recording.write(good_dataset(2), tmp_path / "b.nc")
    counted.clear()
    with recording.reuse_validation():
        ha = recording.validate(a)
        hb = recording.validate(b)
        assert recording.validate(a) == ha and recording.validate(b) == hb
        ds = recording.load(a)
        np.testing.assert_array_equal(ds["accel"].values, good_dataset(1)["accel"].values)
        assert recording.validate(os.path.relpath(a)) == ha   # the same file by another name
    assert counted == [str(a), str(b)]


def test_outside_the_block_every_call_reads_the_samples(tmp_path, counted):
    a = recording.write(good_dataset(1), tmp_path / "a.nc")
    counted.clear()
    recording.validate(a)
    recording.load(a)
    with recording.reuse_validation():
        recording.validate(a)
    recording.validate(a)
    assert counted == [str(a)] * 4


def test_blocks_nest_and_forget_on_exit(tmp_path, counted):
    a = recording.write(good_dataset(1), tmp_path / "a.nc")
    counted.clear()
    with recording.reuse_validation():
        recording.validate(a)
        with recording.reuse_validation():
            recording.validate(a)
        recording.validate(a)   # the inner block's end keeps what the outer one knows
    with recording.reuse_validation():
        recording.validate(a)   # a new block checks again
    assert counted == [str(a)] * 2


def test_a_changed_file_is_checked_again_and_refused(tmp_path, counted):
    path = recording.write(good_dataset(1), tmp_path / "a.nc")
    with recording.reuse_validation():
        recording.validate(path)
        ds = good_dataset(1)
        acc = ds["accel"].values.astype(float)
        acc[17, 1] = np.nan
        ds["accel"] = (("time", "axis"), acc, ds["accel"].attrs)
        st = os.stat(path)
        write_netcdf(ds, path)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))   # changed, whatever the clock's grain
        with pytest.raises(recording.RecordingError, match="NaN or Inf at sample 17"):
            recording.validate(path)
        with pytest.raises(recording.RecordingError, match="NaN or Inf at sample 17"):
            recording.load(path)


def test_a_refused_file_is_refused_every_time(tmp_path, counted):
    ds = good_dataset(1)
    ds["accel"].attrs["units"] = "furlong"
    path = write_netcdf(ds, tmp_path / "bad.nc")
    with recording.reuse_validation():
        for _ in range(2):
            with pytest.raises(recording.RecordingError, match="units='furlong' not allowed"):
                recording.validate(path)
        with pytest.raises(recording.RecordingError, match="file not found"):
            recording.validate(tmp_path / "missing.nc")


def test_the_header_given_back_is_a_copy(tmp_path):
    path = recording.write(good_dataset(1), tmp_path / "a.nc")
    with recording.reuse_validation():
        h = recording.validate(path)
        h.attrs["sensor"] = "changed by the caller"
        assert recording.validate(path).attrs["sensor"] == "test unit"


# ------------------------------------------------------------------ the segment table and temperature, read whole


def test_unknown_segment_kind(tmp_path):
    ds = good_dataset()
    ds["segment_kind"] = (("segment",), np.array(["static", "spinning"], dtype=object), ds["segment_kind"].attrs)
    refused(ds, tmp_path, "segment_kind", "segment 1 has kind 'spinning'")


@pytest.mark.parametrize("bad, slice_", [(2, None), (-2, None), (2, 64), (-2, 299)])
def test_segment_index_outside_the_table(tmp_path, monkeypatch, bad, slice_):
    """Refused wherever it lies, also when the check reads the index in slices of ``slice_`` samples."""
    if slice_ is not None:
        monkeypatch.setattr(validation, "PER_SAMPLE_SLICE", slice_)
    ds = good_dataset()
    si = ds["segment_index"].values.copy()
    si[300] = bad
    ds["segment_index"] = (("time",), si, ds["segment_index"].attrs)
    refused(ds, tmp_path, "segment_index", r"values must lie in -1\.\.1")


def test_segment_index_on_the_wrong_dimension(tmp_path):
    ds = good_dataset()
    ds["segment_index"] = (("segment",), np.array([0, 1]), {})
    refused(ds, tmp_path, "segment_index", r"dimensions \('segment',\), expected \('time',\)")


def test_segment_kind_missing_beside_a_segment_table(tmp_path):
    refused(good_dataset().drop_vars("segment_kind"), tmp_path, "segment_kind", "segment table present")


@pytest.mark.parametrize("how, slice_", [("nan", None), ("fill", None), ("nan", 50), ("fill", 7)])
def test_temperature_with_a_missing_sample(tmp_path, monkeypatch, how, slice_):
    """A NaN temperature, and one equal to the variable's _FillValue (written by netCDF4 itself, so the check
    sees a masked sample as xarray would decode it: NaN), are refused naming the sample -- also when the check reads
    the temperature in slices (``slice_`` samples at a time) and the sample lies in a later slice."""
    if slice_ is not None:
        monkeypatch.setattr(validation, "PER_SAMPLE_SLICE", slice_)
    ds = good_dataset()
    path = write_netcdf(ds, tmp_path / "bad.nc")
    import netCDF4

    with netCDF4.Dataset(path, "a") as nc:
        v = nc.variables["temperature"]
        v.set_auto_mask(False)
        v[123] = np.nan if how == "nan" else v.getncattr("_FillValue")
    for fn in (recording.validate, recording.load):
        with pytest.raises(recording.RecordingError, match="NaN or Inf at sample 123") as ei:
            fn(path)
        assert ei.value.variable == "temperature"


def test_values_read_without_xarray_decode_as_xarray_does(tmp_path):
    """float_values / string_values / index_values (the check's reading with netCDF4 alone) against xarray's own
    decoding: a packed variable (scale_factor, add_offset) with _FillValue and missing_value samples, strings, and an
    integer index with a _FillValue sample (-1 where xarray has NaN, in the variable's own integer type)."""
    import netCDF4

    from calib.io.netcdf import float_values, index_values, string_values

    path = tmp_path / "packed.nc"
    with netCDF4.Dataset(path, "w") as nc:
        nc.createDimension("n", 6)
        v = nc.createVariable("packed", "i2", ("n",), fill_value=-999)
        v.setncatts({"scale_factor": 0.5, "add_offset": 10.0, "missing_value": np.int16(-998)})
        v.set_auto_maskandscale(False)
        v[:] = np.array([0, 1, -999, 7, -998, 100], np.int16)
        s = nc.createVariable("names", str, ("n",))
        s[:] = np.array(["static", "rotation", "a", "", "b c", "static"], dtype=object)
        i = nc.createVariable("index", "i4", ("n",), fill_value=-2147483647)
        i[:] = np.ma.masked_array([0, 0, 1, 1, 5, -1], mask=[0, 0, 0, 0, 1, 0])
    with pytest.warns(xr.SerializationWarning, match="multiple fill values"), \
            xr.open_dataset(path, engine="netcdf4") as ds:
        want_f, want_s = ds["packed"].values, [str(x) for x in ds["names"].values]
        want_i = ds["index"].values
    with netCDF4.Dataset(path) as nc:
        got_f, got_s = float_values(nc.variables["packed"]), string_values(nc.variables["names"])
        got_i = index_values(nc.variables["index"])
    np.testing.assert_array_equal(got_f, want_f)   # NaN where xarray has NaN
    np.testing.assert_array_equal(got_f, [10.0, 10.5, np.nan, 13.5, np.nan, 60.0])
    assert got_s == want_s
    assert got_i.dtype == np.int32 and got_i.tolist() == [0, 0, 1, 1, -1, -1]
    np.testing.assert_array_equal(np.where(np.isnan(want_i), -1, want_i), got_i)


def test_the_check_of_a_recording_imports_neither_xarray_nor_pandas(tmp_path):
    """The whole check of a recording (header, segment table, every sample, plausibility -- what calib validate,
    calib diagnose and calib navigate run first) without xarray and pandas: their import is 0.3 s of every such
    process. Run in a fresh interpreter; fails if any module on the path imports them."""
    import subprocess
    import sys

    path = recording.write(good_dataset(2), tmp_path / "ok.nc")
    code = ("import sys\nfrom calib.cli.shared import check_recording\n"
            f"h, plausible = check_recording({str(path)!r}, True, 'recording')\n"
            "assert h.n_samples == %d, h.n_samples\n"
            "print(sorted(m for m in ('xarray', 'pandas') if m in sys.modules))\n" % N)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def _same_as_load(path):
    """load_arrays(path) against load(path): names, sizes, global and variable attributes, dimensions, and values
    with their dtype (NaN where load has NaN)."""
    arr, ds = recording.load_arrays(path), recording.load(path)
    assert isinstance(arr, recording.RecordingArrays)
    assert sorted(arr.variables) == sorted(ds.variables)
    assert arr.sizes == dict(ds.sizes) and sorted(arr.coords) == sorted(ds.coords)
    assert arr.attrs.keys() == ds.attrs.keys()
    for k, v in ds.attrs.items():
        np.testing.assert_array_equal(arr.attrs[k], v)
    for name in ds.variables:
        got, want = arr[name], ds[name]
        assert got.dims == want.dims and got.attrs.keys() == want.attrs.keys(), name
        for k, v in want.attrs.items():
            np.testing.assert_array_equal(got.attrs[k], v, err_msg=f"{name}: {k}")
        assert got.values.dtype == want.values.dtype, (name, got.values.dtype, want.values.dtype)
        np.testing.assert_array_equal(got.values, want.values, err_msg=name)
    return arr


def test_load_arrays_reads_what_load_reads(tmp_path):
    """calib diagnose reads its recording with netCDF4 alone (recording.load_arrays: no xarray, no pandas in its
    process). Every variable, attribute and dimension as xarray's load gives them: a session with a segment table
    (integer counts, strings, float temperature), extra variables with _FillValue / missing_value samples (NaN;
    integers become float32 or float64 as in xarray), a valid_range that netCDF4 alone would mask and xarray keeps,
    and a long file without a time variable (time from t0_s and sample_rate_hz)."""
    import netCDF4

    path = recording.write(good_dataset(4), tmp_path / "ok.nc")
    with netCDF4.Dataset(path, "a") as nc:
        f = nc.createVariable("extra_float", "f4", ("segment",), fill_value=np.float32(-1.0))
        f.set_auto_maskandscale(False)
        f[:] = np.array([-1.0, 2.5], np.float32)
        i = nc.createVariable("extra_int", "i4", ("segment",), fill_value=np.int32(-9))
        i.setncattr("missing_value", np.int32(-8))
        i.set_auto_maskandscale(False)
        i[:] = np.array([-8, 3], np.int32)
        i2 = nc.createVariable("extra_short", "i2", ("segment",), fill_value=np.int16(-7))
        i2[:] = np.ma.masked_array([4, 0], mask=[0, 1])
        r = nc.createVariable("extra_range", "f8", ("segment",))
        r.setncattr("valid_range", np.array([0.0, 1.0]))
        r.set_auto_maskandscale(False)
        r[:] = np.array([0.5, 7.0])
    with pytest.warns(xr.SerializationWarning, match="multiple fill values"):
        arr = _same_as_load(path)
    assert np.isnan(arr["extra_float"].values[0]) and arr["extra_int"].values.dtype == np.float64
    assert arr["extra_short"].values.dtype == np.float32 and np.isnan(arr["extra_short"].values[1])
    assert arr["extra_range"].values.tolist() == [0.5, 7.0]
    assert arr.attrs["_path"] == str(path) and arr["gyro"].attrs["units"] == "count"

    rng = np.random.default_rng(5)
    long_path = tmp_path / "long.nc"
    with recording.LongRecordingWriter(long_path, 500, 200.0, latitude_deg=45.0, accel_units="m s-1",
                                       gyro_units="rad", dtype="f4", t0_s=3.0, temperature=True) as w:
        w.append(rng.normal(0, 0.05, (500, 3)) + [0, 0, 0.049], rng.normal(0, 1e-5, (500, 3)),
                 np.full(500, 21.5))
    arr = _same_as_load(long_path)
    assert "time" in arr.coords
    np.testing.assert_allclose(arr["time"].values, 3.0 + np.arange(500) / 200.0)
    assert arr["accel"].values.dtype == np.float32


def test_load_arrays_leaves_what_needs_more_decoding_to_xarray(tmp_path):
    """A packed variable (scale_factor: the float type of its values follows xarray's rules), a duration in
    'seconds' (xarray makes time deltas of it) or a character array (xarray joins its last dimension into strings
    and drops it) is read by xarray's load: the same values either way. A dimension no variable uses is not in the
    sizes, as in xarray."""
    import netCDF4

    for k, (attr, value) in enumerate((("scale_factor", 0.5), ("units", "seconds"), ("_Encoding", "utf-8"))):
        path = recording.write(good_dataset(6), tmp_path / f"needs_{k}.nc")
        with netCDF4.Dataset(path, "a") as nc:
            if attr == "_Encoding":
                nc.createDimension("chars", 4)
                v = nc.createVariable("extra", "S1", ("segment", "chars"))
                v.setncattr(attr, value)
                v[:] = netCDF4.stringtochar(np.array(["ab", "cdef"], dtype="S4"))
            else:
                v = nc.createVariable("extra", "i2", ("segment",))
                v.setncattr(attr, value)
                v[:] = np.array([1, 2], np.int16)
        got, want = recording.load_arrays(path), recording.load(path)
        assert isinstance(got, xr.Dataset)
        xr.testing.assert_identical(got, want)
    path = recording.write(good_dataset(6), tmp_path / "unused_dimension.nc")
    with netCDF4.Dataset(path, "a") as nc:
        nc.createDimension("unused", 5)
    arr = _same_as_load(path)
    assert "unused" not in arr.sizes


def test_calib_diagnose_imports_neither_xarray_nor_pandas(tmp_path):
    """calib diagnose of a recording with a segment table, with a noise record, runs without xarray and pandas
    (their import is 0.3 s of a 2 s cold command). Run as the command runs, in a fresh interpreter, the figures
    drawn; fails if any module on its path imports them."""
    import subprocess
    import sys

    from calib.sim.calibration_session import simulate_calibration_session
    from calib.sim.static_session import simulate_static_session

    rec = simulate_calibration_session({"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0,
                                        "revolutions": 1}, 8, tmp_path / "s.nc")
    nr = tmp_path / "nr.nc"
    simulate_static_session({"mode": "counts", "duration_h": 0.2, "sample_rate_hz": 100.0,
                             "site": {"latitude_deg": 30.58, "height_m": 0.0},
                             "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}},
                            3, nr, tmp_path / "nr.truth.json")
    log = tmp_path / "modules.txt"
    code = ("import atexit, sys\n"
            "def spy():\n"
            f"    open({str(log)!r}, 'a').write(' '.join(m for m in ('xarray', 'pandas') if m in sys.modules) + '|')\n"
            "atexit.register(spy)\n"
            "from calib import cli\n"
            f"sys.argv = ['calib', 'diagnose', {str(rec)!r}, '--noise-record', {str(nr)!r}, '--out', "
            f"{str(tmp_path / 'out')!r}]\n"
            "cli.run()\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode in (0, 1, 3), out.stderr
    assert (tmp_path / "out" / "report.json").exists() and (tmp_path / "out" / "allan_deviation.png").exists()
    seen = log.read_text().split("|")[:-1]
    assert seen == [""], seen   # the command's exit, its figures drawn
