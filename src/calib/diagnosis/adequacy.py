"""Adequacy of a fit everywhere it can fail, on the measured noise (module doc of :mod:`calib.diagnosis`).

A family of chi-square tests on the whitened residuals of a fit: the whole record, each (sensor, axis) block,
each sensor's static and rotation windows, and each sensor's first and last third of the session (where warm-up
and drift show). Whitened residuals are the innovations of the block Cholesky factor, one per observation, so a
subset's sum of squares is its chi-square; its degrees of freedom are the subset's share of the residual
freedom, sum(1 - h_ii) with h the leverages of the whitened design. The family is controlled by Holm's
step-down procedure at ``adequacy_alpha``: a fit is adequate when no test is rejected.

The noise is the *measured* one: the Allan deviation of the static samples (fast noise and its rate random walk),
not the level and slow part the search estimates from the window means (vector model) nor the sigmas the norm
model scales to the scatter of the segment means (an overdispersion it reports): an overdispersion can be
reported, never pass a test.

Where a test fails, :func:`unexplained_entries` says where the rest sits (sensor, axis, segment class, part of
the session), how large it is in the sensor's output unit, and which generic shape in time fits it best
(offset, linear or quadratic trend, a sinusoid of the best period on a grid): the open search of the residuals
that a library term is judged against.
"""
from __future__ import annotations

import math

import numpy as np

from calib.core.distributions import chi2_sf
from calib.diagnosis.geometry import AXES, SENSORS
from calib.diagnosis.problem import Fit, Problem


def measured_factors(prob: Problem) -> dict:
    """Cholesky factors of the measured noise of the window means: the Allan deviation of the static samples
    (fast noise and its rate-random-walk term), before the problem estimates a level or a slow part from the
    window means themselves (vector model) or scales the sigmas to their scatter (norm model)."""
    return prob.L_measured if prob.L_measured is not None else prob.L


def leverages(prob: Problem, f: Fit, L=None) -> np.ndarray:
    """Diagonal of the hat matrix of the whitened design of ``f`` (zeros when the fit kept no design)."""
    if f.X is None:
        return np.zeros(prob.n)
    Xw = prob.whiten(f.X, L)
    u, s, _ = np.linalg.svd(Xw, full_matrices=False)
    keep = s > s[0] * 1e-10 if s.size else np.zeros(0, bool)
    return np.sum(u[:, keep] ** 2, axis=1)


def subset_masks(prob: Problem) -> dict:
    """Name -> boolean mask over the observations of every subset the adequacy test judges."""
    return {name: m for name, _, m in _groups(prob)}


def _groups(prob: Problem):
    """(name, description dict, boolean mask) of every subset tested."""
    g, o = prob.geom, prob.geom.obs
    n = prob.n
    out = [("all", {"scope": "all"}, np.ones(n, bool))]
    for (si, a), idx in o["blocks"].items():
        m = np.zeros(n, bool)
        m[idx] = True
        axis = AXES[a] if prob.kind == "vector" else "norm"
        out.append((f"{SENSORS[si]} {axis}", {"scope": "sensor_axis", "sensor": SENSORS[si], "axis": axis}, m))
    kinds = np.array([g.windows[w].kind for w in o["window"]])
    t_mid = np.array([g.time_s[g.windows[w].i0] for w in o["window"]])
    t_lo, t_hi = float(t_mid.min()), float(t_mid.max())
    third = (t_hi - t_lo) / 3.0
    for si, s in enumerate(SENSORS):
        ms = o["sensor"] == si
        if not ms.any():
            continue
        if len(set(kinds[ms])) > 1:
            for kind in ("static", "rotation"):
                m = ms & (kinds == kind)
                if m.any():
                    out.append((f"{s} {kind} windows", {"scope": "segment_class", "sensor": s, "class": kind}, m))
        if third > 0:
            for part, m in (("first third", ms & (t_mid <= t_lo + third)),
                            ("last third", ms & (t_mid >= t_hi - third))):
                if m.sum() >= 3:
                    out.append((f"{s} {part} of the session", {"scope": "session_part", "sensor": s,
                                                                 "part": part}, m))
    return out


def holm(pvalues, alpha):
    """Holm's step-down: which of ``pvalues`` are rejected at family-wise level ``alpha``; adjusted p-values."""
    p = np.asarray(pvalues, float)
    order = np.argsort(p)
    m = p.size
    adj = np.empty(m)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        adj[i] = running
    return adj <= alpha, adj


def adequacy(prob: Problem, f: Fit, alpha: float | None = None, L=None) -> dict:
    """The family of tests of fit ``f`` (see module doc) on the measured noise (or the factors ``L``). Returns
    ``adequate`` (no rejection), ``tests`` (each with chi2, dof, p, Holm-adjusted p, rejected, and the
    overdispersion chi2/dof) and ``alpha``."""
    alpha = float(prob.settings.get("adequacy_alpha", 0.01) if alpha is None else alpha)
    L = measured_factors(prob) if L is None else L
    zw = prob.whiten(np.asarray(f.resid, float), L)
    free = 1.0 - leverages(prob, f, L)
    tests = []
    for name, desc, m in _groups(prob):
        c2 = float(np.sum(zw[m] ** 2))
        dof = float(np.sum(free[m]))
        dof = max(dof, 0.5)
        tests.append({"name": name, **desc, "n_obs": int(m.sum()), "chi2": c2, "dof": dof,
                      "overdispersion": c2 / dof, "p": float(chi2_sf(c2, dof))})
    rej, adj = holm([t["p"] for t in tests], alpha)
    for t, r, a in zip(tests, rej, adj):
        t["p_holm"] = float(a)
        t["rejected"] = bool(r)
    return {"adequate": not any(rej), "alpha": alpha, "tests": tests,
            "method": "chi-square per subset of the whitened residuals, Holm step-down over the family"}


def _shape(t, r, w):
    """Best generic shape in time of residuals ``r`` (weights ``w`` = 1/sigma^2) at times ``t``: name, fraction of
    the weighted sum of squares it explains, and its amplitude (output unit)."""
    if r.size < 4:
        return {"shape": "too few observations", "explained_fraction": 0.0}
    tt = (t - t.mean()) / max(np.ptp(t), 1e-9)
    ss0 = float(np.sum(w * r**2))
    cands = {"offset": np.ones((r.size, 1)), "linear trend in time": np.column_stack([np.ones(r.size), tt]),
             "quadratic in time": np.column_stack([np.ones(r.size), tt, tt**2])}
    span = float(np.ptp(t))
    if r.size >= 8 and span > 0:
        for period in span / np.array([0.75, 1.0, 1.5, 2, 3, 4, 6, 8]):
            ph = 2 * math.pi * (t - t.min()) / period
            cands[f"sinusoid, period {period:.4g} s"] = np.column_stack([np.ones(r.size), np.cos(ph), np.sin(ph)])
    best = None
    sw = np.sqrt(w)
    for name, X in cands.items():
        coef, *_ = np.linalg.lstsq(X * sw[:, None], r * sw, rcond=None)
        ss = float(np.sum(w * (r - X @ coef) ** 2))
        # penalise parameters as BIC does, so an offset is preferred over a sinusoid that fits no better
        score = ss + X.shape[1] * math.log(r.size) * ss0 / max(r.size, 1)
        if best is None or score < best[0]:
            amp = float(np.hypot(coef[1], coef[2])) if name.startswith("sinusoid") else float(
                np.ptp(X @ coef)) if X.shape[1] > 1 else float(abs(coef[0]))
            best = (score, name, 1.0 - ss / ss0 if ss0 > 0 else 0.0, amp)
    return {"shape": best[1], "explained_fraction": best[2], "amplitude": best[3]}


def unexplained_entries(prob: Problem, f: Fit, adq: dict) -> list[dict]:
    """Where the misfit of ``f`` sits, one entry per rejected subset test (not the global one): scope, size (RMS
    residual and its excess over the measured noise, output unit), and the generic shape in time that fits it."""
    g, o = prob.geom, prob.geom.obs
    L = measured_factors(prob)
    sig = np.empty(prob.n)
    for key, idx in o["blocks"].items():
        sig[idx] = np.sqrt(np.einsum("ij,ij->i", L[key], L[key]))
    t = np.array([g.time_s[g.windows[w].i0] + 0.5 * g.windows[w].n * g.dt for w in o["window"]])
    groups = subset_masks(prob)
    out = []
    for test in adq["tests"]:
        if not test["rejected"] or test["name"] == "all":
            continue
        m = groups[test["name"]]
        r = np.asarray(f.resid, float)[m]
        unit = g.units_out.get(test.get("sensor", ""), "") if isinstance(g.units_out, dict) else ""
        if prob.kind == "norm":
            unit = "(m s-2)^2"
        rms = float(np.sqrt(np.mean(r**2)))
        noise = float(np.sqrt(np.mean(sig[m] ** 2)))
        ent = {k: test[k] for k in ("name", "scope", "sensor", "axis", "class", "part") if k in test}
        ent.update({"chi2": test["chi2"], "dof": test["dof"], "p_holm": test["p_holm"],
                    "rms_residual": rms, "rms_noise": noise,
                    "excess_rms": float(math.sqrt(max(rms**2 - noise**2, 0.0))), "unit": unit})
        ent.update(_shape(t[m], r, 1.0 / np.maximum(sig[m], 1e-300) ** 2))
        out.append(ent)
    return out
