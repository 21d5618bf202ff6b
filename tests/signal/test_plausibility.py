"""The limits of calib.signal.plausibility on known values, and the error hierarchy it raises."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calib.core import earth
from calib.core.errors import CalibError, InputError, ResultCheckError
from calib.io.recording import RecordingError
from calib.signal import plausibility as pl


def test_error_hierarchy_and_exit_codes():
    assert issubclass(RecordingError, InputError) and issubclass(RecordingError, ValueError)
    assert InputError("x").exit_code == 2 and ResultCheckError("x").exit_code == 3
    e = CalibError("what", file="f.nc", field="accel", fix="do this")
    assert str(e) == "f.nc: accel: what (fix: do this)"
    r = RecordingError("f.nc", "time", "a gap", "split it")
    assert (r.file, r.field, r.fix, r.exit_code) == ("f.nc", "variable 'time'", "split it", 2)
    assert str(r) == "f.nc: variable 'time': a gap -- fix: split it"


@pytest.mark.parametrize("scale, bias, counts, problem", [
    ([1.0, 1.01, 0.99], [0.3, -0.2, 0.1], False, None),               # a MEMS accelerometer
    ([0.4, 1.0, 1.0], [0.0, 0.0, 0.0], False, "scale factor x = 0.4 outside [0.5, 2]"),
    ([1.0, 1.0, 1.0], [0.0, 2.5, 0.0], False, "accel bias 2.5 m s-2 above 2 m s-2"),
    ([414.5, 412.0, 414.6], None, True, None),                          # IMU-TK's Xsens, counts per m s-2
    ([414.5, 412.0, 1300.0], None, True, "differ by more than a factor 2"),
    ([np.nan, 1.0, 1.0], None, False, "not finite"),
])
def test_accelerometer_result_limits(scale, bias, counts, problem):
    out = pl.check_triad_result("accel", scale, bias, counts=counts)
    assert (out == []) if problem is None else any(problem in p for p in out), out


def test_gyro_bias_limit_in_deg_s():
    mems = np.radians([1.3, -0.4, 0.9])          # the MPU-9150 recordings reach 1.3 deg/s: plausible
    assert pl.check_triad_result("gyro", [1.0, 1.0, 1.0], mems, counts=False) == []
    wrong = np.radians([1.3, -0.4, 0.9]) * 180.0 / math.pi   # the same numbers read as rad/s
    assert any("gyro bias 74.48 deg/s above 10 deg/s" in p for p in
               pl.check_triad_result("gyro", [1.0, 1.0, 1.0], wrong, counts=False))


def test_earth_rate_constant():
    assert pl.EARTH_RATE_DEG_H == pytest.approx(15.041, abs=1e-3)
    assert pl.ACCEL_BIAS_MAX_M_S2 == pytest.approx(0.2 * earth.STANDARD_GRAVITY, rel=0.02)


def test_block_statistics_are_the_plain_definitions():
    """The block means and scatter (norm of the per-axis standard deviation) of _Blocks, which sums axes-first for
    speed and is fed chunk by chunk, against numpy's plain definitions on the whole record laid out as recorded: the
    blocks are the record's ([0, w), [w, 2w), ...) whatever the chunks' lengths, its last incomplete block is left
    out, a NaN spoils only its own block."""
    rng = np.random.default_rng(5)
    w = 50
    chunks = [rng.normal([0.1, -0.2, 9.8], [1e-3, 2e-3, 3e-3], (n, 3)) for n in (1000, 777, 49, 1)]
    chunks[1][300, 2] = np.nan                              # sample 1300 of the record: block 26
    blocks = pl._Blocks(w)
    for x in chunks:
        blocks.add(pl._axes_first(x, 1.0))
    m, sd = blocks.arrays()
    x = np.concatenate(chunks)
    b = x[:len(x) // w * w].reshape(-1, w, 3)
    assert m.shape == (36, 3) and sd.shape == (36,) and len(x) == 1827
    np.testing.assert_allclose(m, b.mean(axis=1), rtol=1e-14)
    np.testing.assert_allclose(sd, np.linalg.norm(b.std(axis=1), axis=1), rtol=1e-12)
    assert np.isnan(sd[26]) and np.isfinite(np.delete(sd, 26)).all()
    np.testing.assert_allclose(np.sqrt(pl._squared_magnitude(pl._axes_first(chunks[0], 2.0))),
                               2.0 * np.linalg.norm(chunks[0], axis=1), rtol=1e-15)


def test_block_sums_of_squares_bound_the_samples():
    """_Blocks.add returns the largest sum of |x|^2 over the blocks it completed (the plain definition on the
    record's blocks, NaN when one holds a NaN) and where this chunk's samples outside them begin."""
    rng = np.random.default_rng(6)
    w = 50
    sizes = (1000, 777, 49, 1, 130)
    x = rng.normal([0.1, -0.2, 9.8], [1e-3, 2e-3, 3e-3], (sum(sizes), 3))
    ends = np.cumsum(sizes)
    blocks = pl._Blocks(w)
    got = [blocks.add(pl._axes_first(x[e - n:e], 1.0)) for n, e in zip(sizes, ends)]
    ss = np.einsum("ijk,ijk->i", *2 * [x[:len(x) // w * w].reshape(-1, w, 3)])   # sum |x|^2 per record block
    for (bound, end), n, e in zip(got, sizes, ends):
        done = [b for b in range(len(ss)) if e - n < (b + 1) * w <= e]             # blocks completed by this chunk
        assert bound == (pytest.approx(ss[done].max(), rel=1e-13) if done else -np.inf)
        assert end == (((e // w) * w - (e - n)) if done else 0)
    blocks = pl._Blocks(w)
    y = x[:100].copy()
    y[70, 1] = np.nan
    assert np.isnan(blocks.add(pl._axes_first(y, 1.0))[0])


def test_absurd_samples_are_found_wherever_the_chunks_cut_the_blocks(tmp_path):
    """The spike test decides from the block sums whether a chunk needs its samples tested one by one; spikes in a
    block straddling two chunks (on either side of the cut), inside a chunk, and in the record's last incomplete
    block: first index and count as numpy finds them on the whole record."""
    from calib.io import recording

    rng = np.random.default_rng(9)
    n, fs = 30_050, 100.0
    gyr = rng.normal(0, 1e-4, (n, 3)) + np.radians(15.04 / 3600) * np.array([0.0, 0.6, 0.8])
    acc = rng.normal(0, 1e-2, (n, 3)) + [0.0, 0.0, 9.79]
    spikes = {7_000: 1.5e4, 14_005: -2e4, 12_345: 2e4, 30_040: 3e4}    # chunks of 7001: cuts at 7001, 14002, ...
    for i, v in spikes.items():
        acc[i] = [0.0, v, 0.0]
    gyr[21_004] = [0.0, 0.0, np.radians(2e4)]                           # 2e4 deg/s, just after the cut at 21003
    ds = recording.make_dataset(acc, gyr, sample_rate_hz=fs, latitude_deg=30.0, accel_units="m s-2",
                                gyro_units="rad s-1", source="synthetic")
    path = recording.write(ds, tmp_path / "r.nc")
    h = recording.read_header(path)
    check = pl.RecordingCheck(path, h, force=True)
    for i0, a, g in recording.iter_raw_chunks(path, h, chunk=7_001):
        check.add(i0, a, g)
    res = check.finish()
    for name, x, limit in (("accel", acc, pl.ABSURD_ACCEL_G * earth.STANDARD_GRAVITY),
                           ("gyro", gyr, math.radians(pl.ABSURD_GYRO_DEG_S))):
        bad = np.flatnonzero(np.linalg.norm(x, axis=1) > limit)
        assert len(bad) == (4 if name == "accel" else 1)
        found = [w for w in res.warnings if f": {name}: sample" in w]
        assert len(found) == 1 and f"sample {bad[0]}:" in found[0] and f"({len(bad)} such sample(s))" in found[0]


def test_a_check_fed_chunk_by_chunk_is_the_check_of_the_file(tmp_path):
    """RecordingCheck fed the samples chunk by chunk (here 7001 samples a chunk: no whole number of blocks) judges
    as check_recording reading the file itself; a spike named by its index."""
    from calib.io import recording

    rng = np.random.default_rng(8)
    n, fs = 30_000, 100.0
    gyr = rng.normal(0, 1e-4, (n, 3)) + np.radians(15.04 / 3600) * np.array([0.0, 0.6, 0.8])
    acc = rng.normal(0, 1e-2, (n, 3)) + [0.0, 0.0, 9.79]
    acc[12_345] = [0.0, 0.0, 2e4]                                          # a spike of ~2000 g
    ds = recording.make_dataset(acc, gyr, sample_rate_hz=fs, latitude_deg=30.0, accel_units="m s-2",
                                gyro_units="rad s-1", source="synthetic")
    path = recording.write(ds, tmp_path / "r.nc")
    h = recording.read_header(path)
    whole = pl.check_recording(path, h, force=True)
    check = pl.RecordingCheck(path, h, force=True)
    for i0, a, g in recording.iter_raw_chunks(path, h, chunk=7_001):
        check.add(i0, a, g)
    fed = check.finish()
    assert check.n_seen == n
    assert any("sample 12345" in w for w in whole.warnings), whole.warnings
    assert fed.warnings == whole.warnings
    assert fed.n_quiet_blocks == whole.n_quiet_blocks == n // 100 - 1       # the spike's block is not quiet
    assert fed.accel_static_norm == pytest.approx(9.79, rel=1e-3)
    assert fed.gyro_static_deg_h == pytest.approx(whole.gyro_static_deg_h, rel=1e-12)
