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
  model ``mean_m = b + G a_m`` on the interval means, bound ``(X^T W X)^-1``, W = n_m / sigma_i^2).
* Not bounded here (reported as such, never as a number): the gyro's gravity-direction parameters (the
  information of the integrated motions is not computed) and the offsets of the ``initial`` / ``estimate`` modes.

The noise is the white part measured inside the intervals: slower noise (bias drift over the session) is not in
it, so the bound is what white noise alone allows.
"""
from __future__ import annotations

import numpy as np

from calib.calibration import bound as calbound
from calib.fieldcal.accelerometer import accel_matrix
from calib.fieldcal.gyroscope import GSENS_NAMES
from calib.fieldcal.results import BIAS_NAMES

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


def gyro_offset_bound(fit, gyro_in, accel_cal, intervals, mode: str) -> dict:
    """The bound of the gyro fit's offsets for the bias ``mode`` (``statics`` | ``g_sensitive``; the others are
    reported as not bounded) from the static intervals' white noise."""
    spans = used_samples(intervals)
    means, n, sig = interval_noise(gyro_in, spans)
    names = BIAS_NAMES + (GSENS_NAMES if mode == "g_sensitive" else ())
    out = {nm: None for nm in fit.names}
    reason = {nm: "not bounded: the gravity-direction fit's information is not computed" for nm in fit.names}
    if mode == "statics":
        X = np.ones((len(n), 1))
    elif mode == "g_sensitive":
        am = np.array([np.asarray(accel_cal[a:b], dtype=float).mean(axis=0) for a, b in spans])
        X = np.column_stack([np.ones(len(n)), am])
    else:
        for nm in BIAS_NAMES:
            reason[nm] = f"not bounded: the bias of mode {mode!r} is not computed here"
        return {"sigma": out, "why_none": reason, "noise_sigma_per_sample": [float(v) for v in sig],
                "noise": NOISE_NOTE}
    for i in range(3):   # axis i: mean_m,i = X_m . [b_i, G_i,:], variance sig_i^2 / n_m
        C = np.linalg.inv(X.T @ (X * (n / sig[i] ** 2)[:, None]))
        s = np.sqrt(np.diag(C))
        out[BIAS_NAMES[i]] = float(s[0])
        reason.pop(BIAS_NAMES[i])
        if mode == "g_sensitive":
            for j in range(3):
                out[GSENS_NAMES[3 * i + j]] = float(s[1 + j])
                reason.pop(GSENS_NAMES[3 * i + j])
    return {"sigma": {nm: out[nm] for nm in fit.names}, "why_none": reason,
            "noise_sigma_per_sample": [float(v) for v in sig], "noise": NOISE_NOTE,
            "model": f"offsets ({mode}) from {len(n)} static interval means, {int(n.sum())} samples",
            "of": list(names)}


def attach(acc_fit, gyr_fit, acc_in, gyr_in, accel_raw, intervals, gravity: float) -> None:
    """Put the bounds of a norm-method result in its fits' ``extra["sigma_crb"]`` (reported by
    :meth:`calib.fieldcal.results.FieldCalResult.summary`): the accel's from :func:`accel_bound`, the gyro's offsets
    from :func:`gyro_offset_bound` (bias mode ``extra["bias_mode"]`` of the gyro fit)."""
    acc_fit.extra["sigma_crb"] = accel_bound(acc_fit, acc_in, intervals, gravity)
    if gyr_fit is not None and gyr_in is not None:
        mode = gyr_fit.extra.get("bias_mode", "")
        acc_cal = acc_fit.apply(np.asarray(accel_raw)) if mode == "g_sensitive" else None
        gyr_fit.extra["sigma_crb"] = gyro_offset_bound(gyr_fit, gyr_in, acc_cal, intervals, mode)
