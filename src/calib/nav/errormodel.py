"""Linearised error model of a stationary pure-inertial INS in ENU (He 2019 eqs. 4-8), vertical channel removed.

State (7) and inputs (6, body frame)::

    x = [phi_E, phi_N, phi_U, dvE, dvN, dL, dlambda]       [rad, rad, rad, m/s, m/s, rad, rad]
    u = [eps_x, eps_y, eps_z, nabla_x, nabla_y, nabla_z]   gyro drift [rad/s], accelerometer bias [m/s^2]

Conventions (those of :mod:`calib.core.rotations` and :mod:`calib.nav.strapdown`): measured = true + error;
the misalignment phi is defined by C_b^n(computed) = (I - [phi x]) C_b^n(true); errors are computed minus
true. On a stationary base (v = 0, omega_en = 0, omega_in = omega_ie = (0, W cos L, W sin L)) He 2019
eqs. (4)-(7) become::

    phi'   = phi x omega_ie + d(omega_ie) + d(omega_en) - C_b^n eps
    dv'    = f^n x phi - 2 omega_ie x dv + C_b^n nabla             (f^n = (0, 0, g); horizontal part)
    dL'    = dvN / (R_M + h)
    dlam'  = dvE / ((R_N + h) cos L)

with d(omega_ie) = (0, -W sin L dL, W cos L dL) and d(omega_en) = (-dvN/(R_M+h), dvE/(R_N+h),
dvE tan L/(R_N+h)). Written out (W_N = W cos L, W_U = W sin L, R_M, R_N including h)::

    phi_E' =  W_U phi_N - W_N phi_U - dvN/R_M                       - eps_E
    phi_N' = -W_U phi_E + dvE/R_N - W_U dL                           - eps_N
    phi_U' =  W_N phi_E + dvE tan L/R_N + W_N dL                     - eps_U
    dvE'   = -g phi_N + 2 W_U dvN                                    + nabla_E
    dvN'   =  g phi_E - 2 W_U dvE                                    + nabla_N
    dL'    =  dvN / R_M
    dlam'  =  dvE sec L / R_N

The +-2 W sin L couplings of the velocity errors are the Coriolis (Foucault) terms: they split the
Schuler frequency omega_s = sqrt(g/R) into the pair sqrt(omega_s^2 + omega_F^2) +- omega_F with
omega_F = W sin L (an 84-min oscillation whose envelope beats with the ~34-h Foucault period at 30.58 deg),
besides the 24-h Earth-rate mode. The closed forms of He 2019 eqs. (9)-(15) ignore this coupling (and carry
dimensional slips), so they are not used as reference; the model is integrated exactly instead: with the
constant inputs appended to the state, z = [x; u] obeys z' = A z, A = [[F, G], [0, 0]], and
z(t) = expm(A t) z(0). :func:`transition` evaluates expm once per output step and propagates on a uniform
grid by repeated products (blocked, vectorised).

Secular behaviour worth knowing (follows from the steady state of the equations above): a constant drift
makes the longitude error grow at d(lambda)/dt = eps_N cos L + eps_U sin L (the drift component along the
Earth's axis), while an east drift produces a constant heading error -eps_E/(W cos L) -- the reason the
east drift is unobservable after self-alignment (see :mod:`calib.nav.alignment`).
"""
from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import xarray as xr

from calib.core import earth
from calib.core.rotations import dcm_to_euler, rot_x, rot_z, skew

STATE_NAMES = ("phi_E", "phi_N", "phi_U", "vE_err", "vN_err", "lat_err", "lon_err")
STATE_UNITS = ("rad", "rad", "rad", "m s-1", "m s-1", "rad", "rad")
NX, NU = 7, 6


def f_matrix(lat, h=0.0, radius=None, gravity=None):
    """System matrix F (7x7) of the stationary error model at latitude ``lat`` [rad], height ``h`` [m].

    ``radius`` [m] replaces both R_M + h and R_N + h (spherical Earth, for closed-form checks);
    ``gravity`` [m/s^2] replaces the WGS-84 normal gravity.
    """
    W = earth.OMEGA_IE
    wN, wU = W * math.cos(lat), W * math.sin(lat)
    if radius is None:
        r_m, r_n = earth.radii(lat)
        RM, RN = float(r_m) + h, float(r_n) + h
    else:
        RM = RN = float(radius)
    g = float(earth.normal_gravity(lat, h)) if gravity is None else float(gravity)
    F = np.zeros((NX, NX))
    F[0, 1], F[0, 2], F[0, 4] = wU, -wN, -1.0 / RM
    F[1, 0], F[1, 3], F[1, 5] = -wU, 1.0 / RN, -wU
    F[2, 0], F[2, 3], F[2, 5] = wN, math.tan(lat) / RN, wN
    F[3, 1], F[3, 4] = -g, 2.0 * wU
    F[4, 0], F[4, 3] = g, -2.0 * wU
    F[5, 4] = 1.0 / RM
    F[6, 3] = 1.0 / (RN * math.cos(lat))
    return F


def g_matrix(C_bn):
    """Input matrix G (7x6): body-frame gyro drift [rad/s] and accelerometer bias [m/s^2] to the state rates."""
    C = np.asarray(C_bn, float)
    G = np.zeros((NX, NU))
    G[0:3, 0:3] = -C
    G[3:5, 3:6] = C[0:2, :]
    return G


def system_matrix(lat, C_bn, h=0.0, drift_coupling=None, **kw):
    """Augmented matrix A (13x13) of z = [x; u]: z' = A z.

    ``drift_coupling`` (3,) body drift [rad/s], optional: adds the term phi x (C_b^n eps) that the
    linearisation drops (the drift acts through the *computed* C_b^n = (I - [phi x]) C_b^n). It is
    bilinear in drift and misalignment, so with it the model is no longer linear in the drift; it matters
    only over many Earth-rate periods, where it drives the 24-h mode at its own frequency (a response
    growing like t; ~1-3 % of the attitude and velocity errors after 240 h at 0.01 deg/h).
    """
    A = np.zeros((NX + NU, NX + NU))
    A[:NX, :NX] = f_matrix(lat, h, **kw)
    A[:NX, NX:] = g_matrix(C_bn)
    if drift_coupling is not None:
        e = np.asarray(C_bn, float) @ np.asarray(drift_coupling, float)
        A[0:3, 0:3] -= skew(e)
    return A


def _uniform_step(t):
    t = np.asarray(t, float)
    if t.ndim != 1 or t.size == 0:
        raise ValueError("t must be a non-empty 1-D array of times [s]")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t must be strictly increasing")
    if t[0] < 0:
        raise ValueError("t must start at or after 0 (the start of navigation)")
    if t.size == 1:
        return None
    d = np.diff(t)
    step = (t[-1] - t[0]) / (t.size - 1)
    return step if np.max(np.abs(d - step)) <= 1e-9 * max(step, 1.0) else None


def transition(t, A, Z0, block=512):
    """States ``expm(A t_k) Z0`` for all ``t_k`` (times from the start [s]); returns (N, n, m).

    ``Z0`` (n, m) initial columns. On a uniform grid one ``expm`` per output step is propagated by
    products (blocks of ``block`` steps vectorised); otherwise one ``expm`` per time.
    """
    t = np.asarray(t, float)
    Z0 = np.asarray(Z0, float)
    squeeze = Z0.ndim == 1
    if squeeze:
        Z0 = Z0[:, None]
    step = _uniform_step(t)
    n, m = Z0.shape
    out = np.empty((t.size, n, m))
    if step is None:
        for k, tk in enumerate(t):
            out[k] = scipy.linalg.expm(A * tk) @ Z0
    else:
        Phi = scipy.linalg.expm(A * step)
        B = min(block, t.size)
        P = np.empty((B, n, n))
        P[0] = np.eye(n)
        for j in range(1, B):
            P[j] = Phi @ P[j - 1]
        PhiB = Phi @ P[B - 1]
        z = scipy.linalg.expm(A * t[0]) @ Z0
        for k0 in range(0, t.size, B):
            k1 = min(k0 + B, t.size)
            out[k0:k1] = np.einsum("bij,jm->bim", P[: k1 - k0], z)
            z = PhiB @ z
    return out[:, :, 0] if squeeze else out


def sensitivity(t, lat, C_bn, h=0.0, **kw):
    """Linear map from constant sensor errors to the error time series.

    Returns ``S`` (N, 7, 6): ``x(t_k) = S[k] @ [eps_x, eps_y, eps_z, nabla_x, nabla_y, nabla_z]`` (body frame,
    rad/s and m/s^2) for a start from zero errors; memory N*42*8 bytes (3 h at 1 s: 3.6 MB).
    """
    A = system_matrix(lat, C_bn, h, **kw)
    Z0 = np.zeros((NX + NU, NU))
    Z0[NX:, :] = np.eye(NU)
    return transition(t, A, Z0)[:, :NX, :]


def initial_sensitivity(t, lat, h=0.0, **kw):
    """Response (N, 7, 7) to the initial errors: ``x(t_k) = Phi[k] @ x(0)`` (inputs zero)."""
    F = f_matrix(lat, h, **kw)
    return transition(t, F, np.eye(NX))


def phi_to_euler_error(phi, pitch, roll, yaw):
    """Linear map from the misalignment phi (..., 3) [rad] to (d_pitch, d_roll, d_yaw) [rad].

    From C_b^n = Rz(yaw) Rx(pitch) Ry(roll): -[phi x] = dC C^T gives
    -phi = d_yaw e_z + d_pitch Rz(yaw) e_x + d_roll Rz(yaw) Rx(pitch) e_y.
    """
    M = np.column_stack([rot_z(yaw)[:, 0], (rot_z(yaw) @ rot_x(pitch))[:, 1], [0.0, 0.0, 1.0]])
    return -np.asarray(phi) @ np.linalg.inv(M).T


def error_response(t, lat, drift_body=(0.0, 0.0, 0.0), accel_bias_body=(0.0, 0.0, 0.0), C_bn=None, h=0.0,
                   x0=None, drift_coupling=False, **kw) -> xr.Dataset:
    """Navigation errors of a stationary INS predicted by the linear model, integrated exactly.

    t [s] from the start of navigation; lat [rad]; drift_body [rad/s]; accel_bias_body [m/s^2];
    C_bn the true attitude (default identity); x0 optional initial state (7,); ``drift_coupling`` adds the
    bilinear phi x eps^n term (see :func:`system_matrix`). Returns a Dataset on ``time`` [h] with
    phi_E, phi_N, phi_U [rad], vE_err, vN_err [m/s], lat_err, lon_err [rad] and the Euler-angle errors
    pitch_err, roll_err, yaw_err [rad] (linearised about the true attitude).
    """
    C = np.eye(3) if C_bn is None else np.asarray(C_bn, float)
    z0 = np.zeros(NX + NU)
    if x0 is not None:
        z0[:NX] = x0
    z0[NX:NX + 3] = drift_body
    z0[NX + 3:] = accel_bias_body
    A = system_matrix(lat, C, h, drift_coupling=np.asarray(drift_body, float) if drift_coupling else None, **kw)
    X = transition(t, A, z0)[:, :NX]
    p, r, y = dcm_to_euler(C)
    eul = phi_to_euler_error(X[:, 0:3], float(p), float(r), float(y))
    data = {name: (("time",), X[:, i], {"units": u}) for i, (name, u) in enumerate(zip(STATE_NAMES, STATE_UNITS))}
    for i, name in enumerate(("pitch_err", "roll_err", "yaw_err")):
        data[name] = (("time",), eul[:, i], {"units": "rad"})
    return xr.Dataset(data, coords={"time": ("time", np.asarray(t, float) / 3600.0, {"units": "h"})},
                      attrs={"model": "linearised stationary INS error model, ENU, vertical removed",
                             "latitude_rad": float(lat)})


def longitude_rate(lat, drift_body, C_bn=None):
    """Secular longitude-error rate [rad/s] of a constant drift: eps_N cos L + eps_U sin L (steady state)."""
    C = np.eye(3) if C_bn is None else np.asarray(C_bn, float)
    e = C @ np.asarray(drift_body, float)
    return e[1] * math.cos(lat) + e[2] * math.sin(lat)


def mode_frequencies(lat, h=0.0, **kw):
    """Positive oscillation frequencies [rad/s] of F, sorted: Earth rate, Schuler-minus, Schuler-plus."""
    ev = np.linalg.eigvals(f_matrix(lat, h, **kw))
    w = np.sort(np.abs(ev.imag[ev.imag > 1e-12]))
    return w


def discretize(F, Qc, dt):
    """``(Phi, Qd)`` of the linear model dx/dt = F x + w, E[w w^T] = Qc delta: Phi = expm(F dt) and the exact
    discrete process-noise covariance Qd = int_0^dt expm(F s) Qc expm(F s)^T ds, both from one matrix exponential
    (Van Loan 1978); Qd symmetrised."""
    n = F.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -F
    M[:n, n:] = Qc
    M[n:, n:] = F.T
    E = scipy.linalg.expm(M * dt)
    Phi = E[n:, n:].T
    Qd = Phi @ E[:n, n:]
    return Phi, 0.5 * (Qd + Qd.T)
