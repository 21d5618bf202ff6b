"""Synthetic multi-position sessions (IMU-TK / Tedaldi protocol) for the field-calibration tests, with known truth."""
from __future__ import annotations

import numpy as np
import pytest

G = 9.81


def _rot(axis, angle):
    """DCM of a right-handed rotation by ``angle`` about unit ``axis`` (Rodrigues)."""
    k = np.asarray(axis, float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def misalign(p6):
    yz, zy, zx, xz, xy, yx = p6
    return np.array([[1.0, -yz, zy], [xz, 1.0, -zx], [-xy, yx, 1.0]])


def session(seed, *, fs=100.0, n_poses=20, rest_s=30.0, pose_s=3.0, turn_s=1.5, axes=None, start=None,
            drop=0.0, burst=None, gyro_noise=5e-4, accel_noise=3e-3):
    """A session: rest, then ``n_poses`` static poses separated by hand-like turns of 30-120 deg about random body
    axes (``axes``: a fixed axis for every turn instead). Truth: accel a = T_a K_a (N - b_a) (IMU-TK's 9
    parameters), gyro w = T_g K_g (N - b_g). Returns a dict with raw accel [m s-2], raw gyro [rad s-1], the
    arrival stamps (``burst``: steps of ``burst`` x the period, a short one every 40 samples; ``drop``: fraction
    of samples lost) and the truth."""
    rng = np.random.default_rng(seed)
    T = 1.0 / fs
    ka = 1 + 0.01 * rng.standard_normal(3)
    kg = 1 + 0.01 * rng.standard_normal(3)
    Ta = misalign([*(0.005 * rng.standard_normal(3)), 0, 0, 0])
    Tg = misalign(0.005 * rng.standard_normal(6))
    ba, bg = 0.05 * rng.standard_normal(3), 0.01 * rng.standard_normal(3)
    C = np.eye(3) if start is None else np.asarray(start, float)  # body -> level frame
    gn = np.array([0.0, 0.0, G])
    f, w = [], []

    def hold(C, dur):
        n = round(dur * fs)
        f.append(np.tile(C.T @ gn, (n, 1)))
        w.append(np.zeros((n, 3)))

    hold(C, rest_s)
    for _ in range(n_poses - 1):
        if axes is None:
            e = rng.standard_normal(3)
            e /= np.linalg.norm(e)
        else:
            e = np.asarray(axes, float)
        theta = np.radians(rng.uniform(30, 120)) * rng.choice([-1, 1])
        n = round(turn_s * fs)
        tt = np.arange(n) * T
        phi = theta / turn_s * (tt - turn_s / (2 * np.pi) * np.sin(2 * np.pi * tt / turn_s))
        rate = theta / turn_s * (1 - np.cos(2 * np.pi * tt / turn_s))
        f.append(np.array([(C @ _rot(e, p)).T @ gn for p in phi]))
        w.append(rate[:, None] * e[None, :])
        C = C @ _rot(e, theta)
        hold(C, pose_s + rng.uniform(0, 1))
    f, w = np.concatenate(f), np.concatenate(w)
    n = len(f)
    acc = (f @ np.linalg.inv(Ta @ np.diag(ka)).T) + ba + accel_noise * rng.standard_normal((n, 3))
    gyr = (w @ np.linalg.inv(Tg @ np.diag(kg)).T) + bg + gyro_noise * rng.standard_normal((n, 3))
    i = np.arange(n)
    t = 2.0 + i * T
    if burst is not None:
        t = t + (burst - 1.0) * T * ((i + rng.integers(40)) % 40)
    keep = np.ones(n, bool)
    if drop:
        keep = rng.random(n) >= drop
        keep[:2] = keep[-2:] = True
    return {"accel": acc[keep], "gyro": gyr[keep], "time": t[keep], "index": i[keep], "fs": fs,
            "gyro_scale_factors": 1.0 / kg, "accel_scale_factors": 1.0 / ka, "gravity": G}


def write_columns(tmp_path, s, *, with_time=True, gyro_factor=1.0, name="session.csv"):
    """The session as a delimited text file for the ``columns`` importer (time in s with 9 decimals)."""
    cols = [s["accel"], s["gyro"] * gyro_factor]
    header = "ax,ay,az,gx,gy,gz"
    fmt = ["%.9e"] * 6
    if with_time:
        cols.insert(0, s["time"][:, None])
        header = "t," + header
        fmt = ["%.9f"] + fmt
    p = tmp_path / name
    np.savetxt(p, np.column_stack(cols), delimiter=",", header=header, comments="", fmt=fmt)
    return p


def columns_settings(path, *, gyro_units="rad s-1", rate=None, with_time=True):
    s = {"format": "columns", "file": str(path), "delimiter": ",", "header": True, "latitude_deg": 45.0,
         "gravity_m_s2": G,
         "accel": {"columns": ["ax", "ay", "az"], "units": "m s-2", "sample_kind": "rate"},
         "gyro": {"columns": ["gx", "gy", "gz"], "units": gyro_units, "sample_kind": "rate"}}
    if with_time:
        s["time"] = {"column": "t", "units": "s"}
    if rate is not None:
        s["sample_rate_hz"] = rate
    return s


@pytest.fixture
def synthetic_session():
    return session


# ----------------------------------------------------------------------------- static-pose protocols

#: per-sample white noise of a typical MEMS IMU at 100 Hz (MPU-9150 class: about 400 ug/sqrt(Hz) and
#: 0.005 deg/s/sqrt(Hz) over a 40-50 Hz band): accel [m s-2], gyro [rad s-1]
MEMS_ACCEL_NOISE = 0.02
MEMS_GYRO_NOISE = 1e-3
#: raw counts of a +-16 g accelerometer and a +-2000 deg/s gyro (16-bit)
COUNTS_PER_G = 2048.0
COUNTS_PER_DEG_S = 16.4


def protocol_session(seed, *, fs=100.0, rest_s=None, n_poses=None, min_wait_s=None, noise=None, units=None):
    """A hand-made static-pose protocol with known truth, its parameters drawn from ``seed`` unless given:
    initial rest ``rest_s`` (2-60 s), ``n_poses`` poses after it (9-40), each held for a wait drawn from
    [``min_wait_s``, 5 s] (``min_wait_s`` 1-5 s), turns of 30-150 deg about random axes (1-2.5 s, smooth rate
    profile; the sensor 5-20 cm from the centre of the turns, the hand lifting it by up to 10 cm meanwhile) each
    followed by a 0.3 s settling wobble of up to 1 deg at 8 Hz; white noise ``noise`` (0.5-10, log-uniform)
    x :data:`MEMS_ACCEL_NOISE` / :data:`MEMS_GYRO_NOISE`; ``units`` "SI" (m s-2, rad s-1) or "count" (raw
    integers of a +-16 g accelerometer and a +-2000 deg/s gyro). Truth: IMU-TK's models ``a = T_a K_a (N - b_a)``
    (T_a upper triangular) and ``w = T_g K_g (N - b_g)``, gains within a few % of nominal.

    Returns a dict: ``accel``, ``gyro`` (raw, recording units), ``intervals`` (the true static holds
    ``[start, stop)``), ``accel_scale_factors`` (input units per m s-2), ``units``, ``fs``, ``gravity``, the drawn
    protocol (``rest_s``, ``n_poses``, ``min_wait_s``, ``noise``) and :func:`protocol_dataset` builds the
    recording."""
    rng = np.random.default_rng(seed)
    rest_s = rng.uniform(2.0, 60.0) if rest_s is None else float(rest_s)
    n_poses = int(rng.integers(9, 41)) if n_poses is None else int(n_poses)
    min_wait_s = rng.uniform(1.0, 5.0) if min_wait_s is None else float(min_wait_s)
    noise = float(np.exp(rng.uniform(np.log(0.5), np.log(10.0)))) if noise is None else float(noise)
    units = ("SI", "count")[int(rng.integers(2))] if units is None else units
    T = 1.0 / fs
    ka = 1 + 0.02 * rng.standard_normal(3)
    kg = 1 + 0.02 * rng.standard_normal(3)
    Ta = misalign([*(0.01 * rng.standard_normal(3)), 0, 0, 0])
    Tg = misalign(0.01 * rng.standard_normal(6))
    q = rng.standard_normal(3)
    C = _rot(q / np.linalg.norm(q), rng.uniform(0, np.pi))  # body -> level frame
    gn = np.array([0.0, 0.0, G])
    f, w, iv = [], [], []
    n0 = 0

    def hold(C, dur):
        nonlocal n0
        n = int(round(dur * fs))
        f.append(np.tile(C.T @ gn, (n, 1)))
        w.append(np.zeros((n, 3)))
        iv.append((n0, n0 + n))
        n0 += n

    def move(C, e, phi, rate, accel, lift):
        """A turn about body axis ``e`` by angles ``phi`` (rates ``rate``, angular accelerations ``accel``) about a
        centre ``arm`` away from the sensor, while the hand lifts the unit by ``lift`` (level frame, m s-2)."""
        nonlocal n0
        # every sample at once: the operations of ``_rot(e, p)`` and of ``(C @ _rot(e, p)).T @ (gn + lift)`` sample
        # by sample, in the same order (the session is bit-identical to the per-sample loop's, 30 times faster)
        k = np.asarray(e, float)
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        Cb = C @ (np.eye(3) + np.sin(phi)[:, None, None] * K + ((1 - np.cos(phi))[:, None, None] * K) @ K)
        om, al = rate[:, None] * e, accel[:, None] * e
        fb = (np.swapaxes(Cb, 1, 2) @ (gn + lift)[:, :, None])[:, :, 0]
        f.append(fb + np.cross(al, arm) + np.cross(om, np.cross(om, arm)))
        w.append(rate[:, None] * e[None, :])
        n0 += len(phi)

    arm = rng.standard_normal(3)
    arm *= rng.uniform(0.05, 0.2) / np.linalg.norm(arm)  # sensor from the centre of the hand's turns [m]
    hold(C, rest_s)
    for _ in range(n_poses):
        e = rng.standard_normal(3)
        e /= np.linalg.norm(e)
        theta = np.radians(rng.uniform(30, 150)) * rng.choice([-1, 1])
        d = rng.uniform(1.0, 2.5)
        tt = np.arange(int(round(d * fs))) * T
        c, sn = np.cos(2 * np.pi * tt / d), np.sin(2 * np.pi * tt / d)
        lift = np.outer(0.5 * rng.uniform(0.0, 0.2) * (2 * np.pi / d) ** 2 * c, [0.0, 0.0, 1.0])
        move(C, e, theta / d * (tt - d / (2 * np.pi) * sn), theta / d * (1 - c), theta / d * 2 * np.pi / d * sn,
             lift)
        C = C @ _rot(e, theta)
        e2 = rng.standard_normal(3)
        e2 /= np.linalg.norm(e2)
        amp, om, ds_ = np.radians(rng.uniform(0.0, 1.0)), 2 * np.pi * 8.0, 0.3
        tt = np.arange(int(round(ds_ * fs))) * T
        env, denv, d2env = (1 - tt / ds_) ** 2, -2 * (1 - tt / ds_) / ds_, 2 / ds_ ** 2
        psi = amp * np.sin(om * tt) * env
        dpsi = amp * (om * np.cos(om * tt) * env + np.sin(om * tt) * denv)
        d2psi = amp * (-om ** 2 * np.sin(om * tt) * env + 2 * om * np.cos(om * tt) * denv + np.sin(om * tt) * d2env)
        move(C, e2, psi, dpsi, d2psi, np.zeros((len(tt), 3)))
        hold(C, rng.uniform(min_wait_s, 5.0))
    f, w = np.vstack(f), np.concatenate(w)
    n = len(f)
    if units == "SI":
        ca, cg = 1.0, 1.0
        ba, bg = 0.1 * rng.standard_normal(3), 0.01 * rng.standard_normal(3)
    else:
        ca, cg = COUNTS_PER_G / 9.80665, COUNTS_PER_DEG_S * 180.0 / np.pi
        ba, bg = 20.0 * rng.standard_normal(3), 20.0 * rng.standard_normal(3)
    gain_a, gain_g = ka / ca, kg / cg  # output per input unit
    acc = f @ np.linalg.inv(Ta @ np.diag(gain_a)).T + ba + ca * MEMS_ACCEL_NOISE * noise * rng.standard_normal((n, 3))
    gyr = w @ np.linalg.inv(Tg @ np.diag(gain_g)).T + bg + cg * MEMS_GYRO_NOISE * noise * rng.standard_normal((n, 3))
    if units == "count":
        acc, gyr = np.round(acc), np.round(gyr)
    return {"accel": acc, "gyro": gyr, "intervals": np.array(iv, dtype=np.int64), "units": units, "fs": fs,
            "gravity": G, "accel_scale_factors": 1.0 / gain_a, "gyro_scale_factors": 1.0 / gain_g,
            "rest_s": rest_s, "n_poses": n_poses, "min_wait_s": min_wait_s, "noise": noise}


def protocol_dataset(s, *, protocol_attrs=False):
    """The recording of a :func:`protocol_session` (in memory); counts carry their nominal ``approx_counts_per_g``
    / ``approx_counts_per_deg_s``; ``protocol_attrs``: also the protocol timing as ``protocol_*`` attributes."""
    from calib.io import recording

    counts = s["units"] == "count"
    extra = {}
    if protocol_attrs:
        extra = {"protocol_initial_rest_s": s["rest_s"], "protocol_min_wait_s": s["min_wait_s"],
                 "protocol_n_poses": s["n_poses"]}
    ds = recording.make_dataset(s["accel"], s["gyro"], sample_rate_hz=s["fs"], latitude_deg=45.0,
                                accel_units="count" if counts else "m s-2", gyro_units="count" if counts else "rad s-1",
                                gravity_m_s2=s["gravity"], source="recorded", extra_attrs=extra)
    if counts:
        ds["accel"].attrs["approx_counts_per_g"] = COUNTS_PER_G
        ds["gyro"].attrs["approx_counts_per_deg_s"] = COUNTS_PER_DEG_S
    return ds
