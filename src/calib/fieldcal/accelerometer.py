"""Accelerometer by the gravity norm: ``a = T_a K_a (N - b_a)``, 9 parameters (IMU-TK's model, written anew),
its algebraic start and the Levenberg-Marquardt fit with standard errors and identifiability."""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from calib.core.triad import MIN_POSES_TO_TEST, NORM_PARAMETERS
from calib.calibration.ellipsoid import fit_ellipsoid
from calib.signal import detect
from calib.calibration.identifiability import rank_summary
from calib.fieldcal.results import (
    ACCEL_NAMES,
    MIN_INTERVALS,
    PLAUSIBLE_ACCEL_BIAS_G,
    PLAUSIBLE_MISALIGNMENT_RAD,
    PLAUSIBLE_SCALE_REL,
    RECOMMENDED_INTERVALS,
    Determination,
    FieldCalError,
    TriadFit,
    input_label,
    log,
    scale_factor_units,
)

# =========================================================================== models


def misalignment_matrix(p6) -> np.ndarray:
    """IMU-TK's misalignment matrix from ``(mis_yz, mis_zy, mis_zx, mis_xz, mis_xy, mis_yx)``:
    ``[[1, -yz, zy], [xz, 1, -zx], [-xy, yx, 1]]`` (columns: sensor axes in the body frame, small angles)."""
    yz, zy, zx, xz, xy, yx = p6
    return np.array([[1.0, -yz, zy], [xz, 1.0, -zx], [-xy, yx, 1.0]])


def accel_matrix(p) -> np.ndarray:
    """``T_a K_a`` of the 9-parameter norm model (order :data:`ACCEL_NAMES`)."""
    return misalignment_matrix([p[0], p[1], p[2], 0.0, 0.0, 0.0]) * np.asarray(p[3:6])[None, :]


def accel_apply(p, N):
    return (N - p[6:9]) @ accel_matrix(p).T


def accel_residual(p, N, g):
    return np.linalg.norm(accel_apply(p, N), axis=1) - g


def accel_jacobian(p, N, g):
    """d(|a| - g)/dp for the 9-parameter model; rows = samples, columns = :data:`ACCEL_NAMES`."""
    d = N - p[6:9]
    u = d * p[3:6]
    T = misalignment_matrix([p[0], p[1], p[2], 0.0, 0.0, 0.0])
    x = u @ T.T
    n = x / np.linalg.norm(x, axis=1)[:, None]
    nT = n @ T  # (n^T T)_i
    J = np.empty((len(N), 9))
    J[:, 0] = -n[:, 0] * u[:, 1]
    J[:, 1] = n[:, 0] * u[:, 2]
    J[:, 2] = -n[:, 1] * u[:, 2]
    J[:, 3:6] = nT * d
    J[:, 6:9] = -nT * p[3:6]
    return J


def ellipsoid_guess(means, g: float):
    """Initial 9 parameters from an algebraic ellipsoid fit to static means (>= 9, spread over orientations).

    :func:`calib.calibration.ellipsoid.fit_ellipsoid`, then the centre as the bias and the upper-triangular
    Cholesky factor of the normalised ``Q`` as ``T_a K_a``. Returns None when
    the quadric is not an ellipsoid (then use :func:`range_guess`).
    """
    fit = fit_ellipsoid(means)
    if fit is None:
        return None
    Qn, s0 = fit.Qn, fit.s0
    L = np.linalg.cholesky(Qn)  # Qn = L L^T, L lower -> R = L^T upper with R^T R = Qn
    R = L.T * (g / s0)
    k = np.diag(R).copy()
    T = R / k[None, :]
    return np.array([-T[0, 1], T[0, 2], -T[1, 2], k[0], k[1], k[2], *fit.bias])


def range_guess(samples, g: float):
    """Crude initial parameters: bias = midpoint of the extremes, gain = 2 g / range, no misalignment."""
    s = np.asarray(samples, dtype=float)
    lo, hi = s.min(axis=0), s.max(axis=0)
    rng = np.where(hi - lo > 0, hi - lo, 1.0)
    return np.array([0.0, 0.0, 0.0, *(2.0 * g / rng), *((lo + hi) / 2.0)])


# =========================================================================== accelerometer: gravity norm


def _select_samples(x, intervals, n_per):
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    if n_per is None:
        return np.concatenate([x[a:b] for a, b in iv]), np.concatenate(
            [np.full(b - a, i) for i, (a, b) in enumerate(iv)])
    short = [(a, b) for a, b in iv if b - a < n_per]
    if short:
        raise FieldCalError(f"samples_per_interval={n_per} but interval(s) {short[:3]} are shorter -- fix: drop "
                            "short intervals (min_interval_s) or lower samples_per_interval")
    return np.concatenate([x[a:a + n_per] for a, b in iv]), np.repeat(np.arange(len(iv)), n_per)


def _require_intervals(n_found, needed, recommended, detection, path, what="static intervals"):
    """Raise the too-few error (with a threshold suggestion from ``detection``) or return a note."""
    if n_found < needed:
        if detection is not None:
            raise detect.too_few_static_error(needed, n_found, detection.threshold, rule=detection.rule,
                                              suggestion=detection.suggest_threshold(needed), path=path,
                                              min_interval_s=detection.min_samples / detection.fs, k=detection.k)
        raise FieldCalError(f"{path or 'input'}: {n_found} {what} given, the 9-parameter norm model needs at "
                            f"least {needed} (recommended {recommended}) -- fix: record more static positions "
                            "or lower the detection threshold (detect.StaticDetection.suggest_threshold)")
    if n_found < recommended:
        msg = f"only {n_found} {what} (>= {needed} needed, >= {recommended} recommended)"
        if detection is not None:
            sug = detection.suggest_threshold(recommended)
            if sug is not None:
                msg += f"; threshold={sug:.4g} in detect_static would give {recommended}"
        return msg
    return None


#: nominal parameters of the norm model in physical units: no misalignment, unit gains, no bias
NOMINAL = (0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0)


def _put(p, held, q):
    """``p`` with its free entries (not ``held``) replaced by ``q``."""
    out = np.array(p, dtype=float)
    out[~held] = q
    return out


def accel_determination(p, means, n_samples, sigma, gravity, names=ACCEL_NAMES, misfit=True) -> Determination:
    """What the static poses determine of the 9 norm-model parameters at ``p``: marginal standard errors from the
    Jacobian of the interval *means* (so that sample noise lends no rank to orientations never visited), with
    the scatter of the interval means, floored at the sample scatter over the mean interval length. Plausibility
    scales: misalignment 1 deg, gain 1 %, bias 0.1 g (in input units)."""
    means = np.asarray(means, dtype=float)
    J = accel_jacobian(p, means, gravity)
    res = np.linalg.norm(accel_apply(p, means), axis=1) - gravity
    m = len(means)
    s2 = float(res @ res) / max(m - 9, 1) if misfit else 0.0
    s2 = max(s2, sigma ** 2 / max(n_samples / max(m, 1), 1.0))
    gains = np.abs(p[3:6])
    scale = np.concatenate([np.full(3, PLAUSIBLE_MISALIGNMENT_RAD), PLAUSIBLE_SCALE_REL * gains,
                            PLAUSIBLE_ACCEL_BIAS_G * gravity / gains])
    return Determination.from_jacobian(J, math.sqrt(s2), names, scale, based_on=f"interval means ({m} rows)")


def fit_accel_norm(accel, intervals, gravity: float, *, samples_per_interval: int | None = None, x0=None,
                   input_units: str = "count", input_factor: float = 1.0, input_kind: str = "rate",
                   dt: float = 1.0, min_intervals: int = MIN_INTERVALS,
                   recommended_intervals: int = RECOMMENDED_INTERVALS, rank_rtol: float = 1e-6,
                   detection: detect.StaticDetection | None = None, path=None,
                   hold_undetermined: bool = True) -> TriadFit:
    """Accelerometer calibration by the gravity norm at static intervals (9-parameter model).

    ``accel``: (n, 3) samples in the calibration's input units (counts, or m s-2 -- already converted).
    ``intervals``: (m, 2) ``[start, stop)`` static sample ranges. ``gravity``: local gravity [m s-2].
    ``samples_per_interval``: use only the first n samples of each interval (IMU-TK: 100); None = all.
    ``x0``: initial parameters (:data:`ACCEL_NAMES` order); default: ellipsoid fit to the interval means.
    Raises a :class:`detect.StaticDetectionError` (with a threshold suggestion when ``detection`` is given)
    for fewer than ``min_intervals`` intervals. ``input_*``/``dt``: how raw recording samples map to the input
    units (stored for :meth:`TriadFit.apply`).

    What the poses determine (:func:`accel_determination`) is stored as ``determination``; with
    ``hold_undetermined`` the parameters ``not determined`` are held at nominal (misalignment 0; gain 1 and
    bias 0 for physical units, for counts the geometric mean of the determined gains and the initial bias) and
    the others refitted (their covariance rows are NaN). As many poses as parameters (9) or fewer leave no
    redundancy: said in the notes and on the console.
    """
    accel = np.asarray(accel, dtype=np.float64)
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    notes = []
    note = _require_intervals(len(iv), min_intervals, recommended_intervals, detection, path)
    if note:
        notes.append(note)
    N, which = _select_samples(accel, iv, samples_per_interval)
    means = np.array([accel[a:b].mean(axis=0) for a, b in iv])
    if x0 is None:
        x0 = ellipsoid_guess(means, gravity)
        if x0 is None and input_units != "count":
            x0 = np.array(NOMINAL)
            notes.append("initial guess nominal (ellipsoid fit to the static means not positive definite: the "
                         "poses do not span all directions)")
        elif x0 is None:
            x0 = range_guess(means, gravity)
            notes.append("initial guess from the range of the static means (ellipsoid fit not positive definite)")
        else:
            notes.append("initial guess from an algebraic ellipsoid fit to the static means")
    x0 = np.asarray(x0, dtype=float)
    hold0 = np.zeros(9, dtype=bool)
    if hold_undetermined and any("not positive definite" in n for n in notes):
        # poses that do not span all directions: hold what they cannot see before the fit, or the fit wanders
        r0 = accel_residual(x0, N, gravity)
        r0 = r0 - np.array([r0[which == i].mean() for i in range(len(iv))])[which]  # noise only, not misfit
        det0 = accel_determination(x0, means, len(N), float(np.sqrt(np.mean(r0 ** 2))), gravity, misfit=False)
        hold0 = np.array([v == "not determined" for v in det0.verdicts])
    if hold0.any():
        x_fixed = x0.copy()

        def fun0(q):
            return accel_residual(_put(x_fixed, hold0, q), N, gravity)

        def jac0(q):
            return accel_jacobian(_put(x_fixed, hold0, q), N, gravity)[:, ~hold0]

        sol = least_squares(fun0, x0[~hold0], jac=jac0, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12,
                            gtol=1e-12)
        p = _put(x_fixed, hold0, sol.x)
    else:
        sol = least_squares(accel_residual, x0, jac=accel_jacobian, args=(N, gravity), method="lm",
                            x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
        p = sol.x
    if p[5] < 0 or p[4] < 0 or p[3] < 0:  # a sign flip of one axis gives the same norms: fix the gauge
        flip = np.sign(p[3:6])
        p = p.copy()
        p[3:6] *= flip
        # T' = D T D with D = diag(flip): entry (i, j) changes sign with d_i d_j; the output frame is D x the old
        p[0] *= flip[0] * flip[1]
        p[1] *= flip[0] * flip[2]
        p[2] *= flip[1] * flip[2]
        notes.append("gain signs fixed positive (the norm does not see axis sign)")
    r = accel_residual(p, N, gravity)
    sigma_first = math.sqrt(float(r @ r) / max(len(r) - 9, 1))
    det = accel_determination(p, means, len(N), sigma_first, gravity)
    free = ~hold0
    if hold_undetermined and (det.not_determined or hold0.any()):
        free = np.array([v != "not determined" for v in det.verdicts]) & ~hold0
        gains_det = np.abs(p[3:6][free[3:6]])
        nominal = np.zeros(9)
        if input_units == "count":
            nominal[3:6] = float(np.exp(np.mean(np.log(gains_det)))) if gains_det.size else p[3:6]
            nominal[6:9] = x0[6:9]
        else:
            nominal[3:6] = 1.0
        p = np.where(free, p, nominal)
        if free.any():
            p_fixed = p.copy()

            def fun_free(q):
                pp = p_fixed.copy()
                pp[free] = q
                return accel_residual(pp, N, gravity)

            def jac_free(q):
                pp = p_fixed.copy()
                pp[free] = q
                return accel_jacobian(pp, N, gravity)[:, free]

            sol2 = least_squares(fun_free, p[free], jac=jac_free, method="lm", x_scale="jac", xtol=1e-12,
                                 ftol=1e-12, gtol=1e-12)
            p = p_fixed.copy()
            p[free] = sol2.x
        det.held = tuple(n for n, f in zip(ACCEL_NAMES, free) if not f)
        det.nominal = {n: float(p[i]) for i, n in enumerate(ACCEL_NAMES) if not free[i]}
    r = accel_residual(p, N, gravity)
    J = accel_jacobian(p, N, gravity)
    m, k = J.shape
    dof = max(m - int(free.sum()), 1)
    sigma2 = float(r @ r) / dof
    if free.all():
        cov = sigma2 * np.linalg.pinv(J.T @ J)
    else:
        cov = np.full((9, 9), np.nan)
        cov[np.ix_(free, free)] = sigma2 * np.linalg.pinv(J[:, free].T @ J[:, free])
    if len(iv) < MIN_POSES_TO_TEST:
        msg = (f"{len(iv)} static poses for {NORM_PARAMETERS} accelerometer parameters: no redundancy, the residuals "
               f"cannot reveal a bad pose or a model error (calib diagnose needs at least {MIN_POSES_TO_TEST} and "
               "will answer inconclusive on this file)")
        notes.append(msg)
        log.warning("%s: %s", path or "input", msg)
    if det.not_determined or det.weak:
        notes.append(det.describe("accel"))
        log.warning("%s: %s", path or "input", det.describe("accel"))
    ident = rank_summary(accel_jacobian(p, means, gravity), ACCEL_NAMES, rank_rtol,
                            based_on=f"interval means ({len(iv)} rows)")
    if ident.rank < 9:
        notes.append(f"norm model not fully identified: {ident.describe()}")
    gains = p[3:6]
    sf = 1.0 / gains
    sf_std = np.sqrt(np.diag(cov)[3:6]) / gains ** 2
    cal_means = accel_apply(p, means)
    mean_res = np.linalg.norm(cal_means, axis=1) - gravity
    in_u = input_label("accel", input_units, input_kind)
    sf_units = scale_factor_units("accel", input_units, in_u)
    return TriadFit(
        sensor="accel", method="gravity_norm", names=ACCEL_NAMES, values=p, covariance=cov,
        param_units=("rad", "rad", "rad", f"m s-2 per {in_u}", f"m s-2 per {in_u}", f"m s-2 per {in_u}",
                     in_u, in_u, in_u),
        matrix=accel_matrix(p), bias=p[6:9].copy(), input_units=input_units, input_factor=float(input_factor),
        input_kind=input_kind, dt=float(dt), output_units="m s-2", scale_factors=sf, scale_factor_std=sf_std,
        scale_factor_units=sf_units, residual_rms=float(np.sqrt(np.mean(r * r))), residual_units="m s-2",
        n_residuals=int(m), identifiability=ident, notes=notes, determination=det,
        extra={"interval_norm_residuals": mean_res, "interval_norm_rms": float(np.sqrt(np.mean(mean_res ** 2))),
               "sigma": math.sqrt(sigma2), "n_intervals": int(len(iv)), "samples_per_interval": samples_per_interval,
               "x0": x0, "nfev": int(sol.nfev), "residuals": r, "residual_interval": which})


def norm_residual_rms(accel_calibrated, gravity: float, intervals=None, mask=None,
                      samples_per_interval: int | None = None) -> float:
    """Per-sample RMS of ``|a| - g`` [m s-2] over static ``intervals`` (optionally their first n samples)
    or a boolean ``mask`` of static samples: how IMU-TK, imucal and mikoff/imu-calib measure it."""
    a = np.asarray(accel_calibrated, dtype=float)
    if mask is not None:
        x = a[np.asarray(mask, dtype=bool)]
    else:
        x, _ = _select_samples(a, intervals, samples_per_interval)
    r = np.linalg.norm(x, axis=1) - gravity
    return float(np.sqrt(np.mean(r * r)))
