"""Simulated IMU sessions written as ROS bags with ``rosbags`` (ROS 1, ROS 2 sqlite3, ROS 2 MCAP, a plain MCAP
file), and the ``calib`` command line in a fresh interpreter."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
G = 9.80665
T0_NS = 1_700_000_000_123_456_789  # an epoch-like first stamp (ns), far from 0 so float seconds would round
KINDS = ("ros1", "ros2_sqlite3", "ros2_mcap", "mcap_file")


def calib(*argv, cwd=None, timeout=300):
    """``python -m calib.cli ARGV`` (what a user's terminal shows)."""
    return subprocess.run([sys.executable, "-m", "calib.cli", *map(str, argv)], capture_output=True, text=True,
                          cwd=cwd or ROOT, timeout=timeout)


def _rot(axis, angle):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def session(seed, *, fs=100.0, duration_s=30.0, jitter_ns=20_000, drop=(), frame_ids=None):
    """A hand-held session: rest, then three turns of 90 deg about random axes, with MEMS-like noise. Returns the
    header stamps [ns] (nominal period 1/fs, uniform jitter of +-``jitter_ns``; messages ``drop`` removed), the
    receive stamps (header + 1-3 ms latency), accel [m s-2], gyro [rad s-1] (body frame, SI), the frame ids."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * fs))
    t = np.arange(n) / fs
    w = np.zeros((n, 3))
    for k in range(3):  # 2 s turns starting at 5, 12, 19 s
        a = int(round((5 + 7 * k) * fs))
        b = a + int(round(2 * fs))
        if b > n:
            break
        e = rng.standard_normal(3)
        e /= np.linalg.norm(e)
        w[a:b] = (np.pi / 2 / 2.0) * (1 - np.cos(2 * np.pi * (t[a:b] - t[a]) / 2.0))[:, None] * e
    C = np.eye(3)
    f = np.empty((n, 3))
    for i in range(n):
        f[i] = C.T @ np.array([0.0, 0.0, G])
        C = C @ _rot(w[i] if np.any(w[i]) else [0, 0, 1], np.linalg.norm(w[i]) / fs)
    accel = f + 0.02 * rng.standard_normal((n, 3))
    gyro = w + 1e-3 * rng.standard_normal((n, 3)) + 0.005 * rng.standard_normal(3)
    period_ns = int(round(1e9 / fs))
    stamps = T0_NS + np.arange(n, dtype=np.int64) * period_ns + rng.integers(-jitter_ns, jitter_ns + 1, n)
    recv = stamps + rng.integers(1_000_000, 3_000_000, n)
    recv = np.maximum.accumulate(recv)
    keep = np.ones(n, bool)
    keep[list(drop)] = False
    ids = frame_ids if frame_ids is not None else ["imu_link"] * n
    return {"stamps": stamps[keep], "recv": recv[keep], "accel": accel[keep], "gyro": gyro[keep],
            "frame_ids": [ids[i] for i in np.flatnonzero(keep)], "fs": fs, "period_ns": period_ns}


def _typestore(kind):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)


def imu_message(ts, ns, acc, gyr, frame_id, seq=0, cov=0.0):
    T = ts.types["builtin_interfaces/msg/Time"]
    H = ts.types["std_msgs/msg/Header"]
    Q = ts.types["geometry_msgs/msg/Quaternion"]
    V = ts.types["geometry_msgs/msg/Vector3"]
    Imu = ts.types["sensor_msgs/msg/Imu"]
    kw = {"seq": seq} if "seq" in H.__dataclass_fields__ else {}
    c = np.zeros(9)
    c[0] = cov
    hdr = H(stamp=T(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000)), frame_id=frame_id, **kw)
    return Imu(hdr, Q(0.0, 0.0, 0.0, 1.0), np.zeros(9), V(*map(float, gyr)), c.copy(), V(*map(float, acc)), c.copy())


def temperature_message(ts, ns, value, frame_id="imu_link"):
    T = ts.types["builtin_interfaces/msg/Time"]
    H = ts.types["std_msgs/msg/Header"]
    Temp = ts.types["sensor_msgs/msg/Temperature"]
    kw = {"seq": 0} if "seq" in H.__dataclass_fields__ else {}
    return Temp(H(stamp=T(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000)), frame_id=frame_id, **kw),
                float(value), 0.0)


def write_bag(kind, folder, s, *, topic="/imu", extra_imu_topics=(), temperature=None, cov=0.0, name="session"):
    """Write session ``s`` (:func:`session`) as a bag of ``kind`` (:data:`KINDS`) in ``folder``; returns its path.

    ``temperature``: (stamps ns, values degC) on /imu/temperature. ``extra_imu_topics``: more Imu topics (a copy
    of the first 10 messages each)."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin, Writer as Writer2

    folder = Path(folder)
    ts = _typestore(kind)
    imu_t = "sensor_msgs/msg/Imu"
    ser = ts.serialize_ros1 if kind == "ros1" else ts.serialize_cdr
    msgs = []  # (topic, receive ns, raw)
    for i, (ns, rv, a, g, fid) in enumerate(zip(s["stamps"], s["recv"], s["accel"], s["gyro"], s["frame_ids"])):
        msgs.append((topic, int(rv), ser(imu_message(ts, ns, a, g, fid, i, cov), imu_t)))
    for other in extra_imu_topics:
        for i in range(10):
            msgs.append((other, int(s["recv"][i]), ser(imu_message(ts, s["stamps"][i], s["accel"][i], s["gyro"][i],
                                                                  "other"), imu_t)))
    if temperature is not None:
        for ns, v in zip(*temperature):
            msgs.append(("/imu/temperature", int(ns), ser(temperature_message(ts, ns, v),
                                                          "sensor_msgs/msg/Temperature")))
    msgs.sort(key=lambda m: m[1])
    types = {topic: imu_t, **{o: imu_t for o in extra_imu_topics}}
    if temperature is not None:
        types["/imu/temperature"] = "sensor_msgs/msg/Temperature"
    if kind == "ros1":
        path = folder / f"{name}.bag"
        with Writer1(path) as w:
            conns = {t: w.add_connection(t, mt, typestore=ts) for t, mt in types.items()}
            for t, ns, raw in msgs:
                w.write(conns[t], ns, raw)
        return path
    plugin = StoragePlugin.SQLITE3 if kind == "ros2_sqlite3" else StoragePlugin.MCAP
    path = folder / name
    with Writer2(path, version=9, storage_plugin=plugin) as w:
        conns = {t: w.add_connection(t, mt, typestore=ts) for t, mt in types.items()}
        for t, ns, raw in msgs:
            w.write(conns[t], ns, raw)
    if kind == "mcap_file":  # the storage file alone: a plain MCAP file as ROS 2 tools write them
        mc = next(path.glob("*.mcap"))
        plain = folder / f"{name}_plain.mcap"
        shutil.copy(mc, plain)
        shutil.rmtree(path)
        return plain
    return path


def rosbag_settings(path, **over):
    s = {"format": "rosbag", "file": str(path), "topic": "/imu", "latitude_deg": 48.1, "height_m": 520.0}
    s.update(over)
    return s


@pytest.fixture
def bag_session():
    return session
