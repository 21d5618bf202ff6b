"""Benchmark of the ROS bag importer: a bag of one hour of sensor_msgs/msg/Imu at 200 Hz (720,000 messages) is
written with rosbags into a temporary folder, then imported the way ``calib import`` does (read, decode, fit the
clock, check, write the netCDF recording atomically and validate it). Target: at most 10 s per import.

Run: .venv/bin/python benchmarks/bench_rosbag_import.py [--kind ros2_mcap|ros2_sqlite3|ros1|all] [--hours H]
"""
from __future__ import annotations

import argparse
import math
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from calib.ingest import importers

TARGET_S = 10.0
T0_NS = 1_700_000_000_000_000_000


def write_bag(kind: str, folder: Path, n: int, fs: float) -> Path:
    """A static IMU at ``fs`` Hz with white noise and 20 us stamp jitter, as a bag of ``kind``."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    T, H = ts.types["builtin_interfaces/msg/Time"], ts.types["std_msgs/msg/Header"]
    Q, V, Imu = ts.types["geometry_msgs/msg/Quaternion"], ts.types["geometry_msgs/msg/Vector3"], \
        ts.types["sensor_msgs/msg/Imu"]
    ser = ts.serialize_ros1 if kind == "ros1" else ts.serialize_cdr
    rng = np.random.default_rng(0)
    acc = np.array([0.05, -0.03, 9.81]) + 0.01 * rng.standard_normal((n, 3))
    gyr = 1e-3 * rng.standard_normal((n, 3))
    stamps = T0_NS + np.arange(n, dtype=np.int64) * int(round(1e9 / fs)) + rng.integers(-20_000, 20_001, n)
    zero = np.zeros(9)
    quat = Q(0.0, 0.0, 0.0, 1.0)
    kw = {"seq": 0} if "seq" in H.__dataclass_fields__ else {}

    def messages(w, conn):
        for i in range(n):
            ns = int(stamps[i])
            m = Imu(H(stamp=T(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id="imu_link", **kw),
                    quat, zero, V(*gyr[i].tolist()), zero, V(*acc[i].tolist()), zero)
            w.write(conn, ns, ser(m, "sensor_msgs/msg/Imu"))

    if kind == "ros1":
        path = folder / "imu.bag"
        with Writer1(path) as w:
            messages(w, w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts))
        return path
    path = folder / "imu_bag"
    plugin = StoragePlugin.MCAP if kind == "ros2_mcap" else StoragePlugin.SQLITE3
    with Writer2(path, version=9, storage_plugin=plugin) as w:
        messages(w, w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts))
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--kind", default="ros2_mcap", choices=["ros2_mcap", "ros2_sqlite3", "ros1", "all"])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--rate", type=float, default=200.0)
    args = ap.parse_args(argv)
    n = int(round(args.hours * 3600.0 * args.rate))
    kinds = ["ros2_mcap", "ros2_sqlite3", "ros1"] if args.kind == "all" else [args.kind]
    ok = True
    for kind in kinds:
        folder = Path(tempfile.mkdtemp(prefix="calib-bench-rosbag-"))
        try:
            t0 = time.perf_counter()
            bag = write_bag(kind, folder, n, args.rate)
            t_write = time.perf_counter() - t0
            size = sum(p.stat().st_size for p in ([bag] if bag.is_file() else bag.iterdir()))
            settings = {"format": "rosbag", "file": str(bag), "topic": "/imu", "latitude_deg": 45.0}
            t0 = time.perf_counter()
            out = importers.import_recording(settings, folder / "imu.nc")
            t_imp = time.perf_counter() - t0
            from calib.io import recording

            h = recording.read_header(out)
            assert h.n_samples == n and math.isclose(h.sample_rate_hz, args.rate, rel_tol=1e-6)
            passed = t_imp <= TARGET_S * args.hours
            ok &= passed
            print(f"{kind:13s} {n} messages ({args.hours:g} h at {args.rate:g} Hz, {size / 1e6:.0f} MB; written in "
                  f"{t_write:.1f} s): import {t_imp:.2f} s (target <= {TARGET_S * args.hours:g} s) "
                  f"{'PASS' if passed else 'FAIL'}; rate {h.sample_rate_hz:.9g} Hz")
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
