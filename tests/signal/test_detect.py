"""Static-interval detection: closed forms, a synthetic session with known static spans, and the real
recordings in ../shared/data against what their authors report (shared/data/README, IMU-TK)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from calib.figures import segment_plots
from calib.signal import detect
from calib.ingest import importers
from calib.io import recording

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
CONFIG = ROOT / "config" / "import"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared real-data directory {DATA} is missing")

G = 9.80665


# ----------------------------------------------------------------------------- closed forms


def _brute(x, w, i):
    h = w // 2
    return np.linalg.norm(np.var(x[i - h:i + h + 1], axis=0, ddof=1))


def test_moving_variance_norm_matches_direct_variance():
    rng = np.random.default_rng(11)
    x = rng.normal(size=(500, 3)) * [1.0, 2.0, 0.5]
    w, h = 11, 5
    s = detect.moving_variance_norm(x, w)
    ref = np.array([_brute(x, w, i) for i in range(h, 500 - h)])
    np.testing.assert_allclose(s[h:500 - h], ref, rtol=1e-12)
    assert np.all(s[:h] == s[h]) and np.all(s[500 - h:] == s[500 - h - 1])


def test_moving_variance_norm_exact_for_raw_counts_across_chunks():
    # raw 16-bit counts: offset 32768, variance 9 count^2 per axis; values checked across chunk seams
    rng = np.random.default_rng(12)
    n, w = 200_000, 101
    x = 32768.0 + np.round(rng.normal(scale=3.0, size=(n, 3)))
    s = detect.moving_variance_norm(x, w)
    for seam in (detect.CHUNK, 2 * detect.CHUNK):
        for i in range(seam - 120, seam + 120, 7):
            assert s[i] == pytest.approx(_brute(x, w, i), rel=1e-9)
    # the median of the statistic is near its expectation sqrt(3) * 9 (chi-square spread shrinks with w)
    assert np.median(s) == pytest.approx(math.sqrt(3) * 9.0, rel=0.05)


def test_runs_and_window_samples():
    np.testing.assert_array_equal(detect.runs([0, 1, 1, 0, 1, 0, 0, 1]), [[1, 3], [4, 5], [7, 8]])
    assert detect.runs([0, 0]).shape == (0, 2)
    assert detect.window_samples(1.0, 100.0) == 101  # IMU-TK's default window at 100 Hz
    assert detect.window_samples(1.01, 100.0) == 101
    assert detect.window_samples(0.5, 204.8) % 2 == 1


# ----------------------------------------------------------------------------- synthetic session


def _session(seed=0, fs=100.0):
    """Rest 20 s, then moves (90 deg about x, or 90 deg about the vertical z) separated by statics.

    Returns accel [m s-2], gyro [rad s-1] (body frame, z up at the start) and the true static spans.
    """
    rng = np.random.default_rng(seed)
    statics = [20.0, 4.0, 2.5, 6.0, 3.0, 5.0, 2.0, 8.0]
    moves = ["x", "x", "z", "x", "x", "z", "x"]
    T = 3.0
    acc, gyr, spans = [], [], []
    roll = 0.0  # accumulated angle about x
    n0 = 0
    for k, st in enumerate(statics):
        m = int(st * fs)
        a = np.tile([0.0, G * math.sin(roll), G * math.cos(roll)], (m, 1))
        acc.append(a)
        gyr.append(np.zeros((m, 3)))
        spans.append((n0, n0 + m))
        n0 += m
        if k < len(moves):
            t = np.arange(int(T * fs)) / fs
            ang = 0.5 * math.pi / 2 * (1 - np.cos(math.pi * t / T))
            rate = 0.5 * math.pi / 2 * math.pi / T * np.sin(math.pi * t / T)
            if moves[k] == "x":
                r = roll + ang
                a = np.column_stack([np.zeros_like(t), G * np.sin(r), G * np.cos(r)])
                g = np.column_stack([rate, np.zeros_like(t), np.zeros_like(t)])
                roll += math.pi / 2
            else:  # turn about the vertical: specific force unchanged (sensor at the turn centre)
                a = np.tile([0.0, G * math.sin(roll), G * math.cos(roll)], (len(t), 1))
                g = np.column_stack([np.zeros_like(t), rate * math.sin(roll), rate * math.cos(roll)])
            acc.append(a)
            gyr.append(g)
            n0 += len(t)
    accel = np.vstack(acc) + rng.normal(scale=0.01, size=(n0, 3))
    gyro = np.vstack(gyr) + rng.normal(scale=1e-3, size=(n0, 3))
    return accel, gyro, spans, moves


def test_synthetic_static_spans_found():
    fs = 100.0
    accel, gyro, spans, moves = _session()
    det = detect.detect_static(accel, gyro, fs)
    assert det.count == len(spans)
    w = det.window
    for (a, b), (ta, tb) in zip(det.intervals, spans):
        # inside the true span (a window may reach at most half into a quiet motion edge) ...
        assert ta - w // 2 <= a and b <= tb + w // 2
        # ... and covering it except for about one window at each end
        assert a <= ta + w and b >= tb - w
    # the automatic initial rest ends one window before the first move, which starts at 20 s
    assert det.init_span[0] == 0 and 20 * fs - 2 * w <= det.init_span[1] <= 20 * fs
    assert "found automatically" in det.rule and det.k == 10.0


def test_turn_about_vertical_needs_the_gyro():
    # accel alone cannot see a turn about the gravity vector: the two statics around it merge
    fs = 100.0
    accel, gyro, spans, moves = _session(seed=1)
    n_vertical = moves.count("z")
    acc_only = detect.detect_static(accel, gyro, fs, use_gyro=False)
    both = detect.detect_static(accel, gyro, fs, use_gyro=True)
    assert both.count == len(spans)
    assert acc_only.count == len(spans) - n_vertical


def test_min_interval_and_explicit_threshold():
    fs = 100.0
    accel, gyro, spans, _ = _session(seed=2)
    det = detect.detect_static(accel, gyro, fs, min_interval_s=3.5)
    # a detected static is about one window shorter than the true one: the 2-4 s statics are dropped
    assert det.count == sum(1 for a, b in spans if (b - a) / fs > 3.5 + det.window / fs) == 4
    assert (det.intervals[:, 1] - det.intervals[:, 0]).min() >= 350
    det2 = detect.detect_static(accel, gyro, fs, threshold=1e-3, gyro_threshold=1e-4)
    assert det2.threshold == 1e-3 and det2.gyro_threshold == 1e-4 and "given" in det2.rule
    assert det2.count == len(spans)


def test_too_few_static_error_suggests_a_threshold():
    fs = 100.0
    accel, gyro, spans, _ = _session(seed=3)
    det = detect.detect_static(accel, gyro, fs)
    with pytest.raises(detect.StaticDetectionError) as e:
        det.require(len(spans) + 40, path="session.nc")
    msg = str(e.value)
    assert "session.nc" in msg and f"found {len(spans)}" in msg and f"{len(spans) + 40} needed" in msg
    assert "threshold" in msg and "fix:" in msg
    err = detect.too_few_static_error(12, 3, 0.5, suggestion=0.8)
    assert isinstance(err, ValueError) and "threshold=0.8" in str(err)
    # a suggested threshold really gives the number asked for
    thr = det.suggest_threshold(len(spans))
    assert thr is not None and len(det.intervals_at(thr)) >= len(spans)


def test_no_initial_rest_is_an_error_unless_threshold_given():
    fs = 100.0
    accel, gyro, spans, _ = _session(seed=4)
    start = spans[0][1] + 10  # begin in the middle of the first move
    with pytest.raises(detect.StaticDetectionError, match="threshold"):
        detect.detect_static(accel[start:], gyro[start:], fs)
    det = detect.detect_static(accel[start:], gyro[start:], fs, threshold=1e-3, gyro_threshold=1e-4)
    assert det.count == len(spans) - 1


# ----------------------------------------------------------------------------- real recordings


def _imported(name):
    s = importers.load_settings(CONFIG / f"{name}.yaml")
    s["data_dir"] = str(DATA)
    return importers.import_dataset(s)


@pytest.fixture(scope="module")
def xsens():
    return _imported("imu_tk_xsens")


@needs_data
def test_xsens_static_positions_imu_tk_settings(xsens):
    # IMU-TK's own pipeline with its defaults (window 101, threshold 10 x initial variance, 50 s initial
    # interval) finds 38 intervals including the initial rest; shared/data/README: ~51 s rest then ~37 positions
    det = detect.detect_in_recording(xsens, init_s=50.0, window_s=1.01, k=10.0, min_interval_s=1.0)
    assert det.window == 101 and det.init_span == (0, 5000)
    first = det.intervals[0]
    assert first[0] == 0 and 50.0 <= first[1] / 100.0 <= 53.0  # the initial rest, about 51 s
    assert 37 <= det.count - 1 <= 38
    # hand-placed positions of 1-11 s (README), give or take a window at each end
    d = det.durations_s[1:]
    assert d.min() >= 1.0 and d.max() <= 12.0


@needs_data
def test_xsens_automatic_threshold_agrees(xsens):
    det = detect.detect_in_recording(xsens)
    assert 50.0 <= det.init_span[1] / 100.0 <= 52.0
    assert 37 <= det.count - 1 <= 38
    acc_only = detect.detect_in_recording(xsens, use_gyro=False)
    assert 37 <= acc_only.count - 1 <= 38


@needs_data
@pytest.mark.parametrize("unit", ["imu0", "imu1", "imu2"])
def test_mikoff_static_periods(unit):
    ds = _imported(f"mikoff_{unit}")
    det = detect.detect_in_recording(ds)
    assert 22 <= det.count <= 25  # shared/data/README: about 22-25 static periods
    # gravity norm over the detected statics is the local gravity (m s-2, uncalibrated MEMS: 2 %)
    acc = ds["accel"].values
    norms = [np.linalg.norm(acc[a:b].mean(axis=0)) for a, b in det.intervals]
    assert np.median(norms) == pytest.approx(9.81, rel=0.02)


@needs_data
def test_adis_is_one_long_static_period():
    ds = _imported("smac_adis16405")
    det = detect.detect_in_recording(ds)
    assert det.count == 1
    a, b = det.intervals[0]
    assert (b - a) >= 0.99 * ds.sizes["time"]


@needs_data
def test_add_segment_table_and_plot(tmp_path):
    ds = _imported("mikoff_imu1")
    det = detect.detect_in_recording(ds)
    seg = detect.add_segment_table(ds, det)
    idx = seg["segment_index"].values
    assert seg.sizes["segment"] == det.count
    assert set(seg["segment_kind"].values) == {"static"}
    for i, (a, b) in enumerate(det.intervals):
        assert np.all(idx[a:b] == i)
    assert (idx >= 0).sum() == int((det.intervals[:, 1] - det.intervals[:, 0]).sum())
    assert "static_detection_rule" in seg["segment_index"].attrs
    out = recording.write(seg, tmp_path / "mikoff1_static.nc")
    back = recording.load(out)
    np.testing.assert_array_equal(back["segment_index"].values, idx)
    # refuses a second table
    with pytest.raises(ValueError, match="segment"):
        detect.add_segment_table(seg, det.intervals)
    # deterministic figure: same bytes twice, no software/date stamp
    p1 = segment_plots.static_detection(ds["accel"].values, ds["gyro"].values, 100.0, det, tmp_path / "a.png",
                                        title="mikoff imu1", accel_units="m s-2", gyro_units="rad s-1")
    p2 = segment_plots.static_detection(ds["accel"].values, ds["gyro"].values, 100.0, det, tmp_path / "b.png",
                                        title="mikoff imu1", accel_units="m s-2", gyro_units="rad s-1")
    b1 = p1.read_bytes()
    assert b1[:8] == b"\x89PNG\r\n\x1a\n" and b1 == p2.read_bytes()
    assert b"Software" not in b1 and b"Date" not in b1
