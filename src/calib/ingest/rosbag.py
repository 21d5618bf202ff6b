"""ROS bags: ``sensor_msgs/msg/Imu`` messages of one topic (ROS 1 bags, ROS 2 bags in sqlite3 or MCAP storage,
plain MCAP files), read with the pure-Python ``rosbags`` library.

Settings (besides :data:`calib.ingest.common.COMMON_KEYS`)::

    format: rosbag
    file: session.bag            # a ROS 1 .bag, a rosbag2 folder (metadata.yaml), a .mcap or a .db3 file
    topic: /imu                  # required: no topic is guessed (`calib import ... --topic /imu` overrides it)
    time_source: header          # header (default: header.stamp, the driver's sample time) | receive (bag time)
    temperature_topic: /imu/temperature   # optional sensor_msgs/msg/Temperature topic [degC]
    sample_rate_hz: 200          # optional nominal rate, checked against the stamps' clock
    start_s: 0                   # optional window [start_s, stop_s) in seconds from the topic's first message
    stop_s: 3600
    latitude_deg: 48.1           # required, as for every format
    accel: {sign: [1, 1, 1]}     # optional: units are fixed by the message (m s-2 and rad s-1 rates, REP 145)
    gyro: {sign: [1, 1, 1]}

What is read: ``linear_acceleration`` [m s-2] and ``angular_velocity`` [rad s-1] of each message, in the frame
of ``header.frame_id`` (stored as the attribute ``ros_frame_id``; REP 103: x forward, y left, z up for a body),
the orientation and the covariances are not kept. A topic whose ``*_covariance[0]`` is -1 (REP 145: "this
field is not provided") is refused. Time: ``header.stamp`` (or the bag's receive time) as nanoseconds, stored
as seconds from the first sample (exact to the float64 rounding of that difference); the first stamp itself as
``time_origin_unix_ns``. The rate is the least-squares clock of the stamps (:func:`calib.core.clock.fit_clock`,
never the median step), stored with its uncertainty, the jitter and the dropped messages (``clock_*``
attributes, and ``import_summary``, the line ``calib import`` prints). Stamps that are not strictly increasing
are refused (fix: ``time_source: receive``, or repair the driver's stamps), and so is a gap (a pause longer than
max(1 s, 50 periods) or not a whole number of periods): the recording format holds one uniform clock, so the
refusal names each gap and the window (``start_s`` / ``stop_s``) that imports the part before or after it.
Dropped messages (steps of a whole number of periods) are kept as gaps of the time coordinate and counted.

Temperature: the named topic's ``temperature`` [degC], linearly interpolated in time to the IMU samples (held
at the first / last value outside its span; its span must overlap the IMU's).

Speed: the messages are decoded with ``rosbags``' own deserialiser for a sample of them (the first, the last and
evenly spread ones, and one of every layout); when all of them agree with a vectorised read of the same fields at
the offsets the CDR / ROS 1 layout gives (header with its frame_id string, then 37 float64), the vectorised read
is used for all messages (an hour at 200 Hz in a few seconds), otherwise every message goes through ``rosbags``.

Plain MCAP files: ``rosbags`` reads MCAP files of the ``ros2`` profile (CDR messages, as ROS 2 and rosbags write
them) directly; other profiles are refused with the fix (convert with ``rosbags-convert`` or ``ros2 bag
convert``), so no second MCAP library is needed.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from calib.ingest.common import (
    ImportDataError,
    check_keys,
    data_file,
    declared_rate,
    finish,
    number_setting,
    serr,
    time_clock,
)

#: the settings keys of this format (besides :data:`calib.ingest.common.COMMON_KEYS`)
KEYS = {"file", "topic", "time_source", "temperature_topic", "sample_rate_hz"}   # start_s / stop_s: common keys,
# applied here to the bag's messages (before the clock is fitted), not again by finish()

IMU_TYPE = "sensor_msgs/msg/Imu"
TEMPERATURE_TYPE = "sensor_msgs/msg/Temperature"
TIME_SOURCES = ("header", "receive")
#: float64 fields after the header: Imu = orientation (4), its covariance (9), angular_velocity (3), covariance
#: (9), linear_acceleration (3), covariance (9); Temperature = temperature, variance
IMU_FLOATS = 37
IMU_GYRO, IMU_GYRO_COV, IMU_ACCEL, IMU_ACCEL_COV = 13, 16, 25, 28
TEMPERATURE_FLOATS = 2
#: messages decoded at once (memory: about 0.3 kB each for Imu)
CHUNK = 200_000
#: messages of a chunk checked against the rosbags deserialiser
N_CHECK = 24

FIX_TOPIC = "set 'topic' in the settings or pass --topic"


def _si_triads(settings) -> dict:
    """The settings with the Imu message's fixed units filled in (m s-2 and rad s-1 rates); other units refused."""
    s = dict(settings)
    for tri, units in (("accel", "m s-2"), ("gyro", "rad s-1")):
        t = s.get(tri)
        if t is None:
            t = {}
        if not isinstance(t, dict):
            raise serr(settings, tri, "must be a mapping (optional for ROS bags: sign, scale)")
        t = dict(t)
        if t.get("units", units) != units or t.get("sample_kind", "rate") != "rate":
            raise serr(settings, f"{tri}.units", f"sensor_msgs/msg/Imu carries {units} rates (REP 145), declared "
                       f"{t.get('units')!r} / {t.get('sample_kind')!r}", f"remove {tri}.units and "
                       f"{tri}.sample_kind (or set them to '{units}' and 'rate')")
        if t.get("columns") is not None:
            raise serr(settings, f"{tri}.columns", "a ROS message has no columns", "remove it")
        t["units"], t["sample_kind"] = units, "rate"
        s[tri] = t
    return s


# --------------------------------------------------------------------------- opening


def bag_kind(path: Path) -> str:
    """'ros1' (a .bag file), 'rosbag2' (a folder with metadata.yaml), 'mcap' or 'sqlite3' (a storage file)."""
    if path.is_dir():
        if (path / "metadata.yaml").exists():
            return "rosbag2"
        raise ImportDataError(path, "file", "a folder without metadata.yaml is not a rosbag2 bag",
                              "give the bag folder (holding metadata.yaml and the .db3/.mcap files)")
    suffix = path.suffix.lower()
    kind = {".bag": "ros1", ".mcap": "mcap", ".db3": "sqlite3"}.get(suffix)
    if kind is None:
        raise ImportDataError(path, "file", f"not a ROS bag (suffix {path.suffix!r})",
                              "give a ROS 1 .bag file, a rosbag2 folder, or a .mcap / .db3 file")
    return kind


def _open(path: Path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    kind = bag_kind(path)
    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    try:
        reader = AnyReader([path], default_typestore=store)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - whatever rosbags raises, the file is not a readable bag
        msg = " ".join(str(exc).split()) or type(exc).__name__
        fix = "check the file (a truncated bag can be reindexed with 'rosbag reindex' / 'ros2 bag reindex')"
        if "Profile is not ros2" in msg:
            fix = ("only ROS 2 (CDR) MCAP files are read: convert it with 'rosbags-convert' or 'ros2 bag convert'")
        raise ImportDataError(path, "file", f"not a readable ROS bag ({type(exc).__name__}: {msg})", fix) from None
    return reader, kind


def _topics_of(reader, msgtype):
    return {name: info for name, info in sorted(reader.topics.items()) if info.msgtype == msgtype}


def _topic_list(reader, msgtype) -> str:
    t = _topics_of(reader, msgtype)
    if not t:
        others = ", ".join(f"{n} ({i.msgtype})" for n, i in sorted(reader.topics.items())) or "none"
        return f"the bag holds no {msgtype} topic (topics: {others})"
    return f"{msgtype} topics in the bag: " + ", ".join(f"{n} ({i.msgcount} messages)" for n, i in t.items())


def _connections(reader, path, settings, key, msgtype):
    topic = settings.get(key)
    if not topic:
        raise ImportDataError(path, key, f"no topic given; {_topic_list(reader, msgtype)}",
                              FIX_TOPIC if key == "topic" else f"set '{key}' to one of them")
    topic = str(topic)
    info = reader.topics.get(topic)
    if info is None or info.msgtype != msgtype:
        what = "not in the bag" if info is None else f"of type {info.msgtype}, not {msgtype}"
        raise ImportDataError(path, key, f"topic {topic!r} {what}; {_topic_list(reader, msgtype)}",
                              FIX_TOPIC if key == "topic" else f"set '{key}' to one of them")
    return topic, [c for c in reader.connections if c.topic == topic]


# --------------------------------------------------------------------------- decoding


def _layout(buf, starts, lens, ros1: bool):
    """Per message: (offset of the first float64 relative to the message start, little-endian?) from the header
    (ROS 1: seq, secs, nsecs, frame_id length + bytes, then packed fields; CDR: 4-byte encapsulation header, sec,
    nanosec, frame_id length + bytes incl. NUL, fields aligned to their size from the end of the encapsulation
    header)."""
    if np.any(lens < 16):
        return None, None
    idx = starts[:, None] + np.arange(12, 16)
    strlen = buf[idx].copy().view("<u4").ravel().astype(np.int64)
    if ros1:
        return 16 + strlen, np.ones(len(starts), dtype=bool)
    little = (buf[starts] == 0) & (buf[starts + 1] == 1)
    rel = 12 + strlen
    return 4 + rel + (-rel) % 8, little


def _vector_read(raws, ros1: bool, n_floats: int, want):
    """Vectorised read of the header stamp (ns) and the float64 fields ``want`` (indices among the ``n_floats``
    after the header) of raw messages; None when a message does not have the layout (big-endian CDR, short)."""
    n = len(raws)
    lens = np.fromiter((len(r) for r in raws), dtype=np.int64, count=n)
    blob = b"".join(raws)
    buf = np.frombuffer(blob, dtype=np.uint8)
    starts = np.zeros(n, dtype=np.int64)
    np.cumsum(lens[:-1], out=starts[1:])
    off, little = _layout(buf, starts, lens, ros1)
    if off is None or not np.all(little) or np.any(off + 8 * n_floats > lens):
        return None
    sec = buf[starts[:, None] + np.arange(4, 8)].copy().view("<i4" if not ros1 else "<u4").ravel().astype(np.int64)
    nsec = buf[starts[:, None] + np.arange(8, 12)].copy().view("<u4").ravel().astype(np.int64)
    stamps = sec * 1_000_000_000 + nsec
    want = np.asarray(want, dtype=np.int64)
    out = np.empty((n, len(want)))
    keys = lens * 65536 + off
    for key in np.unique(keys):
        sel = np.flatnonzero(keys == key)
        length, o = int(lens[sel[0]]), int(off[sel[0]])
        if len(sel) == n:
            rows = buf.reshape(n, length)
        else:
            rows = np.frombuffer(b"".join(raws[i] for i in sel), dtype=np.uint8).reshape(len(sel), length)
        cols = (o + 8 * want)[:, None] + np.arange(8)
        out[sel] = np.ascontiguousarray(rows[:, cols.ravel()]).view("<f8").reshape(len(sel), len(want))
    return stamps, out, off


def _fields(msg, msgtype):
    s = msg.header.stamp
    ns = int(getattr(s, "sec", getattr(s, "secs", 0))) * 1_000_000_000 + int(getattr(s, "nanosec",
                                                                                   getattr(s, "nsecs", 0)))
    if msgtype == IMU_TYPE:
        av, la = msg.angular_velocity, msg.linear_acceleration
        vals = [av.x, av.y, av.z, float(msg.angular_velocity_covariance[0]), la.x, la.y, la.z,
                float(msg.linear_acceleration_covariance[0])]
    else:
        vals = [msg.temperature]
    return ns, vals


def _decode(reader, raws, msgtype, ros1: bool):
    """(header stamps ns (n,), fields (n, k)) of raw messages: Imu -> gyro x y z, gyro cov[0], accel x y z,
    accel cov[0]; Temperature -> temperature. Vectorised when a sample agrees with rosbags' deserialiser."""
    if msgtype == IMU_TYPE:
        n_floats = IMU_FLOATS
        want = [IMU_GYRO, IMU_GYRO + 1, IMU_GYRO + 2, IMU_GYRO_COV, IMU_ACCEL, IMU_ACCEL + 1, IMU_ACCEL + 2,
                IMU_ACCEL_COV]
    else:
        n_floats, want = TEMPERATURE_FLOATS, [0]
    fast = _vector_read(raws, ros1, n_floats, want)
    if fast is not None:
        stamps, vals, off = fast
        n = len(raws)
        check = set(np.linspace(0, n - 1, min(n, N_CHECK)).astype(int).tolist())
        _, first = np.unique(off, return_index=True)
        check.update(first.tolist())
        ok = True
        for i in sorted(check):
            ns, v = _fields(reader.deserialize(raws[i], msgtype), msgtype)
            if ns != stamps[i] or not np.array_equal(np.asarray(v, dtype=float), vals[i], equal_nan=True):
                ok = False
                break
        if ok:
            return stamps, vals
    stamps = np.empty(len(raws), dtype=np.int64)
    vals = np.empty((len(raws), len(want)))
    for i, raw in enumerate(raws):
        stamps[i], vals[i] = _fields(reader.deserialize(raw, msgtype), msgtype)
    return stamps, vals


def _read_topic(reader, connections, msgtype, ros1):
    """All messages of ``connections``: (header stamps ns, receive times ns, fields, the first message decoded or
    None) in bag order."""
    stamps, recv, vals = [], [], []
    raws, rts = [], []
    first = None

    def flush():
        if raws:
            s, v = _decode(reader, raws, msgtype, ros1)
            stamps.append(s)
            vals.append(v)
            recv.append(np.asarray(rts, dtype=np.int64))
            raws.clear()
            rts.clear()

    for _, t, raw in reader.messages(connections=connections):
        if first is None:
            first = reader.deserialize(raw, msgtype)
        raws.append(bytes(raw))
        rts.append(t)
        if len(raws) >= CHUNK:
            flush()
    flush()
    if not stamps:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 8)), None
    return np.concatenate(stamps), np.concatenate(recv), np.concatenate(vals), first


# --------------------------------------------------------------------------- the importer


def _window(settings, t_s):
    """Samples inside [start_s, stop_s) (seconds from the first message)."""
    keep = np.ones(len(t_s), dtype=bool)
    for key in ("start_s", "stop_s"):
        if settings.get(key) is not None:
            v = number_setting(settings, key, settings[key], positive=False)
            keep &= (t_s >= v) if key == "start_s" else (t_s < v)
    return keep


def _bag_files(path: Path):
    if path.is_dir():
        return sorted(p for p in path.iterdir() if p.is_file())
    return [path]


def import_rosbag(settings) -> xr.Dataset:
    """A ROS 1 / ROS 2 bag or a plain MCAP file: ``sensor_msgs/msg/Imu`` of ``topic`` (see the module docstring
    for the settings, time, rate, gaps and temperature)."""
    settings = _si_triads(settings)
    check_keys(settings, "rosbag", KEYS)
    path = data_file(settings, "file")
    source = settings.get("time_source", "header")
    if source not in TIME_SOURCES:
        raise serr(settings, "time_source", f"value {source!r}", f"one of: {', '.join(TIME_SOURCES)}")
    reader, kind = _open(path)
    ros1 = kind == "ros1"
    try:
        topic, conns = _connections(reader, path, settings, "topic", IMU_TYPE)
        stamps, recv, vals, first = _read_topic(reader, conns, IMU_TYPE, ros1)
        if len(stamps) < 2:
            raise ImportDataError(path, "topic", f"topic {topic!r} holds {len(stamps)} message(s)",
                                  "record a longer session")
        frame_id = str(first.header.frame_id)
        temp = None
        if settings.get("temperature_topic"):
            ttopic, tconns = _connections(reader, path, settings, "temperature_topic", TEMPERATURE_TYPE)
            ts, tr, tv, _ = _read_topic(reader, tconns, TEMPERATURE_TYPE, ros1)
            temp = (ttopic, ts if source == "header" else tr, tv[:, 0])
    finally:
        reader.close()
    gyro, gcov, accel, acov = vals[:, 0:3], vals[:, 3], vals[:, 4:7], vals[:, 7]
    for name, cov in (("angular_velocity", gcov), ("linear_acceleration", acov)):
        if np.all(cov == -1.0):
            raise ImportDataError(path, "topic", f"topic {topic!r} does not provide {name} ({name}_covariance[0] = -1, "
                                  "REP 145)", "record the raw IMU topic (e.g. /imu/data_raw)")
    ns = stamps if source == "header" else recv
    bad = ~np.isfinite(vals[:, [0, 1, 2, 4, 5, 6]])
    if bad.any():
        i = int(np.argmax(bad.any(axis=1)))
        raise ImportDataError(path, "topic", f"message {i} of {topic!r} has NaN or Inf in angular_velocity / "
                              "linear_acceleration", "drop the bad messages before import")
    ns0_all = int(ns[0])
    t_all = (ns - ns0_all).astype(np.float64) * 1e-9
    keep = _window(settings, t_all)
    if keep.sum() < 2:
        raise serr(settings, "start_s", f"the window holds {int(keep.sum())} message(s) of {len(ns)} "
                   f"({t_all[-1]:.6g} s in all)", "widen start_s / stop_s")
    ns, gyro, accel = ns[keep], gyro[keep], accel[keep]
    ns0 = int(ns[0])
    t = (ns - ns0).astype(np.float64) * 1e-9
    d = np.diff(ns)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0))
        raise ImportDataError(path, f"{source} time", f"{topic!r}: stamps not strictly increasing at message {i + 1} "
                              f"({t[i]:.9f} s then {t[i + 1]:.9f} s from the first)",
                              "use time_source: receive (bag time)" if source == "header" else
                              "use time_source: header, or repair the bag")
    fs, clk = time_clock(path, t, f"{source} time", None, declared_rate(settings, required=False), settings)
    if clk.gaps:
        offset = (ns0 - ns0_all) * 1e-9
        where = "; ".join(f"{d_s:.6g} s after {t[j] + offset:.6f} s" for j, d_s in clk.gaps[:5])
        raise ImportDataError(path, f"{source} time", f"{topic!r}: {len(clk.gaps)} gap(s) in the stamps ({where}; "
                              "times from the first message): one recording holds one uniform clock",
                              "import the part before or after a gap with start_s / stop_s (seconds from the "
                              "first message; each part its own recording)")
    temperature = None
    extra = {}
    if temp is not None:
        ttopic, tns, tval = temp
        order = np.argsort(tns, kind="stable")
        tns, tval = tns[order], tval[order]
        ok = np.isfinite(tval)
        tns, tval = tns[ok], tval[ok]
        tt = (tns - ns0).astype(np.float64) * 1e-9
        if len(tt) == 0 or tt[-1] < t[0] or tt[0] > t[-1]:
            raise ImportDataError(path, "temperature_topic", f"{ttopic!r}: no finite temperature inside the IMU "
                                  f"span 0..{t[-1]:.6g} s ({len(tt)} message(s))", "name the temperature topic of "
                                  "this IMU, or leave temperature_topic out")
        temperature = np.interp(t, tt, tval)
        extra["temperature_source"] = (f"{ttopic} (sensor_msgs/msg/Temperature, {len(tt)} messages), linearly "
                                       "interpolated to the IMU samples, held outside its span")
    kind_text = {"ros1": "ROS 1 bag", "rosbag2": "rosbag2 folder", "mcap": "MCAP file",
                 "sqlite3": "rosbag2 sqlite3 file"}[kind]
    summary = (f"{topic}: {len(t)} messages, {t[-1]:.6g} s, rate {clk.describe()}")
    extra.update({"ros_topic": topic, "ros_bag_kind": kind_text, "ros_frame_id": frame_id,
                  "time_source": f"{source} ({'header.stamp' if source == 'header' else 'bag receive time'})",
                  "time_origin_unix_ns": str(ns0), "time_origin_unix_s": ns0 * 1e-9,
                  "ros_messages_in_window": int(len(t)), "import_summary": summary,
                  "body_frame": f"ROS frame {frame_id!r} of the messages (REP 103)"})
    extra.update(clk.attrs())
    return finish(settings, "rosbag", path, accel, gyro, fs, time=t, sources=_bag_files(path),
                  temperature=temperature, extra=extra, window=False)   # start_s / stop_s applied above
