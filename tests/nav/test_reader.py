"""The chunk-aligned, overlapped reader of long recordings (calib.nav.reader): the same samples as the plain
reader of calib.io.recording, bit for bit, whatever the slice size, range, file layout or dtype; slices on the
file's chunk boundaries; errors raised in the calling thread; and the simulator's file chunking."""
from __future__ import annotations

import threading

import netCDF4
import numpy as np
import pytest

from calib.io import recording
from calib.io.recording import RecordingError
from calib.nav import reader
from calib.sim.static_session import simulate_static_session, time_chunking

FS = 100.0
N = 10_007  # not a multiple of the file chunks


def _write(path, dtype="f8", chunk=1000, n=N):
    rng = np.random.default_rng(5)
    acc = rng.normal(0.0, 1.0, (n, 3))
    gyr = rng.normal(0.0, 1e-6, (n, 3))
    if dtype == "i4":
        acc, gyr = np.rint(acc * 1e5).astype(np.int32), np.rint(gyr * 1e9).astype(np.int32)
    units = ("count", "count") if dtype == "i4" else ("m s-1", "rad")
    with recording.LongRecordingWriter(path, n, FS, latitude_deg=30.58, accel_units=units[0], gyro_units=units[1],
                                       dtype=dtype, chunk_samples=chunk) as w:
        for i0 in range(0, n, 3333):
            w.append(acc[i0:i0 + 3333], gyr[i0:i0 + 3333])
    return path


def _plain(path, start=0, stop=None):
    """The samples of ``[start, stop)`` read in one piece by the netCDF library itself (no slicing of ours)."""
    import netCDF4

    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        return (np.asarray(nc.variables["accel"][start:stop], dtype=np.float64),
                np.asarray(nc.variables["gyro"][start:stop], dtype=np.float64))


def _joined(chunks):
    chunks = list(chunks)
    idx = [i0 for i0, _, _ in chunks]
    return idx, np.vstack([a for _, a, _ in chunks]), np.vstack([g for _, _, g in chunks])


@pytest.mark.parametrize("dtype", ["f8", "i4"])
@pytest.mark.parametrize("target", [None, 1, 999, 2_500, 10**6])
@pytest.mark.parametrize("start,stop", [(0, None), (1_234, 8_765), (5_000, 6_000), (10_000, None)])
def test_same_samples_as_the_plain_reader(tmp_path, dtype, target, start, stop):
    path = _write(tmp_path / "r.nc", dtype)
    h = recording.read_header(path)
    idx, acc, gyr = _joined(reader.iter_raw_chunks(path, h, chunk=target, start=start, stop=stop))
    ea, eg = _plain(path, start, stop)
    assert acc.dtype == gyr.dtype == np.float64
    np.testing.assert_array_equal(acc, ea)
    np.testing.assert_array_equal(gyr, eg)
    assert idx[0] == start
    assert all(i % 1000 == 0 for i in idx[1:])  # every later slice starts on a file chunk boundary


def test_slices_are_whole_file_chunks_of_about_the_target():
    b = recording.slice_bounds(1000, 0, 10_007, 2_400)
    assert b[0] == (0, 2000) and b[-1] == (10_000, 10_007) and all(i1 - i0 == 2000 for i0, i1 in b[:-1])
    assert recording.slice_bounds(1000, 1_500, 4_000, 1) == [(1_500, 2_000), (2_000, 3_000), (3_000, 4_000)]
    assert recording.slice_bounds(None, 0, 10, 4) == [(0, 4), (4, 8), (8, 10)]
    assert recording.slice_bounds(1000, 5, 5, 100) == []


def test_contiguous_layout(tmp_path):
    src = _write(tmp_path / "chunked.nc")
    dst = tmp_path / "contiguous.nc"
    with netCDF4.Dataset(src) as s, netCDF4.Dataset(dst, "w") as d:
        s.set_auto_mask(False)
        d.setncatts({k: s.getncattr(k) for k in s.ncattrs()})
        for name, dim in s.dimensions.items():
            d.createDimension(name, len(dim))
        for name in ("accel", "gyro"):
            v = d.createVariable(name, "f8", ("time", "axis"), contiguous=True)
            v.setncatts({k: s[name].getncattr(k) for k in s[name].ncattrs()})
            v[:] = s[name][:]
    with netCDF4.Dataset(dst) as d:
        assert d["gyro"].chunking() == "contiguous"
    idx, acc, gyr = _joined(reader.iter_raw_chunks(dst, chunk=3_000))
    assert idx == [0, 3_000, 6_000, 9_000]
    ea, eg = _plain(src)
    np.testing.assert_array_equal(acc, ea)
    np.testing.assert_array_equal(gyr, eg)


@pytest.mark.parametrize("overlap", [True, False])
def test_for_each_chunk_calls_in_order_with_progress(tmp_path, overlap):
    path = _write(tmp_path / "r.nc")
    seen, prog, threads = [], [], set()

    def fn(i0, acc, gyr):
        threads.add(threading.get_ident())
        seen.append((i0, acc.copy(), gyr.copy()))

    reader.for_each_chunk(path, fn, chunk=2_000, start=10, stop=9_999, progress=prog.append, overlap=overlap)
    idx, acc, gyr = _joined(seen)
    ea, eg = _plain(path, 10, 9_999)
    np.testing.assert_array_equal(acc, ea)
    np.testing.assert_array_equal(gyr, eg)
    assert idx == [10, 2_000, 4_000, 6_000, 8_000] and prog == [2_000, 4_000, 6_000, 8_000, 9_999]
    assert (threading.get_ident() in threads) != overlap  # overlapped: the work runs in a worker thread


def test_an_error_of_the_function_is_raised_here_and_no_thread_is_left(tmp_path):
    path = _write(tmp_path / "r.nc")
    before = threading.active_count()
    calls = []

    def fn(i0, acc, gyr):
        calls.append(i0)
        if i0 >= 4_000:
            raise ZeroDivisionError("in the worker")

    with pytest.raises(ZeroDivisionError, match="in the worker"):
        reader.for_each_chunk(path, fn, chunk=2_000)
    assert calls == [0, 2_000, 4_000] and threading.active_count() == before
    # the file was closed: it can be replaced and read again
    _write(path)
    assert len(list(reader.iter_raw_chunks(path, chunk=1_000))) == 11


def test_unreadable_file_raises_a_recording_error(tmp_path):
    good = _write(tmp_path / "good.nc", n=200_000, chunk=50_000)
    h = recording.read_header(good)
    bad = tmp_path / "bad.nc"
    bad.write_bytes(good.read_bytes()[: good.stat().st_size // 2])  # truncated
    with pytest.raises(RecordingError, match="bad.nc"):
        reader.for_each_chunk(bad, lambda *a: None, h)


def test_time_chunking_splits_evenly_with_little_padding():
    assert time_chunking(86_400_000, 1 << 20) == 1_040_964  # 83 chunks, the last 12 samples short
    assert time_chunking(10, 1 << 20) == 10
    assert time_chunking(90_000, 7_777) == 7_500
    for n, t in ((86_400_000, 1 << 20), (90_001, 7_777), (5, 2)):
        c = time_chunking(n, t)
        k = -(-n // c)
        assert c <= max(t, 1) and k * c - n < k


def test_static_session_file_chunks_and_same_bytes(tmp_path):
    cfg = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "duration_h": 0.05, "sample_rate_hz": 100.0,
           "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}}
    a = simulate_static_session(cfg, 4, tmp_path / "a.nc", prov={"made_by_rule": "test"},
                                chunk_samples=5_000)
    b = simulate_static_session(cfg, 4, tmp_path / "b.nc", prov={"made_by_rule": "test"},
                                chunk_samples=5_000)
    assert a.read_bytes() == b.read_bytes()  # same configuration, same bytes
    with netCDF4.Dataset(a) as nc:
        assert nc["gyro"].chunking() == nc["accel"].chunking() == [4_500, 3]  # 18,000 samples in 4 chunks
