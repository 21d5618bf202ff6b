"""Import of a logger's file as it is: its clock judged by the fitted line (jitter reported, a hole refused with
the windows either side), dropped samples counted, and dropouts / stuck runs trimmed at the ends or refused
inside with their windows. The stamps and samples are made here from a model of the logger, not by the code
under test."""
from __future__ import annotations

import re

import numpy as np
import pytest
import yaml

from calib import cli
from calib.core import dropouts
from calib.ingest import ImportDataError, importers
from calib.io import recording

FS = 100.0


def arrival_stamps(n, seed, n_long=27):
    """Stamps (s) of a logger read over USB at FS: a latency growing by 0.024 periods a sample (steps of
    10.24 ms) that falls back by 0.55 periods past +0.3 (steps of 4.74 ms), and ``n_long`` steps 0.52 periods
    long paid back by the next (15.2 ms then 5 ms); the latency stays within -0.25..+0.3 periods."""
    rng = np.random.default_rng(seed)
    lat, x, pending, pay = np.empty(n), -0.25, False, False
    long_from = set(rng.choice(np.arange(10, n - 10), n_long, replace=False).tolist())
    for i in range(n):
        pending |= i in long_from
        if pay:
            x, pay = x - 0.5, False
        elif pending and x <= -0.22:
            x, pending, pay = x + 0.52, False, True
        else:
            x += 0.024
            x -= 0.55 if x > 0.3 else 0.0
        lat[i] = x
    return 12.0 + (np.arange(n) + lat) / FS


def samples(n, seed):
    """A static MEMS unit: accel in m s-2 (gravity on z, 0.01 m s-2 noise in steps of 0.001), gyro in counts
    of a 16-bit converter (3 counts of noise): no two rows alike for long."""
    rng = np.random.default_rng(100 + seed)
    acc = np.round(np.array([0.05, -0.02, 9.80]) + 0.01 * rng.standard_normal((n, 3)), 3)
    gyr = np.round(3.0 * rng.standard_normal((n, 3)))
    return acc, gyr


def write_csv(path, t, acc, gyr):
    rows = ["t_ms,ax,ay,az,gx,gy,gz"] + [",".join(f"{v:.10g}" for v in (1000.0 * ti, *a, *g))
                                         for ti, a, g in zip(t, acc, gyr)]
    path.write_text("\n".join(rows) + "\n")
    return path


def settings(path, **over):
    s = {"format": "columns", "file": str(path), "delimiter": ",", "header": True,
         "time": {"column": "t_ms", "units": "ms"}, "latitude_deg": 48.0,
         "accel": {"columns": ["ax", "ay", "az"], "units": "m s-2", "sample_kind": "rate"},
         "gyro": {"columns": ["gx", "gy", "gz"], "units": "count", "sample_kind": "rate"}}
    s.update(over)
    return s


def windows_in(message):
    """The (start_s, stop_s) windows a refusal names."""
    return [(float(a), float(b)) for a, b in re.findall(r"start_s: ([0-9.]+), stop_s: ([0-9.]+)", message)]


def test_arrival_stamped_logger_imports_with_jitter_reported_and_trailing_zeros_trimmed(tmp_path, capsys):
    """11 475 rows stamped on arrival (steps 10.24, 4.74 and 15.2 ms; every stamp within +-0.3 periods of the
    line) of which the last 239 are all zero, a logger stopping: imports with its jitter said, the zeros cut."""
    n, n_zero = 11_475, 239
    t = arrival_stamps(n, 1)
    d = np.diff(t)
    assert np.sum(d > 0.015) == 27 and np.median(d) == pytest.approx(0.01024)
    acc, gyr = samples(n, 1)
    acc[-n_zero:] = 0.0
    gyr[-n_zero:] = 0.0
    path = write_csv(tmp_path / "ahrs.csv", t, acc, gyr)
    sfile = tmp_path / "ahrs.yaml"
    sfile.write_text(yaml.safe_dump(settings(path)))
    out = tmp_path / "ahrs.nc"
    assert cli.main(["-q", "import", str(sfile), str(out)]) == 0
    err = capsys.readouterr().err
    assert "clock: 100 Hz fitted" in err and "0 gap(s), 0 dropped sample(s)" in err
    assert f"samples {n - n_zero}..{n - 1}, {n_zero} all-zero rows trimmed at the end" in err
    h = recording.validate(out)
    assert h.n_samples == n - n_zero
    assert h.attrs["clock_gaps"] == 0 and h.attrs["clock_dropped_samples"] == 0
    assert 0.25 < h.attrs["clock_max_residual_periods"] <= 0.3
    assert 0.05 < h.attrs["clock_jitter_std_periods"] < 0.2
    assert h.attrs["clock_rate_hz"] == pytest.approx(FS, rel=1e-5)
    assert "gyro: samples 11236..11474" in h.attrs["dropouts_trimmed"]
    with recording.load(out) as ds:
        np.testing.assert_array_equal(ds["gyro"].values, gyr[:n - n_zero])
        np.testing.assert_allclose(ds["time"].values, t[:n - n_zero], rtol=0, atol=1e-9)
    assert cli.main(["validate", str(out)]) == 0
    assert "clock: 100 Hz fitted" in capsys.readouterr().out


def test_half_second_hole_is_refused_naming_the_windows_that_import(tmp_path):
    t = arrival_stamps(3000, 2, n_long=5)
    t[1500:] += 0.5
    acc, gyr = samples(3000, 2)
    path = write_csv(tmp_path / "hole.csv", t, acc, gyr)
    with pytest.raises(ImportDataError, match=r"time gap of 0\.5.* s .*between samples 1499 and 1500") as exc:
        importers.import_dataset(settings(path))
    w = windows_in(exc.value.fix)
    assert len(w) == 2 and w[0][0] == 0.0 and t[1499] - t[0] < w[0][1] < t[1500] - t[0] and w[1][0] == w[0][1]
    first = importers.import_dataset(settings(path, start_s=w[0][0], stop_s=w[0][1]))
    second = importers.import_dataset(settings(path, start_s=w[1][0], stop_s=w[1][1]))
    assert first.sizes["time"] == 1500 and second.sizes["time"] == 1500
    np.testing.assert_array_equal(second["gyro"].values, gyr[1500:])
    assert second.attrs["clock_gaps"] == 0 and second.attrs["imported_rows"] == "1500..2999 of the file's 0..2999"


def test_dropped_samples_are_counted(tmp_path):
    t = arrival_stamps(6000, 3, n_long=10)
    acc, gyr = samples(6000, 3)
    lost = np.zeros(6000, dtype=bool)
    for s, k in ((700, 1), (1900, 3), (3100, 2), (4400, 7)):
        lost[s:s + k] = True
    path = write_csv(tmp_path / "drops.csv", t[~lost], acc[~lost], gyr[~lost])
    ds = importers.import_dataset(settings(path))
    assert ds.attrs["clock_dropped_samples"] == 13 and ds.attrs["clock_gaps"] == 0
    kept = np.flatnonzero(~lost)
    after = [int(np.searchsorted(kept, s)) - 1 for s in (700, 1900, 3100, 4400)]   # the kept sample before each
    assert ds.attrs["clock_dropped_after"] == f"{after[0]} {after[1]}x3 {after[2]}x2 {after[3]}x7"
    assert "13 dropped sample(s)" in ds.attrs["import_summary"]


def test_a_stuck_run_inside_is_refused_with_its_windows(tmp_path):
    t = arrival_stamps(5000, 4, n_long=5)
    acc, gyr = samples(5000, 4)
    gyr[2000:2120] = gyr[1999]   # the gyro's bus returns its last value for 1.2 s
    path = write_csv(tmp_path / "stuck.csv", t, acc, gyr)
    with pytest.raises(ImportDataError, match=r"gyro: samples 1999\.\.2119, 121 identical rows") as exc:
        importers.import_dataset(settings(path))
    assert "inside the recording" in exc.value.problem and "dropout_min_rows" in exc.value.fix
    w = windows_in(exc.value.fix)
    assert len(w) == 2
    parts = [importers.import_dataset(settings(path, start_s=a, stop_s=b)) for a, b in w]
    assert [p.sizes["time"] for p in parts] == [1999, 5000 - 2120]
    np.testing.assert_array_equal(parts[1]["gyro"].values, gyr[2120:])
    # a sensor that holds its output this long by design: the threshold is a setting
    ds = importers.import_dataset(settings(path, dropout_min_rows=200))
    assert ds.sizes["time"] == 5000 and ds.attrs["dropout_min_rows"] == 200


def test_leading_stuck_run_is_trimmed_and_chance_repeats_are_not_runs(tmp_path):
    """A logger that writes its first reading 60 times before the sensor runs; and a coarse sensor whose rows
    repeat by chance (each axis on one of three codes): neither is taken for the other."""
    t = np.arange(4000) / FS
    acc, gyr = samples(4000, 5)
    acc[:60] = acc[60]
    rng = np.random.default_rng(7)
    gyr = rng.integers(-1, 2, (4000, 3)).astype(float)   # P(row repeats) = 1/27: runs of 50 never by chance
    path = write_csv(tmp_path / "lead.csv", t, acc, gyr)
    ds = importers.import_dataset(settings(path))
    assert ds.sizes["time"] == 4000 - 61   # rows 0..60 alike
    assert ds.attrs["dropouts_trimmed"] == "accel: samples 0..60, 61 identical rows (the sensor's output stuck) " \
                                           "trimmed at the start"
    assert not dropouts.find_runs({"gyro": gyr}, min_run=8)   # even 8 alike in a row: p = (1/27)^7


def test_validate_refuses_a_recorded_file_with_a_dropout(tmp_path):
    acc, gyr = samples(3000, 6)
    acc[-100:] = 0.0
    ds = recording.make_dataset(acc, gyr, sample_rate_hz=FS, latitude_deg=48.0, accel_units="m s-2",
                                gyro_units="count", accel_kind="rate", gyro_kind="rate", source="recorded")
    with pytest.raises(recording.RecordingError, match=r"accel: samples 2900\.\.2999, 100 all-zero rows") as exc:
        recording.write(ds, tmp_path / "r.nc")
    assert "start_s: 0, stop_s: 28.995" in exc.value.fix and "re-import" in exc.value.fix
    # a noise-free synthetic recording may repeat its rows
    ds = recording.make_dataset(np.tile([0.0, 0.0, 9.8], (3000, 1)), np.zeros((3000, 3)), sample_rate_hz=FS,
                                latitude_deg=48.0, accel_units="m s-2", gyro_units="count", accel_kind="rate",
                                gyro_kind="rate", source="synthetic")
    recording.write(ds, tmp_path / "s.nc")
