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
