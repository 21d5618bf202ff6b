"""Plain numpy twin of the compiled strapdown engine (:mod:`calib.nav.strapdown`), slow, for the tests.

The same algorithm (two-sample coning and sculling, He 2019 eqs. 1-3 with the velocity rotation term and the
mid-interval navigation-frame rate) written independently with vector cross products, Rodrigues DCMs of
:mod:`calib.core.rotations` and the Earth model of :mod:`calib.core.earth`: the compiled kernels are checked
against it sample for sample.
"""
from __future__ import annotations

import math

import numpy as np

from calib.core import earth
from calib.core.rotations import dcm_to_euler, dcm_to_quat, quat_to_dcm, rotvec_to_dcm, skew
from calib.nav.strapdown import NOUT, NavInit


def preintegrate_reference(dtheta, dv, n_sub: int, prev=None):
    """Plain numpy twin of :func:`calib.nav.strapdown.preintegrate` (vector cross products, no compilation).

    ``prev`` (6,): the sample before the first one (default: the first sample itself).
    """
    dtheta = np.asarray(dtheta, float)
    dv = np.asarray(dv, float)
    m = len(dtheta) // n_sub
    pt = dtheta[0].copy() if prev is None else np.asarray(prev[:3], float).copy()
    pv = dv[0].copy() if prev is None else np.asarray(prev[3:], float).copy()
    Dth = np.zeros((m, 3))
    Dv = np.zeros((m, 3))
    for j in range(m):
        alpha = np.zeros(3)
        vel = np.zeros(3)
        beta = np.zeros(3)
        scul = np.zeros(3)
        for lidx in range(j * n_sub, (j + 1) * n_sub):
            t, u = dtheta[lidx], dv[lidx]
            xa = alpha + pt / 6.0
            xv = vel + pv / 6.0
            beta = beta + 0.5 * np.cross(xa, t)
            scul = scul + 0.5 * (np.cross(xa, u) + np.cross(xv, t))
            alpha = alpha + t
            vel = vel + u
            pt, pv = t, u
        Dth[j] = alpha + beta
        Dv[j] = vel + scul
    return Dth, Dv


def navigate_reference(Dtheta, Dv, dt_nav: float, init: NavInit, out_every: int = 1):
    """Plain numpy navigation (vertical channel held) with DCM attitude; returns out (n_out, 9).

    Same equations as the compiled kernel but written with :mod:`calib.core.earth` and
    :mod:`calib.core.rotations` (Rodrigues DCMs, matrix products), for sample-by-sample verification.
    """
    T = float(dt_nav)
    C = init.cbn().copy()
    v = np.array([init.vE, init.vN, 0.0])
    lat, lon, h = float(init.lat), float(init.lon), float(init.h)
    out = []
    for k in range(len(Dtheta)):
        a = np.asarray(Dtheta[k], float)
        w = np.asarray(Dv[k], float)
        r_m, r_n = earth.radii(lat)
        w_ie = earth.earth_rate_enu(lat)
        w_en = np.array([-v[1] / (r_m + h), v[0] / (r_n + h), v[0] * math.tan(lat) / (r_n + h)])
        w_in = w_ie + w_en
        g_n = earth.gravity_enu(lat, h)
        an = np.linalg.norm(a)
        if an > 0:
            c1 = (1.0 - math.cos(an)) / an**2
            c2 = (1.0 - math.sin(an) / an) / an**2
        else:
            c1, c2 = 0.5, 1.0 / 6.0
        ka = skew(a)
        dv_b = w + c1 * (ka @ w) + c2 * (ka @ (ka @ w))
        dv_n = (np.eye(3) - 0.5 * T * skew(w_in)) @ (C @ dv_b)
        v_new = v + dv_n + T * (g_n - np.cross(2.0 * w_ie + w_en, v))
        v_new[2] = 0.0
        lat_new = lat + T * 0.5 * (v[1] + v_new[1]) / (r_m + h)
        lon_new = lon + T * 0.5 * (v[0] + v_new[0]) / ((r_n + h) * math.cos(lat))
        vm = 0.5 * (v + v_new)
        w_en_mid = np.array([-vm[1] / (r_m + h), vm[0] / (r_n + h), vm[0] * math.tan(lat) / (r_n + h)])
        w_ie_mid = w_ie + np.array([0.0, -w_ie[2], w_ie[1]]) * 0.5 * (lat_new - lat)  # first order in dlat
        C = rotvec_to_dcm(-(w_ie_mid + w_en_mid) * T) @ C @ rotvec_to_dcm(a)
        # re-orthonormalise through the quaternion (as the kernel normalises its quaternion)
        C = quat_to_dcm(dcm_to_quat(C))
        v, lat, lon = v_new, lat_new, lon_new
        if (k + 1) % out_every == 0:
            p, r, y = dcm_to_euler(C)
            out.append([p, r, y, v[0], v[1], v[2], lat, lon, h])
    return np.array(out).reshape(-1, NOUT)
