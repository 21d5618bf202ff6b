"""Gyroscope by gravity directions: between two rests the calibrated gyro must carry the first rest's gravity
direction into the second's (quaternion RK4 integration); the static g-sensitivity regression; the direction check."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numba
import numpy as np
from scipy.optimize import least_squares

from calib.signal import detect
from calib.fieldcal.accelerometer import misalignment_matrix
from calib.calibration.identifiability import rank_summary
from calib.fieldcal.results import (
    BIAS_NAMES,
    GYRO_NAMES,
    PLAUSIBLE_GYRO_BIAS_RAD_S,
    PLAUSIBLE_MISALIGNMENT_RAD,
    PLAUSIBLE_SCALE_REL,
    Determination,
    FieldCalError,
    FieldCalResult,
    TriadFit,
    input_label,
    log,
    scale_factor_units,
)

# =========================================================================== gyroscope: gravity directions


@numba.njit(cache=True, inline="always")
def _qdot(q0, q1, q2, q3, wx, wy, wz):
    """0.5 q (x) (0, w): body-rate kinematics of q = C_b(t)^b(0), scalar first."""
    return (-0.5 * (q1 * wx + q2 * wy + q3 * wz),
            0.5 * (q0 * wx + q2 * wz - q3 * wy),
            0.5 * (q0 * wy - q1 * wz + q3 * wx),
            0.5 * (q0 * wz + q1 * wy - q2 * wx))


@numba.njit(cache=True, inline="always")
def rk4_step(q0, q1, q2, q3, ax, ay, az, bx, by, bz, h):
    """One classical RK4 step of :func:`_qdot` over ``h`` [s], the rate ``a`` at the start and ``b`` at the end
    (linear between: their mean in the middle); the quaternion renormalised. Shared by the integrators of body
    rates (one order of operations, so that their numbers agree to the bit)."""
    mx, my, mz = 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz)
    k10, k11, k12, k13 = _qdot(q0, q1, q2, q3, ax, ay, az)
    k20, k21, k22, k23 = _qdot(q0 + 0.5 * h * k10, q1 + 0.5 * h * k11, q2 + 0.5 * h * k12,
                               q3 + 0.5 * h * k13, mx, my, mz)
    k30, k31, k32, k33 = _qdot(q0 + 0.5 * h * k20, q1 + 0.5 * h * k21, q2 + 0.5 * h * k22,
                               q3 + 0.5 * h * k23, mx, my, mz)
    k40, k41, k42, k43 = _qdot(q0 + h * k30, q1 + h * k31, q2 + h * k32, q3 + h * k33, bx, by, bz)
    c = h / 6.0
    q0 = q0 + c * (k10 + 2.0 * k20 + 2.0 * k30 + k40)
    q1 = q1 + c * (k11 + 2.0 * k21 + 2.0 * k31 + k41)
    q2 = q2 + c * (k12 + 2.0 * k22 + 2.0 * k32 + k42)
    q3 = q3 + c * (k13 + 2.0 * k23 + 2.0 * k33 + k43)
    nq = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    return q0 / nq, q1 / nq, q2 / nq, q3 / nq


@numba.njit(cache=True)
def integrate_quaternions(w, dt, starts, stops):
    """Integrate body rates ``w`` (n, 3) [rad s-1] over index ranges: for each m, steps ``j = starts[m] ..
    stops[m] - 1`` from sample j to j+1 of length ``dt[j]`` [s]; classical RK4 with the rate linear between
    samples; quaternion renormalised each step. Returns (m, 4) scalar-first quaternions ``C_b(end)^b(start)``.
    """
    m = starts.shape[0]
    out = np.empty((m, 4))
    for i in range(m):
        q0, q1, q2, q3 = 1.0, 0.0, 0.0, 0.0
        for j in range(starts[i], stops[i]):
            h = dt[j]
            ax, ay, az = w[j, 0], w[j, 1], w[j, 2]
            bx, by, bz = w[j + 1, 0], w[j + 1, 1], w[j + 1, 2]
            q0, q1, q2, q3 = rk4_step(q0, q1, q2, q3, ax, ay, az, bx, by, bz, h)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = q0, q1, q2, q3
    return out


def quats_to_dcm(q) -> np.ndarray:
    """(m, 4) scalar-first unit quaternions to (m, 3, 3) DCMs (same rotation as :func:`transforms.quat_to_dcm`)."""
    q = np.asarray(q, dtype=float)
    q0, q1, q2, q3 = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    R[:, 0, 1] = 2 * (q1 * q2 - q0 * q3)
    R[:, 0, 2] = 2 * (q1 * q3 + q0 * q2)
    R[:, 1, 0] = 2 * (q1 * q2 + q0 * q3)
    R[:, 1, 1] = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    R[:, 1, 2] = 2 * (q2 * q3 - q0 * q1)
    R[:, 2, 0] = 2 * (q1 * q3 - q0 * q2)
    R[:, 2, 1] = 2 * (q2 * q3 + q0 * q1)
    R[:, 2, 2] = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    return R


class _GyroProblem:
    """Pre-cut data of the gravity-direction fit: motion samples between consecutive statics."""

    def __init__(self, gyro, accel_cal, intervals, dt, bias0, g_sensitivity=None):
        iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
        u = np.array([accel_cal[a:b].mean(axis=0) for a, b in iv])
        self.u = u / np.linalg.norm(u, axis=1)[:, None]
        # gap between interval i and i+1: from its last static sample to the next one's first
        spans = [(iv[i, 1] - 1, iv[i + 1, 0]) for i in range(len(iv) - 1)]
        idx = np.concatenate([np.arange(a, b + 1) for a, b in spans])
        lens = np.array([b - a + 1 for a, b in spans])
        self.starts = np.concatenate([[0], np.cumsum(lens)[:-1]]).astype(np.int64)
        self.stops = (self.starts + lens - 1).astype(np.int64)
        self.raw = np.ascontiguousarray(gyro[idx], dtype=np.float64)
        self.dt = np.ascontiguousarray(dt[idx], dtype=np.float64)
        self.bias0 = np.asarray(bias0, dtype=float)
        # offsets removed before calibration: the bias, plus G a for a g-sensitive gyro (a: calibrated accel)
        self.offset = np.broadcast_to(self.bias0, self.raw.shape).copy()
        if g_sensitivity is not None:
            self.offset += accel_cal[idx] @ np.asarray(g_sensitivity, dtype=float).T
        self.n_pairs = len(spans)
        self.spans = spans

    def rotations(self, matrix, dbias):
        """Rotation over each gap for calibration ``matrix`` and a bias correction ``dbias`` [input units]."""
        w = np.ascontiguousarray((self.raw - self.offset - dbias) @ matrix.T)
        return quats_to_dcm(integrate_quaternions(w, self.dt, self.starts, self.stops))

    def residual_vectors(self, matrix, dbias=0.0):
        R = self.rotations(matrix, dbias)
        carried = np.einsum("mji,mj->mi", R, self.u[:-1])  # R^T u0
        return carried - self.u[1:]


def direction_angles_deg(res_vectors) -> np.ndarray:
    """Angle [deg] between two unit vectors whose difference is ``res_vectors`` (m, 3)."""
    c = np.clip(np.linalg.norm(res_vectors, axis=1) / 2.0, 0.0, 1.0)
    return np.degrees(2.0 * np.arcsin(c))


def gyro_static_regression(gyro, accel_calibrated, intervals, rank_rtol: float = 1e-6):
    """Orientation-dependent gyro offset from the static intervals: ``mean gyro = b + G a`` (least squares).

    ``gyro``: (n, 3) input units; ``accel_calibrated``: (n, 3) [m s-2]; one equation triple per interval
    (means). Returns a dict: ``bias`` (3,) [input units], ``G`` (3, 3) [input units per m s-2] (the gyro's
    g-sensitivity, imucal's ``K_ga``), ``covariance`` (12, 12) of ``(bias, G row-major)``, ``rms`` of the
    interval-mean residuals [input units] and the rank of the design ``[1, a]`` (4 needed).
    """
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    gm = np.array([gyro[a:b].mean(axis=0) for a, b in iv])
    am = np.array([accel_calibrated[a:b].mean(axis=0) for a, b in iv])
    X = np.column_stack([np.ones(len(am)), am])
    ident = rank_summary(X, ("1", "a_x", "a_y", "a_z"), rank_rtol, based_on="static means design [1, a]")
    coef, *_ = np.linalg.lstsq(X, gm, rcond=None)  # (4, 3): column j = [b_j, G_j,:]
    res = gm - X @ coef
    dof = max(len(gm) - 4, 1)
    s2 = (res * res).sum(axis=0) / dof
    XtXi = np.linalg.pinv(X.T @ X)
    cov = np.zeros((12, 12))
    for j in range(3):  # bias_j -> index j; G[j, :] -> 3 + 3 j ..
        ids = [j, 3 + 3 * j, 4 + 3 * j, 5 + 3 * j]
        cov[np.ix_(ids, ids)] = s2[j] * XtXi
    return {"bias": coef[0].copy(), "G": coef[1:].T.copy(), "covariance": cov,
            "rms": np.sqrt((res * res).mean(axis=0)), "rank": ident.rank, "identifiability": ident,
            "spread": gm.std(axis=0, ddof=1) if len(gm) > 1 else np.zeros(3)}


GSENS_NAMES = tuple(f"gsens_{r}{c}" for r in "xyz" for c in "xyz")


def fit_gyro_directions(gyro, accel_calibrated, intervals, dt, *, bias, g_sensitivity=None,
                        offset_covariance=None, estimate_bias: bool = False, scale_guess: float | None = None,
                        input_units: str = "count", input_factor: float = 1.0, input_kind: str = "rate",
                        sample_dt: float = 1.0, rank_rtol: float = 1e-6, path=None,
                        hold_undetermined: bool = True) -> TriadFit:
    """Gyro calibration from gravity directions across the motions between consecutive static intervals.

    ``gyro``: (n, 3) in the calibration's input units (counts, or rad s-1). ``accel_calibrated``: (n, 3)
    [m s-2] in the body frame. ``intervals``: (m, 2) ``[start, stop)``. ``dt``: (n,) step from each sample to
    the next [s]. ``bias``: gyro bias [input units] (e.g. the initial-rest mean). ``g_sensitivity``: optional
    (3, 3) ``G`` [input units per m s-2]: the offset removed is then ``bias + G a`` (see
    :func:`gyro_static_regression`); ``offset_covariance`` (12, 12) its covariance, stored with the result.
    ``estimate_bias``: refine the bias (3 more parameters). ``scale_guess``: input units per rad s-1 to start
    from; None: 1 for physical units, for counts the best of a logarithmic scan over 1e0..1e7.
    Minimises IMU-TK's residual ``R^T u0 - u1`` with Levenberg-Marquardt (parameters internally relative:
    gain = g0 (1 + d), bias correction = beta / g0 with beta in rad s-1).

    What the motions determine is stored as ``determination`` (marginal standard errors of the internal
    parameters from the Jacobian at the solution; plausibility scales: misalignment 1 deg, gain 1 %, bias
    10 deg/s); with ``hold_undetermined`` the parameters ``not determined`` are held at nominal (misalignment
    0, gain g0 = 1 / ``scale_guess``, bias correction 0) and the others refitted (covariance rows NaN).
    """
    gyro = np.asarray(gyro, dtype=np.float64)
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    if len(iv) < 4:
        raise FieldCalError(f"{path or 'input'}: {len(iv)} static intervals give {max(len(iv) - 1, 0)} motions; the "
                            "gyro fit (9 parameters, 3 residuals per motion) needs at least 4 intervals -- fix: "
                            "record more positions or lower the detection threshold")
    prob = _GyroProblem(gyro, accel_calibrated, iv, np.asarray(dt, dtype=float), bias, g_sensitivity)
    notes = []
    if scale_guess is None:
        if input_units == "count":
            grid = np.logspace(0, 7, 141)
            costs = []
            for s in grid:
                rv = prob.residual_vectors(np.eye(3) / s)
                costs.append(float(np.sum(rv * rv)))
            scale_guess = float(grid[int(np.argmin(costs))])
            notes.append(f"initial scale {scale_guess:.4g} counts per rad s-1 from a logarithmic scan")
        else:
            scale_guess = 1.0
    g0 = 1.0 / scale_guess
    nb = 3 if estimate_bias else 0

    def unpack(q):
        gains = g0 * (1.0 + q[6:9])
        db = q[9:12] / g0 if nb else np.zeros(3)
        return misalignment_matrix(q[:6]) * gains[None, :], gains, db

    def fun(q):
        M, _, db = unpack(q)
        return prob.residual_vectors(M, db).ravel()

    q0 = np.zeros(9 + nb)
    before = direction_angles_deg(fun(q0).reshape(-1, 3))
    sol = least_squares(fun, q0, method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    q = sol.x
    fit_names = GYRO_NAMES + (BIAS_NAMES if nb else ())
    jac_first = sol.jac
    m0 = sol.jac.shape[0]
    det = Determination.from_jacobian(
        sol.jac, np.sqrt(float(sol.fun @ sol.fun) / max(m0 - len(q), 1)), fit_names,
        np.concatenate([np.full(6, PLAUSIBLE_MISALIGNMENT_RAD), np.full(3, PLAUSIBLE_SCALE_REL),
                        np.full(nb, PLAUSIBLE_GYRO_BIAS_RAD_S)]),
        based_on=f"gravity-direction residuals ({prob.n_pairs} motions); gains relative, bias in rad s-1")
    free = np.ones(len(q), dtype=bool)
    if hold_undetermined and det.not_determined:
        free = np.array([v != "not determined" for v in det.verdicts])
        if free.any():
            def fun_free(qf):
                qq = np.zeros(len(q))
                qq[free] = qf
                return fun(qq)

            sol = least_squares(fun_free, np.zeros(int(free.sum())), method="lm", xtol=1e-12, ftol=1e-12,
                                gtol=1e-12)
            q = np.zeros(len(q))
            q[free] = sol.x
            jac = np.zeros((sol.jac.shape[0], len(q)))
            jac[:, free] = sol.jac
        else:
            q = np.zeros(len(q))
            res0 = fun(q)
            sol = SimpleNamespace(fun=res0, jac=np.zeros((len(res0), len(q))), nfev=1)
            jac = sol.jac
        det.held = tuple(n for n, f in zip(fit_names, free) if not f)
        det.nominal = {n: (g0 if n.startswith("gain") else 0.0) for n, f in zip(fit_names, free) if not f}
    M, gains, db = unpack(q)
    b = prob.bias0 + db
    rv = sol.fun.reshape(-1, 3)
    ang = direction_angles_deg(rv)
    J = sol.jac if free.all() else jac
    m, k = J.shape
    dof = max(m - int(free.sum()), 1)
    sigma2 = float(sol.fun @ sol.fun) / dof
    if free.all():
        cov_int = sigma2 * np.linalg.pinv(J.T @ J)
    else:
        cov_int = np.full((k, k), np.nan)
        cov_int[np.ix_(free, free)] = sigma2 * np.linalg.pinv(J[:, free].T @ J[:, free])
    # external parameters: mis (same), gains = g0 (1 + d), bias correction = beta / g0
    a_ext = np.concatenate([np.ones(6), np.full(3, g0), np.full(nb, 1.0 / g0)])
    cov_fit = a_ext[:, None] * cov_int * a_ext[None, :]
    ident = rank_summary(jac_first, fit_names, rank_rtol,
                         based_on=f"gravity-direction residuals ({prob.n_pairs} motions)")
    if ident.rank < len(fit_names):
        notes.append(f"gyro model not fully identified: {ident.describe()}")
    if det.not_determined or det.weak:
        notes.append(det.describe("gyro"))
        log.warning("%s: %s", path or "input", det.describe("gyro"))
    # parameter vector: the direction fit, then the offsets (bias always; G when g-sensitive)
    names = GYRO_NAMES + BIAS_NAMES + (GSENS_NAMES if g_sensitivity is not None else ())
    values = np.concatenate([q[:6], gains, b] + ([np.asarray(g_sensitivity, float).ravel()]
                                                if g_sensitivity is not None else []))
    p = len(names)
    cov = np.zeros((p, p))
    cov[:9, :9] = cov_fit[:9, :9]
    cov[9:, :] = np.nan  # offsets taken as known in the direction fit: their uncertainty only if given
    cov[:, 9:] = np.nan
    if offset_covariance is not None:
        cov[9:, 9:] = 0.0
        oc = np.asarray(offset_covariance, dtype=float)
        k_off = oc.shape[0]
        cov[9:9 + k_off, 9:9 + k_off] = oc[:p - 9, :p - 9] if k_off >= p - 9 else oc
    if nb:
        cov[9:12, 9:12] = np.nan_to_num(cov[9:12, 9:12]) + cov_fit[9:12, 9:12]
        cov[:9, 9:12] = cov_fit[:9, 9:12]
        cov[9:12, :9] = cov_fit[9:12, :9]
    in_u = input_label("gyro", input_units, input_kind)
    sf = 1.0 / gains
    sf_std = np.sqrt(np.diag(cov)[6:9]) / gains ** 2
    return TriadFit(
        sensor="gyro", method="gravity_direction", names=names, values=values, covariance=cov,
        param_units=("rad",) * 6 + (f"rad s-1 per {in_u}",) * 3 + (in_u,) * 3 +
        ((f"{in_u} per m s-2",) * 9 if g_sensitivity is not None else ()),
        matrix=M, bias=np.asarray(b, dtype=float), input_units=input_units, input_factor=float(input_factor),
        input_kind=input_kind, dt=float(sample_dt), output_units="rad s-1", scale_factors=sf,
        scale_factor_std=sf_std, scale_factor_units=scale_factor_units("gyro", input_units, in_u),
        residual_rms=float(np.sqrt(np.mean(ang ** 2))), residual_units="deg", n_residuals=int(m),
        identifiability=ident, notes=notes, determination=det,
        g_sensitivity=None if g_sensitivity is None else np.asarray(g_sensitivity, dtype=float),
        extra={"pair_angles_deg": ang, "rms_before_deg": float(np.sqrt(np.mean(before ** 2))),
               "n_motions": prob.n_pairs, "nfev": int(sol.nfev), "scale_guess": scale_guess,
               "bias_estimated": bool(nb)})


def direction_check(result: "FieldCalResult", accel_raw, gyro_raw, fs: float, intervals=None, **detect_kwargs):
    """Validate a calibration by gravity directions: calibrate, find static intervals on the calibrated signals
    (or use ``intervals``), integrate the calibrated gyro over each gap and compare the carried gravity
    direction with the next one. Returns ``(angles_deg per gap, intervals)``. Only meaningful for a recording
    that is continuous between its static intervals (not for sessions pasted together from pieces).
    """
    a, w = result.apply(accel_raw, gyro_raw)
    if intervals is None:
        intervals = detect.detect_static(a, w, fs, **detect_kwargs).intervals
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    if len(iv) < 2:
        raise FieldCalError("direction_check: fewer than two static intervals")
    prob = _GyroProblem(w, a, iv, np.full(len(w), 1.0 / fs), np.zeros(3))
    return direction_angles_deg(prob.residual_vectors(np.eye(3))), iv
