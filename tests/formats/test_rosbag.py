"""ROS bags in: ROS 1, ROS 2 (sqlite3, MCAP) and plain MCAP files written here with rosbags from a simulated
session come back as the same samples, exactly; dropped messages are counted where they were dropped; a wrong or
missing topic is refused with the list of IMU topics (exit 2 through the command line)."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from calib.ingest import importers
from calib.ingest.common import ImportDataError
from calib.io import recording

from conftest import KINDS, calib, rosbag_settings, session, write_bag


def _imported(tmp_path, path, **over):
    out = importers.import_recording(rosbag_settings(path, **over), tmp_path / "out.nc")
    return recording.load(out)


@pytest.mark.parametrize("kind", KINDS)
def test_round_trip_is_exact(tmp_path, kind):
    s = session(1)
    ds = _imported(tmp_path, write_bag(kind, tmp_path, s))
    np.testing.assert_array_equal(ds["accel"].values, s["accel"])
    np.testing.assert_array_equal(ds["gyro"].values, s["gyro"])
    np.testing.assert_array_equal(ds["time"].values, (s["stamps"] - s["stamps"][0]).astype(float) * 1e-9)
    assert ds.attrs["time_origin_unix_ns"] == str(s["stamps"][0])
    assert ds["accel"].attrs["units"] == "m s-2" and ds["gyro"].attrs["units"] == "rad s-1"
    assert ds.attrs["ros_topic"] == "/imu" and ds.attrs["ros_frame_id"] == "imu_link"
    # the rate is the least-squares clock of the stamps: the true 100 Hz within its jitter (+-20 us uniform)
    assert ds.attrs["sample_rate_hz"] == pytest.approx(100.0, rel=2e-6)
    assert ds.attrs["clock_dropped_samples"] == 0 and ds.attrs["clock_jitter_std_s"] == pytest.approx(
        20e-6 / np.sqrt(3), rel=0.1)


def test_dropped_messages_are_detected_and_reported(tmp_path):
    drop = (700, 1500, 1501)  # one message, then two in a row
    s = session(2, drop=drop)
    ds = _imported(tmp_path, write_bag("ros2_mcap", tmp_path, s))
    assert ds.sizes["time"] == 3000 - 3
    assert ds.attrs["clock_dropped_samples"] == 3
    # dropped after kept sample 699 (message 700), and two after kept sample 1498 (message 1499; 1500, 1501 lost)
    assert ds.attrs["clock_dropped_after"] == "699 1498x2"
    assert "3 dropped sample(s)" in ds.attrs["import_summary"]
    np.testing.assert_array_equal(ds["accel"].values, s["accel"])


def test_frame_ids_of_different_lengths_still_read_exactly(tmp_path):
    ids = ["imu", "imu_link", "base_imu_frame_x"] * 1000
    s = session(3, frame_ids=ids)
    for kind in ("ros1", "ros2_sqlite3"):
        ds = _imported(tmp_path, write_bag(kind, tmp_path, s, name=f"var_{kind}"))
        np.testing.assert_array_equal(ds["gyro"].values, s["gyro"])
        np.testing.assert_array_equal(ds["time"].values, (s["stamps"] - s["stamps"][0]) * 1e-9)


def test_receive_time_and_temperature_topic(tmp_path):
    s = session(4)
    t_ns = s["stamps"][0] - 2_000_000_000 + np.arange(40) * 1_000_000_000  # 1 Hz, from 2 s before the IMU
    temp = 20.0 + 0.1 * np.arange(40)  # a ramp of 0.1 degC/s
    path = write_bag("ros1", tmp_path, s, temperature=(t_ns, temp))
    ds = _imported(tmp_path, path, time_source="receive", temperature_topic="/imu/temperature")
    np.testing.assert_array_equal(ds["time"].values, (s["recv"] - s["recv"][0]) * 1e-9)
    # temperature in the receive time base: the ramp at each IMU receive time (linear interpolation is exact)
    expect = 20.0 + 0.1 * ((s["recv"] - t_ns[0]) * 1e-9)
    np.testing.assert_allclose(ds["temperature"].values, expect, rtol=0, atol=1e-9)


def test_window_gap_and_order_refusals(tmp_path):
    s = session(5)
    s["stamps"][2000:] += 3_000_000_000  # a 3 s pause (not a whole number of dropped messages)
    s["recv"][2000:] += 3_000_000_000
    path = write_bag("ros2_sqlite3", tmp_path, s)
    with pytest.raises(ImportDataError, match=r"1 gap\(s\).*start_s / stop_s"):
        importers.import_dataset(rosbag_settings(path))
    ds = importers.import_dataset(rosbag_settings(path, stop_s=19.995))   # the part before the gap
    assert ds.sizes["time"] == 2000
    ds = importers.import_dataset(rosbag_settings(path, start_s=22.0))    # the part after it
    np.testing.assert_array_equal(ds["accel"].values, s["accel"][2000:])
    s2 = session(6)
    s2["stamps"][100], s2["stamps"][101] = s2["stamps"][101], s2["stamps"][100]
    with pytest.raises(ImportDataError, match="not strictly increasing.*time_source: receive"):
        importers.import_dataset(rosbag_settings(write_bag("mcap_file", tmp_path, s2, name="swapped")))


def test_no_angular_velocity_and_bad_units_refused(tmp_path):
    s = session(7, duration_s=5.0)
    path = write_bag("ros2_mcap", tmp_path, s, cov=-1.0)
    with pytest.raises(ImportDataError, match="does not provide angular_velocity"):
        importers.import_dataset(rosbag_settings(path))
    with pytest.raises(ImportDataError, match="REP 145"):
        importers.import_dataset(rosbag_settings(path, accel={"units": "g", "sample_kind": "rate"}))
    table = tmp_path / "x.csv"
    table.write_text("1,2,3\n")
    with pytest.raises(ImportDataError, match="not a ROS bag"):
        importers.import_dataset(rosbag_settings(table))


def test_wrong_or_missing_topic_is_refused_with_the_topic_list_exit_2(tmp_path):
    s = session(8, duration_s=5.0)
    path = write_bag("ros2_mcap", tmp_path, s, extra_imu_topics=("/imu/raw",))
    cfg = tmp_path / "bag.yaml"
    settings = rosbag_settings(path)
    del settings["topic"]
    cfg.write_text(yaml.safe_dump(settings))
    out = tmp_path / "out.nc"
    for extra in ([], ["--topic", "/camera/imu"]):
        r = calib("import", cfg, out, *extra)
        assert r.returncode == 2, r.stderr
        assert "Traceback" not in r.stderr
        assert "/imu (500 messages)" in r.stderr and "/imu/raw (10 messages)" in r.stderr, r.stderr
        assert ("no topic given" if not extra else "'/camera/imu' not in the bag") in r.stderr
        assert not out.exists()
    r = calib("import", cfg, out, "--topic", "/imu")
    assert r.returncode == 0, r.stderr
    assert "500 messages" in r.stderr and r.stdout.strip() == f"wrote {out}"
    np.testing.assert_array_equal(recording.load(out)["gyro"].values, s["gyro"])


def test_rosbag_is_one_registry_entry():
    assert "rosbag" in importers.FORMATS and importers.IMPORTERS["rosbag"].__name__ == "import_rosbag"
