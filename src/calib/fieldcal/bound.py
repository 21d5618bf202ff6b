"""Cramér–Rao bound of a field calibration's parameters from the recording's poses and its measured noise.

Beside every parameter of ``calib fieldcal`` (norm method) the report gives ``sigma_crb``: how precisely any
unbiased estimator could determine it from the static poses the fit uses, for the noise measured on the recording.
It is computed from the measurement model alone (:mod:`calib.calibration.bound`), not by the fit.

* Accelerometer (9 parameters of the gravity-norm model, :mod:`calib.fieldcal.accelerometer`): the interval means
  ``N_m = M x_m + b`` with ``M = (T_a K_a)^-1`` and ``|x_m| = g`` (the pose's direction unknown: the norm-observed
  model), evaluated at the fit's parameters and poses; the covariance of a mean is ``sigma_i^2 / n_m`` per axis
  with ``sigma_i`` the white scatter of the samples about their interval means (pooled over the intervals) and
  ``n_m`` the samples of interval m the fit uses. The parameters the fit holds at nominal are taken as known.
* Gyro offsets: the constant bias (``statics``: mean over the static samples; bound ``sigma_i / sqrt(n)``, the
  noise density over the square root of the static time) or bias and g-sensitivity (``g_sensitive``: the linear
  model ``mean_m = b + G a_m`` on the interval means, bound ``(X^T W X)^-1``, W = n_m / sigma_i^2); the bias of
  the initial rest (``initial``: the mean of the initial rest's n samples the fit averages, bound
  ``sigma_i / sqrt(n)``); the bias estimated with the gravity-direction parameters from the motions
  (``estimate``: the bias rows of :func:`gyro_direction_bound`'s inverse, the bias a further unknown of the
  integration; an axis the fit holds keeps the initial-rest mean and its bound).
* Gyro gravity-direction parameters (6 misalignments, 3 gains, :func:`gyro_direction_bound`): each motion
  carries the gravity direction of one pose into the next through the integrated, corrected gyro; the
  information of the accel interval means (which see the pose directions and determine the accel calibration)
  and of the motions (the gyro white noise integrated over each, about angle random walk x sqrt(duration))
  over [accel parameters, gyro parameters, pose directions], the directions and the accel parameters profiled
  out. Derivatives of the integration by central differences (the forward model, not the fit's covariance).
* Beside each bound, ``se_over_crb``: the fit's reported standard error over it (None where the fit reports no
  standard error or the bound has no number).

The noise is the white part measured inside the intervals: slower noise (bias drift over the session) is not in
it, so the bound is what white noise alone allows.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

from calib.calibration import bound as calbound
from calib.fieldcal.accelerometer import accel_matrix, misalignment_matrix
from calib.fieldcal.gyroscope import GSENS_NAMES, _GyroProblem
from calib.fieldcal.results import BIAS_NAMES, GYRO_NAMES

NOISE_NOTE = ("white noise measured as the scatter of the samples about their interval means (pooled over the "
              "intervals); slower noise is not included")


def used_samples(intervals, samples_per_interval=None) -> list:
    """The [start, stop) sample range of each interval the fit uses (its first ``samples_per_interval``)."""
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    n = samples_per_interval
    return [(int(a), int(b if n is None else min(b, a + int(n)))) for a, b in iv]


def interval_noise(x, spans):
    """(means (m, 3), counts (m,), white sigma per axis (3,)) of ``x`` (n, 3) over the sample ranges ``spans``:
    the pooled scatter of the samples about their interval means (ddof one per interval)."""
    x = np.asarray(x, dtype=float)
    means = np.array([x[a:b].mean(axis=0) for a, b in spans])
    n = np.array([b - a for a, b in spans], dtype=float)
    ss = sum(((x[a:b] - mu) ** 2).sum(axis=0) for (a, b), mu in zip(spans, means))
    dof = float(np.sum(n - 1.0))
    if dof < 1:
        raise ValueError("the noise needs intervals of at least two samples")
    return means, n, np.sqrt(ss / dof)


def _accel_theta(p):
    """[vec(M) row-major, b] of the field calibration's 9 accel parameters: M = (T_a K_a)^-1."""
    return np.concatenate([np.linalg.inv(accel_matrix(p)).ravel(), np.asarray(p[6:9], dtype=float)])


def accel_bound(fit, accel_in, intervals, gravity: float) -> dict:
    """``{"sigma": {name: bound or None}, "noise": sigma per axis, ...}`` of the accel fit ``fit``
    (:class:`calib.fieldcal.results.TriadFit`, norm model) on ``accel_in`` (n, 3) [the fit's input units]."""
    p = np.asarray(fit.values, dtype=float)
    spans = used_samples(intervals, fit.extra.get("samples_per_interval"))
    means, n, sig = interval_noise(accel_in, spans)
    A = accel_matrix(p)
    x = (means - p[6:9]) @ A.T
    x = float(gravity) * x / np.linalg.norm(x, axis=1, keepdims=True)
    cov = np.stack([np.diag(sig[i] ** 2 / n) for i in range(3)])
    obs = calbound.Observations(x, cov, np.ones(len(n), bool), f"{len(n)} static intervals")
    F = calbound.information(np.linalg.inv(A), [obs], "norm")
    # d theta / d p by central differences (theta(p) is smooth: an inverse of a 3x3 near the identity's scale)
    # steps: 1e-6 of the value, at least of 1 mrad (misalignments) or of 1 m s-2 in input units (biases)
    floor = np.r_[np.full(3, 1e-3), np.abs(p[3:6]), np.full(3, 1.0 / np.abs(p[3:6]).mean())]
    h = 1e-6 * np.maximum(np.abs(p), floor)
    T = np.column_stack([(_accel_theta(p + h[k] * np.eye(9)[k]) - _accel_theta(p - h[k] * np.eye(9)[k]))
                         / (2 * h[k]) for k in range(9)])
    held = set(fit.determination.held) if fit.determination is not None else set()
    free = np.array([nm not in held for nm in fit.names])
    sigma, det = calbound.bound_of_parameters(F, T, fit.names, free)
    why = {nm: ("held at nominal by the fit (not estimated)" if nm in held else
                "not determined by these poses (a null direction of the information)")
           for nm, d in zip(fit.names, det) if not d}
    return {"sigma": {nm: (float(s) if d else None) for nm, s, d in zip(fit.names, sigma, det)},
            "why_none": why, "held_at_nominal": sorted(held), "noise_sigma_per_sample": [float(v) for v in sig],
            "units": dict(zip(fit.names, fit.param_units)), "model": "norm-observed (pose directions unknown)",
            "noise": NOISE_NOTE, "intervals": int(len(n)), "samples": int(n.sum())}


def gyro_offset_bound(fit, gyro_in, accel_cal, intervals, mode: str, bias_span=None) -> dict:
    """The bound of the gyro fit's offsets for the bias ``mode`` from the static intervals' white noise:
    ``statics`` | ``g_sensitive`` (the static interval means), ``initial`` (the mean of the samples
    ``bias_span`` = [start, stop) of the initial rest: ``sigma_i / sqrt(n)``). ``estimate``: the bias comes from
    the motions, bounded by :func:`gyro_direction_bound` (:func:`attach` puts it here); without ``bias_span`` the
    ``initial`` bias gets no number."""
    spans = used_samples(intervals)
    means, n, sig = interval_noise(gyro_in, spans)
    names = BIAS_NAMES + (GSENS_NAMES if mode == "g_sensitive" else ())
    out = {nm: None for nm in fit.names}
    reason = {nm: "not bounded here: a gravity-direction parameter (gyro_direction_bound)" for nm in fit.names}
    base = {"noise_sigma_per_sample": [float(v) for v in sig], "noise": NOISE_NOTE}
    if mode == "initial" or mode == "estimate":
        for nm in BIAS_NAMES:
            reason[nm] = ("not bounded: the samples of the initial rest the bias is the mean of are not known "
                          "(bias_span)" if mode == "initial" else
                          "estimated with the gravity-direction parameters from the motions (gyro_direction_bound)")
        if mode == "estimate" or bias_span is None:
            return {"sigma": out, "why_none": reason, **base}
        a, b = int(bias_span[0]), int(bias_span[1])
        for i, nm in enumerate(BIAS_NAMES):   # the mean of n white samples: variance sig_i^2 / n
            out[nm] = float(sig[i] / np.sqrt(b - a))
            reason.pop(nm)
        return {"sigma": out, "why_none": reason, **base, "of": list(BIAS_NAMES),
                "model": f"offsets (initial): the mean of the initial rest, samples [{a}, {b}) ({b - a} samples)"}
    if mode == "statics":
        X = np.ones((len(n), 1))
    elif mode == "g_sensitive":
        am = np.array([np.asarray(accel_cal[a:b], dtype=float).mean(axis=0) for a, b in spans])
        X = np.column_stack([np.ones(len(n)), am])
    else:
        for nm in BIAS_NAMES:
            reason[nm] = f"not bounded: the bias of mode {mode!r} is not computed here"
        return {"sigma": out, "why_none": reason, **base}
    for i in range(3):   # axis i: mean_m,i = X_m . [b_i, G_i,:], variance sig_i^2 / n_m
        C = np.linalg.inv(X.T @ (X * (n / sig[i] ** 2)[:, None]))
        s = np.sqrt(np.diag(C))
        out[BIAS_NAMES[i]] = float(s[0])
        reason.pop(BIAS_NAMES[i])
        if mode == "g_sensitive":
            for j in range(3):
                out[GSENS_NAMES[3 * i + j]] = float(s[1 + j])
                reason.pop(GSENS_NAMES[3 * i + j])
    return {"sigma": {nm: out[nm] for nm in fit.names}, "why_none": reason, **base,
            "model": f"offsets ({mode}) from {len(n)} static interval means, {int(n.sum())} samples",
            "of": list(names)}


def _gyro_residuals(prob, p, nb):
    """The direction residuals (motions, 3) of the gyro fit's model at its external parameters ``p`` = [6
    misalignments, 3 gains, ``nb`` bias corrections in input units]: the same integration as the fit."""
    M = misalignment_matrix(p[:6]) * np.asarray(p[6:9])[None, :]
    return prob.residual_vectors(M, p[9:9 + nb] if nb else 0.0)


def _tangents(p):
    """(m, 2, 3): two unit vectors orthogonal to each unit row of ``p`` (m, 3)."""
    e = np.eye(3)[np.argmin(np.abs(p), axis=1)]
    t1 = np.cross(p, e)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return np.stack([t1, np.cross(p, t1)], axis=1)


def gyro_direction_bound(fit, gyro_in, accel_in, acc_fit, accel_cal, intervals, gravity: float, dts=None) -> dict:
    """The bound of the gravity-direction fit's parameters (:func:`calib.fieldcal.gyroscope.fit_gyro_directions`):
    the 6 misalignments and 3 gains (with the bias corrections as further unknowns when the fit estimates them).

    Model, at the fits' parameters: the gravity direction ``d_m`` of pose m (unknown: two angles each) is seen
    by the accelerometers, ``N_m = M_a g d_m + b_a`` (the accel fit's 9 parameters, ``M_a = (T_a K_a)^-1``; the
    interval means, covariance ``sigma_a,i^2 / n_m`` per axis from the white scatter of the samples about their
    means), and carried by the gyro over motion m into the next pose, ``R_m(theta)^T d_m - d_m+1 = 0`` up to the
    angle noise of the integrated gyro (R_m: the corrected gyro integrated over the motion as the fit does).
    The angle noise per axis has variance ``sigma_g^2 sum_k w_k^2`` (sigma_g the gyro's white scatter on the
    static intervals, w_k the trapezoid integration weight of sample k: about angle random walk^2 x the motion's
    duration), through the gyro calibration matrix, taken isotropic with the mean of the three axes' variances
    (the trace is exact whatever the turns); only its two components across the carried direction are seen.

    The Fisher information over [accel parameters, gyro parameters, pose directions] is the sum of the accel
    means' ``J^T C^-1 J`` and the motions' (derivatives by the gyro parameters: central differences of the
    integration, the forward model; no fit covariance). The pose directions and the accel parameters are
    estimated with them (the accel calibration comes from the same means: its uncertainty moves every
    direction) and profiled out; the bound is the inverse on the seen combinations
    (:func:`calib.core.information.seen_inverse`). Parameters a fit holds at nominal are known; a parameter a
    null direction moves gets no number. Taken as known: the gyro offsets (bias, g-sensitivity) removed before
    the integration, unless the fit estimates the bias. ``dts``: the integration steps the fit used (default: the
    nominal step)."""
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    gyro_in = np.asarray(gyro_in, dtype=float)
    accel_cal = np.asarray(accel_cal, dtype=float)
    dts = np.full(len(gyro_in), float(fit.dt)) if dts is None else np.asarray(dts, dtype=float)
    nb = 3 if fit.extra.get("bias_estimated") else 0
    names = GYRO_NAMES + (BIAS_NAMES if nb else ())
    prob = _GyroProblem(gyro_in, accel_cal, iv, dts, fit.bias, fit.g_sensitivity)
    p = np.concatenate([np.asarray(fit.values[:9], dtype=float), np.zeros(nb)])
    kg = len(p)
    gains = p[6:9]
    # steps: 1e-6 rad (misalignments), 1e-6 of the gain, a bias of 1e-6 rad s-1
    h = np.concatenate([np.full(6, 1e-6), 1e-6 * np.abs(gains), np.full(nb, 1e-6 / np.abs(gains).mean())])
    Jg = np.stack([(_gyro_residuals(prob, p + h[k] * np.eye(kg)[k], nb)
                    - _gyro_residuals(prob, p - h[k] * np.eye(kg)[k], nb)) / (2 * h[k])
                   for k in range(kg)], axis=-1)   # (motions, 3, kg)
    G = misalignment_matrix(p[:6]) * gains[None, :]
    R = prob.rotations(G, p[9:9 + nb] if nb else 0.0)
    d = prob.u                                     # (poses, 3) unit gravity directions
    carried = np.einsum("mji,mj->mi", R, d[:-1])   # R_m^T d_m
    m, npos = prob.n_pairs, len(d)
    tb, tc = _tangents(d), _tangents(carried)
    # the accel fit: 9 parameters -> theta = [vec(M_a), b_a] (as accel_bound)
    pa = np.asarray(acc_fit.values, dtype=float)
    floor = np.r_[np.full(3, 1e-3), np.abs(pa[3:6]), np.full(3, 1.0 / np.abs(pa[3:6]).mean())]
    ha = 1e-6 * np.maximum(np.abs(pa), floor)
    Ta = np.column_stack([(_accel_theta(pa + ha[k] * np.eye(9)[k]) - _accel_theta(pa - ha[k] * np.eye(9)[k]))
                          / (2 * ha[k]) for k in range(9)])
    Ma = np.linalg.inv(accel_matrix(pa))
    spans = [(int(a), int(b)) for a, b in iv]
    _, n_a, sig_a = interval_noise(accel_in, spans)
    _, _, sig_g = interval_noise(gyro_in, spans)
    q = 9 + kg + 2 * npos                          # [accel 9, gyro kg, two angles per pose]
    F = np.zeros((q, q))
    for k in range(npos):                          # the accel means: N_m,i = M_a,i . g d_m + b_a,i
        x = float(gravity) * d[k]
        for i in range(3):
            row = np.zeros(q)
            jt = np.zeros(12)
            jt[3 * i:3 * i + 3] = x
            jt[9 + i] = 1.0
            row[:9] = jt @ Ta
            row[9 + kg + 2 * k:11 + kg + 2 * k] = float(gravity) * (Ma[i] @ tb[k].T)
            F += np.outer(row, row) * (n_a[k] / sig_a[i] ** 2)
    var_rate = float(np.trace(G @ np.diag(sig_g ** 2) @ G.T)) / 3.0   # [rad2 s-2] per sample, mean of the axes
    phi2 = np.empty(m)
    for k in range(m):                             # the motions: R_m^T d_m - d_m+1, across the carried direction
        step = prob.dt[prob.starts[k]:prob.stops[k]]
        w = np.zeros(len(step) + 1)
        w[:-1] += 0.5 * step
        w[1:] += 0.5 * step
        phi2[k] = var_rate * float(w @ w)
        rows = np.zeros((2, q))
        rows[:, 9:9 + kg] = tc[k] @ Jg[k]
        rows[:, 9 + kg + 2 * k:11 + kg + 2 * k] = tc[k] @ R[k].T @ tb[k].T
        rows[:, 11 + kg + 2 * k:13 + kg + 2 * k] = -tc[k] @ tb[k + 1].T
        F += rows.T @ rows / phi2[k]
    held_a = set(acc_fit.determination.held) if acc_fit.determination is not None else set()
    held = set(fit.determination.held) if fit.determination is not None else set()
    free = np.concatenate([[nm not in held_a for nm in acc_fit.names], [nm not in held for nm in names],
                           np.ones(2 * npos, bool)])
    sigma, det = calbound.bound_of_parameters(0.5 * (F + F.T), np.eye(q), None, free)
    sigma, det = sigma[9:9 + kg], det[9:9 + kg]
    why = {nm: ("held at nominal by the fit (not estimated)" if nm in held else
                "not determined: a combination of the gyro parameters, the pose directions and the accel "
                "calibration that these poses and motions do not see moves it (a null direction of the information)")
           for nm, dd in zip(names, det) if not dd}
    return {"sigma": {nm: (float(s) if dd else None) for nm, s, dd in zip(names, sigma, det)}, "why_none": why,
            "held_at_nominal": sorted(held), "motions": int(m),
            "accel_noise_sigma_per_sample": [float(v) for v in sig_a],
            "gyro_noise_sigma_per_sample": [float(v) for v in sig_g],
            "angle_noise_rad": [float(v) for v in np.sqrt(phi2)],
            "model": (f"gravity directions of {npos} poses seen by the accel means and carried over {m} motions "
                      "by the integrated gyro (derivatives of the integration by central differences); the "
                      "directions and the accel calibration estimated with them; noise: white, measured on the "
                      "static intervals" + ("; bias corrections estimated with them" if nb else
                                            "; the gyro offsets taken as known"))}


def _se_over_crb(fit, block) -> None:
    """Add ``se_over_crb`` to a bound ``block``: the fit's reported standard error of each parameter over its
    bound (None where either is missing: a bound without a number, or a parameter the fit reports no standard
    error for)."""
    se = fit.std
    ratio = {}
    for k, nm in enumerate(fit.names):
        b = block["sigma"].get(nm)
        ratio[nm] = float(se[k] / b) if (b is not None and b > 0 and np.isfinite(se[k])) else None
    block["se_over_crb"] = ratio


def attach(acc_fit, gyr_fit, acc_in, gyr_in, accel_raw, intervals, gravity: float) -> None:
    """Put the bounds of a norm-method result in its fits' ``extra["sigma_crb"]`` (reported by
    :meth:`calib.fieldcal.results.FieldCalResult.summary`): the accel's from :func:`accel_bound`, the gyro's offsets
    from :func:`gyro_offset_bound` (bias mode ``extra["bias_mode"]`` of the gyro fit; the initial rest's samples
    ``extra["bias_span"]``) and its gravity-direction parameters from :func:`gyro_direction_bound` (integration
    steps ``extra["integration_dt"]`` of the gyro fit, else the nominal step), with the bias in mode ``estimate``
    (an axis the fit holds at its initial-rest mean: that mean's bound); each with ``se_over_crb``."""
    acc_fit.extra["sigma_crb"] = accel_bound(acc_fit, acc_in, intervals, gravity)
    _se_over_crb(acc_fit, acc_fit.extra["sigma_crb"])
    if gyr_fit is not None and gyr_in is not None:
        mode = gyr_fit.extra.get("bias_mode", "")
        span = gyr_fit.extra.get("bias_span")
        acc_cal = acc_fit.apply(np.asarray(accel_raw))
        init = gyro_offset_bound(gyr_fit, gyr_in, None, intervals, "initial", span) if span is not None else None
        off = init if mode == "initial" and init is not None else gyro_offset_bound(
            gyr_fit, gyr_in, acc_cal if mode == "g_sensitive" else None, intervals, mode)
        dirb = gyro_direction_bound(gyr_fit, gyr_in, acc_in, acc_fit, acc_cal, intervals, gravity,
                                    gyr_fit.extra.get("integration_dt"))
        from_dir = GYRO_NAMES + (BIAS_NAMES if mode == "estimate" else ())
        for nm in from_dir:
            off["sigma"][nm] = dirb["sigma"].get(nm)
            off["why_none"].pop(nm, None)
            if nm in dirb["why_none"]:
                off["why_none"][nm] = dirb["why_none"][nm]
        if mode == "estimate":
            held = [nm for nm in BIAS_NAMES if nm in dirb.get("held_at_nominal", [])]
            for nm in held:   # held at its start: the initial-rest mean, bounded when its samples are known
                off["sigma"][nm] = None if init is None else init["sigma"][nm]
                off["why_none"].pop(nm, None)
                if init is None:
                    off["why_none"][nm] = ("held by the fit at the initial-rest mean, whose samples are not known "
                                           "(bias_span)")
            off["of"] = list(BIAS_NAMES)
            off["model"] = ("offsets (estimate): the bias estimated with the gravity-direction parameters from the "
                            f"{dirb['motions']} motions (see direction)" +
                            (f"; {', '.join(held)} held by the fit at the initial-rest mean" +
                             (f": {init['model']}" if init is not None else "") if held else ""))
        off["direction"] = {k: v for k, v in dirb.items() if k not in ("sigma", "why_none")}
        _se_over_crb(gyr_fit, off)
        gyr_fit.extra["sigma_crb"] = off
