"""Pure-inertial strapdown navigation in the ENU local-level frame (WGS-84), compiled with numba.

(Kept as one module of ~660 lines on purpose: the two-speed, single-speed and multi-stream kernels share
``inline='always'`` numba helpers and one state layout; split across modules they would no longer be inlined
into one compiled loop, and the loop is the hot path of the whole study.)

Frames, units, conventions
--------------------------
* ``n`` = East-North-Up local-level frame, ``b`` = IMU body frame (Liu 2021 unit: right-front-up).
* Inputs are body-frame *increments* per sample: ``dtheta`` [rad] (integral of the angular rate
  omega_ib^b) and ``dv`` [m/s] (integral of the specific force f^b).
* Attitude is the quaternion of C_b^n (scalar first, :mod:`calib.core.rotations`); outputs are pitch, roll,
  yaw [rad] with C_b^n = Rz(yaw) Rx(pitch) Ry(roll); vE, vN, vU [m/s]; lat, lon [rad]; h [m].
* The navigation equations are He 2019 eqs. (1)-(3) with the WGS-84 radii R_M, R_N, normal gravity and
  Earth rate of :mod:`calib.core.earth`.

Algorithm (two-speed, after Savage, "Strapdown inertial navigation integration algorithm design", 1998)
-------------------------------------------------------------------------------------------------------
High rate (every sample, :func:`preintegrate`): over the ``n_sub`` samples of one navigation interval
the increments are summed, alpha = sum dtheta and v = sum dv, together with the recursive two-sample
coning and sculling terms (each uses the current and the previous sample, also across interval
boundaries)::

    d_beta  = 1/2 (alpha_{l-1} + dtheta_{l-1}/6) x dtheta_l                 (coning)
    d_scul  = 1/2 [(alpha_{l-1} + dtheta_{l-1}/6) x dv_l + (v_{l-1} + dv_{l-1}/6) x dtheta_l]

and the navigation-rate increments are ``Dtheta = alpha + beta`` and ``Dv = v + scul`` (the velocity
*rotation* term is not included there: it is applied in the navigation update, so that a per-stream gyro
compensation changes it exactly; see :func:`navigate_multi`).

Navigation rate (interval T = n_sub dt, :func:`navigate`):

1. Earth quantities at the current position: R_M, R_N, g(lat, h), omega_ie^n, omega_en^n.
2. velocity: Dv_sf^b = Dv + c1 Dtheta x Dv + c2 Dtheta x (Dtheta x Dv) (rotation compensation, c1 ~ 1/2,
   c2 ~ 1/6, Savage's exact coefficients for a fixed rotation axis), Dv_sf^n = (I - T/2 [omega_in^n x])
   C_b^n Dv_sf^b, v += Dv_sf^n + T (g^n - (2 omega_ie^n + omega_en^n) x v)                  (He 2019 eq. 2)
3. position with the mean velocity of the interval: lat += T vN/(R_M + h), lon += T vE/((R_N + h) cos lat)
                                                                                           (He 2019 eq. 3)
4. attitude: q = q(-omega_in^n T) * q * q(Dtheta) with exact rotation-vector quaternions; omega_in^n at
   mid-interval (mean of old and new velocity, mean latitude), matching the mid-interval attitude the
   velocity update sees: the discrete Schuler loop is then area-preserving (no spurious amplitude growth
   or decay over 240 h)                                                                      (He 2019 eq. 1)

The single-speed path is the same with ``n_sub = 1`` (the coning/sculling terms then reduce to the
classical "previous sample" corrections dtheta_{k-1} x dtheta_k / 12).

Vertical channel
----------------
Default ``vertical="hold"``: height fixed to its initial value and vU = 0. In pure inertial mode the
vertical channel is unstable: a height error dh changes the computed gravity by 2 g/R dh, which feeds
back positively (d2(dh)/dt2 = +2 g/R dh), so any error grows like exp(sqrt(2) omega_s t) with a time
constant of about 9 minutes -- after a few hours the height and vU are meaningless and, through the
Coriolis and transport-rate terms, they would contaminate the horizontal channels that He 2019 studies.
``"free"`` integrates the vertical channel as is (for demonstration); ``"damped"`` closes a second-order
loop on the initial height (a barometer-like reference) with natural period ``vertical_period_s``.

Numerics
--------
Every 3x3 product is written out; trig is replaced by series below 0.1 rad (error < 1e-16); the kernels
allow fused multiply-add contraction (LLVM ``contract``) and nothing else of fast-math, so results are
deterministic on a given machine and may differ between CPUs only at the rounding level.
:mod:`calib.nav.strapdown_reference` is a plain numpy implementation of the same algorithm written
independently (DCMs and :mod:`calib.core.rotations`), used by the tests to check the compiled kernels sample
for sample.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from calib.core import earth
from calib.core.rotations import dcm_to_quat, euler_to_dcm

# --- constants baked into the kernels ---------------------------------------------------------------
_A = earth.A
_E2 = earth.E2
_F = earth.F
_OMEGA = earth.OMEGA_IE
_GE = earth.GAMMA_E
_KS = earth.K_SOMIGLIANA
_MR = earth.M_RATIO

#: per-stream state vector layout: q0..q3, vE vN vU, lat lon h, h_ref, sin lat, cos lat, lat of last exact trig
NX = 14
IQ0, IVE, IVN, IVU, ILAT, ILON, IH, IHREF, ISL, ICL, ILREF = 0, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13
#: fields of one output record
OUT_FIELDS = ("pitch", "roll", "yaw", "vE", "vN", "vU", "lat", "lon", "h")
NOUT = len(OUT_FIELDS)
VERTICAL_MODES = {"hold": 0, "free": 1, "damped": 2}
#: LLVM fast-math flags of the kernels: only 'contract' (fused multiply-add), no reassociation, so results
#: are as accurate as plain IEEE arithmetic and deterministic for a given machine
_FM = {"contract"}
# The kernels called from Python are compiled with nogil=True: they run without the GIL, so the next slice of a
# recording is read while they navigate this one (calib.nav.reader.for_each_chunk).


# ======================================================================================================
# compiled kernels
# ======================================================================================================
#: layout of the pre-integration carry: previous sample (dtheta, dv), partial sums alpha, v, beta, scul,
#: number of samples already summed in the open interval
NPC = 19


@njit(cache=True, fastmath=_FM, inline="always")
def _pre_accum(p0, p1, p2, p3, p4, p5, a0, a1, a2, v0, v1, v2, b0, b1, b2, c0, c1, c2,
               t0, t1, t2, u0, u1, u2):  # pragma: no cover - compiled
    """Add one sample (t = dtheta, u = dv) to the open interval (recursive coning/sculling, Savage)."""
    s6 = 1.0 / 6.0
    x0 = a0 + s6 * p0
    x1 = a1 + s6 * p1
    x2 = a2 + s6 * p2
    y0 = v0 + s6 * p3
    y1 = v1 + s6 * p4
    y2 = v2 + s6 * p5
    b0 += 0.5 * (x1 * t2 - x2 * t1)
    b1 += 0.5 * (x2 * t0 - x0 * t2)
    b2 += 0.5 * (x0 * t1 - x1 * t0)
    c0 += 0.5 * ((x1 * u2 - x2 * u1) + (y1 * t2 - y2 * t1))
    c1 += 0.5 * ((x2 * u0 - x0 * u2) + (y2 * t0 - y0 * t2))
    c2 += 0.5 * ((x0 * u1 - x1 * u0) + (y0 * t1 - y1 * t0))
    return (t0, t1, t2, u0, u1, u2, a0 + t0, a1 + t1, a2 + t2, v0 + u0, v1 + u1, v2 + u2,
            b0, b1, b2, c0, c1, c2)


@njit(cache=True, fastmath=_FM, nogil=True)
def _preint_kernel(dth, dv, n_sub, pc, Dth, Dv):  # pragma: no cover - compiled
    """Pre-integrate samples into completed intervals (written to Dth, Dv); returns their number.

    ``pc`` (NPC,) carries the previous sample and the partial sums of the open interval across calls.
    """
    p0, p1, p2, p3, p4, p5 = pc[0], pc[1], pc[2], pc[3], pc[4], pc[5]
    a0, a1, a2, v0, v1, v2 = pc[6], pc[7], pc[8], pc[9], pc[10], pc[11]
    b0, b1, b2, c0, c1, c2 = pc[12], pc[13], pc[14], pc[15], pc[16], pc[17]
    cnt = int(pc[18])
    j = 0
    for k in range(dth.shape[0]):
        (p0, p1, p2, p3, p4, p5, a0, a1, a2, v0, v1, v2, b0, b1, b2, c0, c1, c2) = _pre_accum(
            p0, p1, p2, p3, p4, p5, a0, a1, a2, v0, v1, v2, b0, b1, b2, c0, c1, c2,
            dth[k, 0], dth[k, 1], dth[k, 2], dv[k, 0], dv[k, 1], dv[k, 2])
        cnt += 1
        if cnt == n_sub:
            Dth[j, 0] = a0 + b0
            Dth[j, 1] = a1 + b1
            Dth[j, 2] = a2 + b2
            Dv[j, 0] = v0 + c0
            Dv[j, 1] = v1 + c1
            Dv[j, 2] = v2 + c2
            j += 1
            cnt = 0
            a0 = a1 = a2 = v0 = v1 = v2 = b0 = b1 = b2 = c0 = c1 = c2 = 0.0
    pc[0], pc[1], pc[2], pc[3], pc[4], pc[5] = p0, p1, p2, p3, p4, p5
    pc[6], pc[7], pc[8], pc[9], pc[10], pc[11] = a0, a1, a2, v0, v1, v2
    pc[12], pc[13], pc[14], pc[15], pc[16], pc[17] = b0, b1, b2, c0, c1, c2
    pc[18] = cnt
    return j


@njit(cache=True, fastmath=_FM, inline="always")
def _rv_quat(x, y, z):  # pragma: no cover - compiled
    """Quaternion (scalar first) of the rotation vector (x, y, z) [rad]; series below 0.1 rad."""
    n2 = x * x + y * y + z * z
    if n2 < 1e-2:
        c = 1.0 - n2 * (1.0 / 8.0) + n2 * n2 * (1.0 / 384.0) - n2 * n2 * n2 * (1.0 / 46080.0)
        s = 0.5 - n2 * (1.0 / 48.0) + n2 * n2 * (1.0 / 3840.0) - n2 * n2 * n2 * (1.0 / 645120.0)
    else:
        n = math.sqrt(n2)
        c = math.cos(0.5 * n)
        s = math.sin(0.5 * n) / n
    return c, s * x, s * y, s * z


@njit(cache=True, fastmath=_FM, inline="always")
def _rot_coeffs(n2):  # pragma: no cover - compiled
    """(1 - cos a)/a^2 and (1 - sin a / a)/a^2 for a^2 = n2 (velocity rotation compensation)."""
    if n2 < 1e-2:
        c1 = 0.5 - n2 * (1.0 / 24.0) + n2 * n2 * (1.0 / 720.0) - n2 * n2 * n2 * (1.0 / 40320.0)
        c2 = 1.0 / 6.0 - n2 * (1.0 / 120.0) + n2 * n2 * (1.0 / 5040.0) - n2 * n2 * n2 * (1.0 / 362880.0)
    else:
        a = math.sqrt(n2)
        c1 = (1.0 - math.cos(a)) / n2
        c2 = (1.0 - math.sin(a) / a) / n2
    return c1, c2


@njit(cache=True, fastmath=_FM, inline="always")
def _nav_update(q0, q1, q2, q3, vE, vN, vU, lat, lon, h, href, sL, cL, lref,
                a0, a1, a2, w0, w1, w2, T, vmode, k1, k2):  # pragma: no cover - compiled
    """One navigation interval T [s] with increments Dtheta=(a0,a1,a2) [rad], Dv=(w0,w1,w2) [m/s].

    ``sL, cL`` = sin, cos of ``lat`` carried in the state (second-order Taylor update per step, exact
    re-evaluation whenever lat has moved more than 1e-6 rad from ``lref``, the latitude of the last
    exact evaluation; the Taylor branch thus sees steps |d| <= 2e-6 rad and its remainder d^3/6 is below
    2e-18 per step; it saves a sin and a cos per step).
    """
    # --- Earth quantities at the current position (WGS-84) ---
    s2 = sL * sL
    den = 1.0 - _E2 * s2
    rs = 1.0 / math.sqrt(den)
    RN = _A * rs
    RM = _A * (1.0 - _E2) * rs * rs * rs
    iRM = 1.0 / (RM + h)
    iRN = 1.0 / (RN + h)
    icL = 1.0 / cL
    wieN = _OMEGA * cL
    wieU = _OMEGA * sL
    wenE = -vN * iRM
    wenN = vE * iRN
    wenU = vE * iRN * sL * icL
    winE = wenE
    winN = wieN + wenN
    winU = wieU + wenU
    g = _GE * (1.0 + _KS * s2) * rs * (1.0 - 2.0 / _A * (1.0 + _F + _MR - 2.0 * _F * s2) * h + 3.0 / (_A * _A) * h * h)
    # --- C_b^n from q ---
    c00 = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    c01 = 2.0 * (q1 * q2 - q0 * q3)
    c02 = 2.0 * (q1 * q3 + q0 * q2)
    c10 = 2.0 * (q1 * q2 + q0 * q3)
    c11 = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    c12 = 2.0 * (q2 * q3 - q0 * q1)
    c20 = 2.0 * (q1 * q3 - q0 * q2)
    c21 = 2.0 * (q2 * q3 + q0 * q1)
    c22 = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    # --- velocity rotation compensation in b(k-1) ---
    n2 = a0 * a0 + a1 * a1 + a2 * a2
    r1, r2 = _rot_coeffs(n2)
    x0 = a1 * w2 - a2 * w1
    x1 = a2 * w0 - a0 * w2
    x2 = a0 * w1 - a1 * w0
    y0 = a1 * x2 - a2 * x1
    y1 = a2 * x0 - a0 * x2
    y2 = a0 * x1 - a1 * x0
    b0 = w0 + r1 * x0 + r2 * y0
    b1 = w1 + r1 * x1 + r2 * y1
    b2 = w2 + r1 * x2 + r2 * y2
    f0 = c00 * b0 + c01 * b1 + c02 * b2
    f1 = c10 * b0 + c11 * b1 + c12 * b2
    f2 = c20 * b0 + c21 * b1 + c22 * b2
    # (I - T/2 [w_in x]) f
    hT = 0.5 * T
    d0 = f0 - hT * (winN * f2 - winU * f1)
    d1 = f1 - hT * (winU * f0 - winE * f2)
    d2 = f2 - hT * (winE * f1 - winN * f0)
    # Coriolis + transport: (2 w_ie + w_en) x v
    oE = winE
    oN = wieN + winN
    oU = wieU + winU
    cor0 = oN * vU - oU * vN
    cor1 = oU * vE - oE * vU
    cor2 = oE * vN - oN * vE
    nE = vE + d0 - T * cor0
    nN = vN + d1 - T * cor1
    nU = vU + d2 + T * (-g - cor2)
    nh = h
    if vmode == 0:
        nU = 0.0
        nh = href
    elif vmode == 1:
        nh = h + hT * (vU + nU)
    else:
        dh = h - href
        nU = nU - T * k2 * dh
        nh = h + hT * (vU + nU) - T * k1 * dh
    nlat = lat + hT * (vN + nN) * iRM
    nlon = lon + hT * (vE + nE) * iRN * icL
    d = nlat - lat
    if abs(nlat - lref) > 1e-6:
        lref = nlat
        nsL = math.sin(nlat)
        ncL = math.cos(nlat)
    else:
        hd2 = 1.0 - 0.5 * d * d
        nsL = sL * hd2 + cL * d
        ncL = cL * hd2 - sL * d
    # --- attitude: q <- q(-w_in T) * q * q(Dtheta), w_in at mid-interval ---
    # The velocity update above sees the mid-interval attitude (through the -T/2 w_in x f term), so the
    # transport rate here uses the mean of the old and new velocity and the Earth rate the mean latitude:
    # the discrete Schuler loop then has a unit determinant. With the old (new) velocity alone the
    # Schuler amplitude grows (decays) by (w_s T)^2/4 per step, 3 % over 240 h at 10 Hz.
    e0, e1, e2, e3 = _rv_quat(a0, a1, a2)
    m0 = q0 * e0 - q1 * e1 - q2 * e2 - q3 * e3
    m1 = q0 * e1 + q1 * e0 + q2 * e3 - q3 * e2
    m2 = q0 * e2 - q1 * e3 + q2 * e0 + q3 * e1
    m3 = q0 * e3 + q1 * e2 - q2 * e1 + q3 * e0
    hd = 0.5 * (nlat - lat)
    mvE = 0.5 * (vE + nE)
    zE = -0.5 * (vN + nN) * iRM * T
    zN = (wieN - wieU * hd + mvE * iRN) * T
    zU = (wieU + wieN * hd + mvE * iRN * sL * icL) * T
    n0, n1, n2_, n3 = _rv_quat(-zE, -zN, -zU)
    p0 = n0 * m0 - n1 * m1 - n2_ * m2 - n3 * m3
    p1 = n0 * m1 + n1 * m0 + n2_ * m3 - n3 * m2
    p2 = n0 * m2 - n1 * m3 + n2_ * m0 + n3 * m1
    p3 = n0 * m3 + n1 * m2 - n2_ * m1 + n3 * m0
    # normalisation: |p|^2 = 1 + e with |e| ~ 1e-16, so 1/|p| = 1 - e/2 to O(e^2)
    inv = 1.5 - 0.5 * (p0 * p0 + p1 * p1 + p2 * p2 + p3 * p3)
    return p0 * inv, p1 * inv, p2 * inv, p3 * inv, nE, nN, nU, nlat, nlon, nh, nsL, ncL, lref


@njit(cache=True, fastmath=_FM, inline="always")
def _quat_euler(q0, q1, q2, q3):  # pragma: no cover - compiled
    """(pitch, roll, yaw) of C_b^n = Rz(yaw) Rx(pitch) Ry(roll)."""
    c01 = 2.0 * (q1 * q2 - q0 * q3)
    c11 = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    c20 = 2.0 * (q1 * q3 - q0 * q2)
    c21 = 2.0 * (q2 * q3 + q0 * q1)
    c22 = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    if c21 > 1.0:
        c21 = 1.0
    elif c21 < -1.0:
        c21 = -1.0
    return math.asin(c21), math.atan2(-c20, c22), math.atan2(-c01, c11)


@njit(cache=True, fastmath=_FM, inline="always")
def _record(out, j, q0, q1, q2, q3, vE, vN, vU, lat, lon, h):  # pragma: no cover - compiled
    """Output record j: [pitch, roll, yaw, vE, vN, vU, lat, lon, h]."""
    p, r, y = _quat_euler(q0, q1, q2, q3)
    out[j, 0] = p
    out[j, 1] = r
    out[j, 2] = y
    out[j, 3] = vE
    out[j, 4] = vN
    out[j, 5] = vU
    out[j, 6] = lat
    out[j, 7] = lon
    out[j, 8] = h


@njit(cache=True, fastmath=_FM, nogil=True)
def _run_stream(Dth, Dv, T, x, gb0, gb1, gb2, ab0, ab1, ab2, out_every, phase, out,
                vmode, k1, k2):  # pragma: no cover - compiled
    """Navigate one stream over all intervals; ``x`` (NX,) state updated in place; records to ``out``.

    ``phase`` = number of steps already done modulo ``out_every``; a record is written after every
    step whose running count is a multiple of ``out_every``.
    """
    q0, q1, q2, q3 = x[0], x[1], x[2], x[3]
    vE, vN, vU = x[4], x[5], x[6]
    lat, lon, h, href = x[7], x[8], x[9], x[10]
    sL, cL, lref = x[11], x[12], x[13]
    gT0 = gb0 * T
    gT1 = gb1 * T
    gT2 = gb2 * T
    aT0 = ab0 * T
    aT1 = ab1 * T
    aT2 = ab2 * T
    cnt = out_every - phase
    j = 0
    for i in range(Dth.shape[0]):
        q0, q1, q2, q3, vE, vN, vU, lat, lon, h, sL, cL, lref = _nav_update(
            q0, q1, q2, q3, vE, vN, vU, lat, lon, h, href, sL, cL, lref,
            Dth[i, 0] - gT0, Dth[i, 1] - gT1, Dth[i, 2] - gT2,
            Dv[i, 0] - aT0, Dv[i, 1] - aT1, Dv[i, 2] - aT2, T, vmode, k1, k2)
        cnt -= 1
        if cnt == 0:
            cnt = out_every
            _record(out, j, q0, q1, q2, q3, vE, vN, vU, lat, lon, h)
            j += 1
    x[0], x[1], x[2], x[3] = q0, q1, q2, q3
    x[4], x[5], x[6] = vE, vN, vU
    x[7], x[8], x[9] = lat, lon, h
    x[11], x[12], x[13] = sL, cL, lref


@njit(cache=True, fastmath=_FM, parallel=True, nogil=True)
def _run_multi_parallel(Dth, Dv, T, X, GB, AB, out_every, phase, out, vmode, k1, k2):  # pragma: no cover
    for s in prange(X.shape[0]):
        _run_stream(Dth, Dv, T, X[s], GB[s, 0], GB[s, 1], GB[s, 2], AB[s, 0], AB[s, 1], AB[s, 2],
                    out_every, phase, out[s], vmode, k1, k2)


@njit(cache=True, fastmath=_FM, nogil=True)
def _run_multi_serial(Dth, Dv, T, X, GB, AB, out_every, phase, out, vmode, k1, k2):  # pragma: no cover
    for s in range(X.shape[0]):
        _run_stream(Dth, Dv, T, X[s], GB[s, 0], GB[s, 1], GB[s, 2], AB[s, 0], AB[s, 1], AB[s, 2],
                    out_every, phase, out[s], vmode, k1, k2)


@njit(cache=True, fastmath=_FM, nogil=True)
def _run_fused(dth, dv, n_sub, pc, T, x, out_every, phase, out, vmode, k1, k2):  # pragma: no cover
    """Single stream, high-rate samples in: pre-integration and navigation in one pass.

    Operation for operation the same as :func:`_preint_kernel` followed by :func:`_run_stream`
    (bit-identical results) without the intermediate arrays. Returns the number of navigation steps.
    """
    p0, p1, p2, p3, p4, p5 = pc[0], pc[1], pc[2], pc[3], pc[4], pc[5]
    a0, a1, a2, v0, v1, v2 = pc[6], pc[7], pc[8], pc[9], pc[10], pc[11]
    b0, b1, b2, c0, c1, c2 = pc[12], pc[13], pc[14], pc[15], pc[16], pc[17]
    cnt = int(pc[18])
    q0, q1, q2, q3 = x[0], x[1], x[2], x[3]
    vE, vN, vU = x[4], x[5], x[6]
    lat, lon, h, href = x[7], x[8], x[9], x[10]
    sL, cL, lref = x[11], x[12], x[13]
    cnt_out = out_every - phase
    j = 0
    nsteps = 0
    for k in range(dth.shape[0]):
        (p0, p1, p2, p3, p4, p5, a0, a1, a2, v0, v1, v2, b0, b1, b2, c0, c1, c2) = _pre_accum(
            p0, p1, p2, p3, p4, p5, a0, a1, a2, v0, v1, v2, b0, b1, b2, c0, c1, c2,
            dth[k, 0], dth[k, 1], dth[k, 2], dv[k, 0], dv[k, 1], dv[k, 2])
        cnt += 1
        if cnt == n_sub:
            q0, q1, q2, q3, vE, vN, vU, lat, lon, h, sL, cL, lref = _nav_update(
                q0, q1, q2, q3, vE, vN, vU, lat, lon, h, href, sL, cL, lref,
                a0 + b0, a1 + b1, a2 + b2,
                v0 + c0, v1 + c1, v2 + c2, T, vmode, k1, k2)
            cnt = 0
            a0 = a1 = a2 = v0 = v1 = v2 = b0 = b1 = b2 = c0 = c1 = c2 = 0.0
            nsteps += 1
            cnt_out -= 1
            if cnt_out == 0:
                cnt_out = out_every
                _record(out, j, q0, q1, q2, q3, vE, vN, vU, lat, lon, h)
                j += 1
    pc[0], pc[1], pc[2], pc[3], pc[4], pc[5] = p0, p1, p2, p3, p4, p5
    pc[6], pc[7], pc[8], pc[9], pc[10], pc[11] = a0, a1, a2, v0, v1, v2
    pc[12], pc[13], pc[14], pc[15], pc[16], pc[17] = b0, b1, b2, c0, c1, c2
    pc[18] = cnt
    x[0], x[1], x[2], x[3] = q0, q1, q2, q3
    x[4], x[5], x[6] = vE, vN, vU
    x[7], x[8], x[9] = lat, lon, h
    x[11], x[12], x[13] = sL, cL, lref
    return nsteps


# ======================================================================================================
# Python API
# ======================================================================================================
@dataclass
class NavInit:
    """Initial navigation state: geodetic position [rad, m], attitude [rad] (ENU convention), velocity [m/s]."""

    lat: float
    lon: float = 0.0
    h: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    yaw: float = 0.0
    vE: float = 0.0
    vN: float = 0.0
    vU: float = 0.0
    C_bn: np.ndarray | None = None  # overrides pitch/roll/yaw when given

    def cbn(self) -> np.ndarray:
        return np.asarray(self.C_bn, float) if self.C_bn is not None else euler_to_dcm(self.pitch, self.roll, self.yaw)

    def state_vector(self) -> np.ndarray:
        x = np.empty(NX)
        x[0:4] = dcm_to_quat(self.cbn())
        x[4:7] = (self.vE, self.vN, self.vU)
        x[7:10] = (self.lat, self.lon, self.h)
        x[10] = self.h
        x[11:14] = (math.sin(self.lat), math.cos(self.lat), self.lat)
        return x


@dataclass
class NavState:
    """Navigation state of S streams carried across chunks.

    ``x`` (S, NX): [q0 q1 q2 q3 | vE vN vU | lat lon h | h_ref | sin lat, cos lat, lat_ref] per stream;
    ``steps`` navigation steps done
    (the output phase); ``dt_nav`` the interval the state was propagated with.
    """

    x: np.ndarray
    steps: int = 0
    dt_nav: float | None = None

    @classmethod
    def from_init(cls, init: NavInit, n_streams: int = 1) -> "NavState":
        return cls(np.tile(init.state_vector(), (n_streams, 1)), 0, None)

    @property
    def n_streams(self) -> int:
        return self.x.shape[0]

    def copy(self) -> "NavState":
        return NavState(self.x.copy(), self.steps, self.dt_nav)


def _vertical_gains(mode: str, period_s: float, lat: float, h: float):
    if mode not in VERTICAL_MODES:
        raise ValueError(f"vertical={mode!r}: expected one of {', '.join(VERTICAL_MODES)}")
    if mode != "damped":
        return VERTICAL_MODES[mode], 0.0, 0.0
    w0 = 2.0 * math.pi / float(period_s)
    ws2 = earth.schuler_frequency(lat, h) ** 2
    # characteristic polynomial s^2 + k1 s + (k2 - 2 ws^2): critically damped at w0
    return 2, 2.0 * w0, w0 * w0 + 2.0 * ws2


def _as_increments(a, name):
    a = np.ascontiguousarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name}: shape {a.shape}, expected (n, 3)")
    return a


def new_carry(first_dtheta=None, first_dv=None) -> np.ndarray:
    """Fresh pre-integration carry (NPC,). The 'previous sample' is set to the first sample when given
    (constant-rate assumption before the start), else zero."""
    pc = np.zeros(NPC)
    if first_dtheta is not None:
        pc[0:3] = first_dtheta
        pc[3:6] = first_dv
    return pc


def preintegrate(dtheta, dv, n_sub: int, carry=None):
    """Pre-integrate high-rate increments into navigation-rate increments (compiled kernel).

    dtheta [rad], dv [m/s]: (n, 3) body-frame increments per sample. Returns ``(Dtheta, Dv)`` (m, 3), one
    row per completed interval of ``n_sub`` samples: Dtheta includes the two-sample coning correction, Dv
    the sculling correction (the velocity rotation term is applied by the navigation update).

    Without ``carry``, ``n`` must be a multiple of ``n_sub``. With a ``carry`` array from
    :func:`new_carry` (updated in place) the call streams: an incomplete last interval stays open in the
    carry and is completed by the next call, and the previous-sample terms continue across chunks.
    """
    dtheta = _as_increments(dtheta, "dtheta")
    dv = _as_increments(dv, "dv")
    if dtheta.shape != dv.shape:
        raise ValueError(f"dtheta {dtheta.shape} and dv {dv.shape} differ in shape")
    n_sub = int(n_sub)
    if n_sub < 1:
        raise ValueError(f"n_sub={n_sub} must be >= 1")
    if carry is None:
        if dtheta.shape[0] % n_sub:
            raise ValueError(f"{dtheta.shape[0]} samples is not a multiple of n_sub={n_sub}; "
                             "pass a carry (new_carry()) to stream with a remainder")
        carry = new_carry(dtheta[0], dv[0]) if len(dtheta) else new_carry()
    elif carry.shape != (NPC,):
        raise ValueError(f"carry: shape {carry.shape}, expected ({NPC},)")
    m = (int(carry[18]) + dtheta.shape[0]) // n_sub
    Dth = np.empty((m, 3))
    Dv = np.empty((m, 3))
    done = _preint_kernel(dtheta, dv, n_sub, carry, Dth, Dv)
    assert done == m
    return Dth, Dv


def _prepare_state(init, n_streams, dt_nav):
    if isinstance(init, NavState):
        st = init
        if st.n_streams != n_streams:
            raise ValueError(f"state has {st.n_streams} streams, biases give {n_streams}")
        if st.dt_nav is not None and abs(st.dt_nav - dt_nav) > 1e-12 * dt_nav:
            raise ValueError(f"state was propagated with dt_nav={st.dt_nav}, called with {dt_nav}")
        st.dt_nav = dt_nav
        return st
    if isinstance(init, NavInit):
        st = NavState.from_init(init, n_streams)
        st.dt_nav = dt_nav
        return st
    raise TypeError(f"init must be NavInit or NavState, got {type(init).__name__}")


def navigate_multi(Dtheta, Dv, dt_nav: float, init, gyro_bias_rad_s, accel_bias=None, out_every: int = 1,
                   vertical: str = "hold", vertical_period_s: float = 300.0, parallel: bool = True):
    """Navigate S streams that share the same navigation-rate increments, in one compiled pass.

    Stream ``s`` uses ``Dtheta - gyro_bias_rad_s[s] * dt_nav`` and ``Dv - accel_bias[s] * dt_nav``
    (constant compensations: gyro [rad/s], accelerometer [m/s^2], body frame). The velocity rotation
    term is recomputed per stream (first order in the bias); the coning and sculling terms inside the
    pre-integrated increments are *not*: replacing every sample dtheta_l by dtheta_l - beta (beta = b dt)
    changes a coning product dtheta_i x dtheta_j by beta x (dtheta_i - dtheta_j), and the sculling terms
    by beta x (dv_i - dv_j) (for an accelerometer bias: a dt x (dtheta_i - dtheta_j)); the first-order
    parts cancel within each interval, leaving the bias times the *change* of the rate or specific force
    between samples -- a product of two small quantities, exactly zero on a stationary base or at constant
    rates. (Size: at most n_sub^2/2 |b dt| |d(dv)| per step; 9e-12 m/s per 0.1 s step for 0.035 deg/h on a
    table turning at 6 deg/s.) Recomputing them would force a high-rate pass per stream.

    ``init``: :class:`NavInit` (all streams start there) or :class:`NavState` (continue a previous chunk;
    the state is updated in place and returned). Returns ``(out, state)`` with ``out`` (S, n_out, 9) =
    [pitch, roll, yaw, vE, vN, vU, lat, lon, h] after every ``out_every``-th step (counted over all
    chunks). Streams are independent, so the ``prange`` over streams gives bit-identical results whatever
    the thread count.
    """
    Dtheta = _as_increments(Dtheta, "Dtheta")
    Dv = _as_increments(Dv, "Dv")
    if Dtheta.shape != Dv.shape:
        raise ValueError(f"Dtheta {Dtheta.shape} and Dv {Dv.shape} differ in shape")
    GB = np.ascontiguousarray(np.atleast_2d(np.asarray(gyro_bias_rad_s, dtype=np.float64)))
    if GB.ndim != 2 or GB.shape[1] != 3:
        raise ValueError(f"gyro_bias_rad_s: shape {GB.shape}, expected (S, 3)")
    S = GB.shape[0]
    if accel_bias is None:
        AB = np.zeros((S, 3))
    else:
        AB = np.ascontiguousarray(np.atleast_2d(np.asarray(accel_bias, dtype=np.float64)))
        if AB.shape != (S, 3):
            raise ValueError(f"accel_bias: shape {AB.shape}, expected ({S}, 3)")
    out_every = int(out_every)
    if out_every < 1:
        raise ValueError("out_every must be >= 1")
    dt_nav = float(dt_nav)
    st = _prepare_state(init, S, dt_nav)
    lat0, h0 = float(st.x[0, ILAT]), float(st.x[0, IHREF])
    vm, k1, k2 = _vertical_gains(vertical, vertical_period_s, lat0, h0)
    n = Dtheta.shape[0]
    phase = st.steps % out_every
    n_out = (phase + n) // out_every
    out = np.empty((S, n_out, NOUT))
    if parallel and S > 1:
        _run_multi_parallel(Dtheta, Dv, dt_nav, st.x, GB, AB, out_every, phase, out, vm, k1, k2)
    else:
        _run_multi_serial(Dtheta, Dv, dt_nav, st.x, GB, AB, out_every, phase, out, vm, k1, k2)
    st.steps += n
    return out, st


def navigate(Dtheta, Dv, dt_nav: float, init, out_every: int = 1, vertical: str = "hold",
             vertical_period_s: float = 300.0):
    """Single-stream navigation of navigation-rate increments (see :func:`navigate_multi`).

    Returns ``(out (n_out, 9), state)``.
    """
    out, st = navigate_multi(Dtheta, Dv, dt_nav, init, np.zeros((1, 3)), None, out_every, vertical,
                             vertical_period_s, parallel=False)
    return out[0], st


def navigate_highrate(dtheta, dv, dt: float, n_sub: int, init, carry=None, out_every: int = 1,
                      vertical: str = "hold", vertical_period_s: float = 300.0):
    """Single stream from high-rate increments: fused pre-integration + navigation (compiled, one pass).

    ``n_sub`` samples per navigation step (``n_sub = 1``: single-speed path at the sample rate), navigation
    interval ``dt * n_sub``. ``init`` a :class:`NavInit` or a :class:`NavState` to continue; ``carry`` the
    pre-integration carry (:func:`new_carry`) for streaming, created from the first sample when None.
    ``out_every`` counts navigation steps. Returns ``(out (n_out, 9), state, carry)``.
    """
    dtheta = _as_increments(dtheta, "dtheta")
    dv = _as_increments(dv, "dv")
    if dtheta.shape != dv.shape:
        raise ValueError(f"dtheta {dtheta.shape} and dv {dv.shape} differ in shape")
    n_sub = int(n_sub)
    if n_sub < 1:
        raise ValueError(f"n_sub={n_sub} must be >= 1")
    out_every = int(out_every)
    if out_every < 1:
        raise ValueError("out_every must be >= 1")
    if carry is None:
        carry = new_carry(dtheta[0], dv[0]) if len(dtheta) else new_carry()
    T = float(dt) * n_sub
    st = _prepare_state(init, 1, T)
    vm, k1, k2 = _vertical_gains(vertical, vertical_period_s, float(st.x[0, ILAT]), float(st.x[0, IHREF]))
    n_steps = (int(carry[18]) + dtheta.shape[0]) // n_sub
    phase = st.steps % out_every
    out = np.empty(((phase + n_steps) // out_every, NOUT))
    done = _run_fused(dtheta, dv, n_sub, carry, T, st.x[0], out_every, phase, out, vm, k1, k2)
    assert done == n_steps
    st.steps += n_steps
    return out, st, carry
