"""Self-alignment of a stationary strapdown INS: coarse (analytic double-vector) and fine (least squares).

Coarse alignment
----------------
Gravity and the Earth rate are known in ENU, f^n = (0, 0, g) and omega_ie^n = (0, W cos L, W sin L), and
measured (time-averaged) in the body frame. Two non-parallel vectors fix the attitude: build the
orthonormal triads (f, f x w, f x (f x w)) in both frames; C_b^n = N B^T.

Fine alignment
--------------
Navigate the window from the coarse attitude with the vertical channel held; at rest the velocity must
stay zero, and by the linear error model (:mod:`calib.nav.errormodel`) the velocity errors over the window are
linear in the initial misalignment phi0 and the north gyro drift eps_N: dv(t) = S(t) [phi0; eps_N].
Least squares gives them, the attitude is corrected (C = exp([phi0 x]) C_computed), eps_N compensated,
and the pass repeated (Gauss-Newton; two or three passes converge to the rounding level on clean data).

What self-alignment makes unobservable
--------------------------------------
Both methods converge to the *equilibrium* of the error equations rather than to the true attitude when
the sensors have constant errors (nabla, eps in ENU components)::

    phi_E = -nabla_N / g,   phi_N = nabla_E / g,   phi_U = (W sin L phi_N - eps_E) / (W cos L)

The level accelerometer biases are exactly compensated by a tilt (after alignment the horizontal
velocity sees nabla - g x tilt = 0), and the east gyro drift by a heading error (the platform's east axis
is placed where the measured horizontal Earth rate has no component). Consequently, after self-alignment,
the level accelerometer biases and the east gyro drift produce no Schuler/Earth-rate oscillation at the
start of navigation: they hide in tilt and heading, and a drift estimator fed with self-aligned runs
cannot see eps_E at all (and nabla_E, nabla_N only through the slow Earth-rate coupling of the tilt).
"""
from __future__ import annotations

import math

import numpy as np

from calib.core import earth
from calib.nav import errormodel
from calib.nav import strapdown
from calib.core.rotations import rotvec_to_dcm


def _triad(a, b):
    u1 = a / np.linalg.norm(a)
    u2 = np.cross(a, b)
    u2 = u2 / np.linalg.norm(u2)
    u3 = np.cross(u1, u2)
    return np.column_stack([u1, u2, u3])


def coarse_align(f_b, w_b, lat: float, h: float = 0.0):
    """C_b^n from the mean specific force f_b [m/s^2] and angular rate w_b [rad/s] (body frame) at rest."""
    f_n = np.array([0.0, 0.0, float(earth.normal_gravity(lat, h))])
    w_n = earth.earth_rate_enu(lat)
    if abs(math.cos(lat)) < 1e-3:
        raise ValueError("coarse alignment: Earth rate and gravity are parallel at the pole; heading is undefined")
    return _triad(f_n, w_n) @ _triad(np.asarray(f_b, float), np.asarray(w_b, float)).T


def coarse_align_increments(dtheta, dv, dt: float, lat: float, h: float = 0.0):
    """Coarse alignment from high-rate increments dtheta [rad], dv [m/s] (n, 3) over a stationary window."""
    T = len(dtheta) * dt
    return coarse_align(np.sum(dv, axis=0) / T, np.sum(dtheta, axis=0) / T, lat, h)


def fine_align(Dtheta, Dv, dt_nav: float, lat: float, h: float, C0, out_every: int = 10, iterations: int = 3,
               lon: float = 0.0, estimate_north_drift: bool = True):
    """Least-squares fine alignment on the velocity errors of a stationary window of nav-rate increments.

    Unknowns: the initial misalignment phi0 (3) and, by default, the north component of the gyro drift
    eps_N [rad/s] (observable at rest: it makes phi_N ramp and vE grow like t^2; left out, it biases the
    tilt and heading). Returns ``(C_bn, info)`` with the corrected attitude and
    ``info = {"phi0": last correction [rad], "eps_N": estimate [rad/s] or None}``.
    """
    C = np.asarray(C0, float).copy()
    m = len(Dtheta) // out_every
    if m < 4:
        raise ValueError("fine alignment: window too short for four velocity samples")
    t = np.arange(1, m + 1) * out_every * dt_nav
    cols = [errormodel.initial_sensitivity(t, lat, h)[:, 3:5, 0:3]]
    if estimate_north_drift:
        # drift along ENU north: body drift C^T e_N; with C_bn = I the body axes are ENU
        cols.append(errormodel.sensitivity(t, lat, np.eye(3), h)[:, 3:5, 1:2])
    S = np.concatenate(cols, axis=2).reshape(2 * m, -1)
    p = np.zeros(S.shape[1])
    eps_n = 0.0
    for _ in range(iterations):
        init = strapdown.NavInit(lat=lat, lon=lon, h=h, C_bn=C)
        gb = (C.T @ np.array([0.0, eps_n, 0.0]))[None, :]
        out, _st = strapdown.navigate_multi(Dtheta[: m * out_every], Dv[: m * out_every], dt_nav, init, gb,
                                            out_every=out_every, parallel=False)
        y = out[0, :, 3:5].reshape(-1)
        p, *_ = np.linalg.lstsq(S, y, rcond=None)
        C = rotvec_to_dcm(p[:3]) @ C  # C_computed = (I - [phi x]) C_true  =>  C_true = exp([phi x]) C_computed
        if estimate_north_drift:
            eps_n += p[3]
    return C, {"phi0": p[:3], "eps_N": eps_n if estimate_north_drift else None}


def align(dtheta, dv, dt: float, lat: float, h: float = 0.0, n_sub: int = 10, fine: bool = True, iterations: int = 3):
    """Coarse, then (optionally) fine alignment on high-rate increments of a stationary window; returns C_b^n."""
    n = len(dtheta) - len(dtheta) % n_sub
    C = coarse_align_increments(dtheta[:n], dv[:n], dt, lat, h)
    if not fine:
        return C
    Dth, Dv = strapdown.preintegrate(dtheta[:n], dv[:n], n_sub)
    out_every = max(1, int(round(1.0 / (n_sub * dt))))  # velocity samples every ~1 s
    C, _info = fine_align(Dth, Dv, n_sub * dt, lat, h, C, out_every=out_every, iterations=iterations)
    return C


def equilibrium_misalignment(lat: float, C_bn, drift_body=(0.0, 0.0, 0.0), accel_bias_body=(0.0, 0.0, 0.0), h=0.0):
    """The misalignment phi [rad] self-alignment converges to with constant sensor errors (module docstring)."""
    C = np.asarray(C_bn, float)
    e = C @ np.asarray(drift_body, float)
    a = C @ np.asarray(accel_bias_body, float)
    g = float(earth.normal_gravity(lat, h))
    phiE, phiN = -a[1] / g, a[0] / g
    W = earth.OMEGA_IE
    phiU = (W * math.sin(lat) * phiN - e[0]) / (W * math.cos(lat))
    return np.array([phiE, phiN, phiU])
