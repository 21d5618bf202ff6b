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

The measured noise still holds a slow part between the segments that the session's static samples (taus up to one
segment) do not measure: the long static record's, or the session's within-segment random walk extended across the
session. :func:`slow_noise_assumption` runs the same family on the noise measured within the segments alone (white
noise and quantisation) and, where a fit passes only with that slow part, finds the smallest bias instability it
needs and the length of a static record that decides; the verdict stands only where the record resolves a slow
noise (:mod:`calib.diagnosis.analysis`).

Where a test fails, :func:`unexplained_entries` says where the rest sits (sensor, axis, segment class, part of
the session), how large it is in the sensor's output unit, and which generic shape in time fits it best
(offset, linear or quadratic trend, a sinusoid of the best period on a grid): the open search of the residuals
that a library term is judged against.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from calib.core.distributions import chi2_ppf, chi2_sf
from calib.diagnosis.geometry import AXES, SENSORS, TO_MODEL
from calib.diagnosis.noise import record_minutes, record_point_models, within_segment_blocks
from calib.diagnosis.problem import Fit, Problem, base_estimates
from calib.signal import allan, noisecov


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
    """(name, description dict, boolean mask) of every subset tested (computed once per problem: they depend on
    its observations only, and the adequacy family runs many times on one problem)."""
    cached = prob.__dict__.get("_adequacy_groups")
    if cached is None:
        cached = prob.__dict__["_adequacy_groups"] = _subsets(prob)
    return cached


def _subsets(prob: Problem):
    """:func:`_groups`, computed."""
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


def _temporary_adequacy(prob: Problem, f: Fit, L: dict) -> dict:
    """:func:`adequacy` of ``f`` on the factors ``L`` of a trial noise, without keeping their padded copy in the
    problem's whitening cache (the trials of :func:`slow_level_needed` are many and used once)."""
    try:
        return adequacy(prob, f, L=L)
    finally:
        prob.__dict__.get("_wc", {}).pop(("Lpad", id(L)), None)


def slow_level_needed(prob: Problem, f: Fit, L_assumed: dict, C_within: dict, sensor: str, iters: int = 24) -> float:
    """The smallest fraction ``m`` in [0, 1] of the between-segment slow noise of ``sensor`` (the difference of the
    assumed covariance ``L_assumed L_assumed^T`` and the within-segment one ``C_within``, on its three axis blocks
    together; the other sensor at the assumed noise) at which the adequacy family of ``f`` passes: the covariance
    ``C_within + m (C_assumed - C_within)`` (a convex combination of two covariances: one for every m). Bisection
    to 2^-iters; 0 when the within-segment noise of ``sensor`` alone passes, 1 when only the whole assumed level
    does (nan when even that fails)."""
    si = SENSORS.index(sensor)
    keys = [k for k in prob.geom.obs["blocks"] if k[0] == si]
    Ca = {k: L_assumed[k] @ L_assumed[k].T for k in keys}

    def passes(m):
        L = dict(L_assumed)
        for k in keys:
            L[k] = np.linalg.cholesky(C_within[k] + m * (Ca[k] - C_within[k]))
        return _temporary_adequacy(prob, f, L)["adequate"]

    if passes(0.0):
        return 0.0
    if not passes(1.0):
        return float("nan")
    lo, hi = 0.0, 1.0
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if passes(mid) else (mid, hi)
    return hi


def slow_avar(tau, tc: float, sigma: float) -> np.ndarray:
    """Allan variance of the slow part ``(tc, sigma)`` of :class:`calib.diagnosis.noise.NoiseFit` (Tc = inf: a
    random walk, AVAR = K^2 tau / 3 with K = sigma; else a Gauss-Markov bias, :func:`noisecov.gm_avar`)."""
    tau = np.asarray(tau, float)
    if sigma <= 0:
        return np.zeros_like(tau)
    if math.isinf(tc):
        return sigma**2 * tau / 3.0
    return noisecov.gm_avar(tau, sigma, tc)


def record_minutes_needed(fs: float, taus, avar_fast, avar_slow) -> float:
    """Length [min] of a static record of the same unit whose Allan deviation tells a slow noise of Allan variance
    ``avar_slow`` (on the taus ``taus`` [s] that separate the segments of the session) from none: the shortest
    record in which, at one of those taus, the lower end of the 95 % Allan band of a unit with that slow noise lies
    above the Allan variance ``avar_fast`` of the noise without it. The band is the chi-square interval of the
    overlapping Allan variance with the equivalent degrees of freedom of :func:`calib.signal.allan.edf_white` (as
    the record's own Allan deviation is computed); the record reaches tau at half its length."""
    tau, af, asl = (np.asarray(v, float) for v in (taus, avar_fast, avar_slow))
    keep = asl > 0
    if not keep.any():
        return math.inf
    tau, af, asl = tau[keep], af[keep], asl[keep]
    need = af / (af + asl)              # lower band / true variance must exceed this
    m = np.maximum(tau * fs, 1.0)

    def shows(length_s, idx):           # every tau at once: the same numbers as one tau at a time
        edf = allan.edf_white(length_s * fs + 1.0, m[idx])
        return edf / chi2_ppf(0.975, edf) >= need[idx]

    every = np.arange(tau.size)
    lo = 2.0 * tau                       # the record reaches tau at half its length
    result = np.full(tau.size, math.inf)
    at_lo = shows(lo, every)
    result[at_lo] = lo[at_lo]
    hi = lo.copy()
    pending, bracketed = ~at_lo, np.zeros(tau.size, bool)
    while pending.any():                 # double until the record shows it (none beyond 1e8 s)
        hi[pending] *= 2.0
        pending &= ~(hi > 1e8)
        idx = np.flatnonzero(pending)
        hit = idx[shows(hi[idx], idx)]
        bracketed[hit] = True
        pending[hit] = False
    idx = np.flatnonzero(bracketed)
    a, b = lo[idx], hi[idx]
    for _ in range(40):                  # bisection between 2 tau and the first length that shows it
        mid = 0.5 * (a + b)
        ok = shows(mid, idx)
        a, b = np.where(ok, a, mid), np.where(ok, mid, b)
    result[idx] = b
    return float(result.min()) / 60.0


def segment_lags(prob: Problem) -> np.ndarray:
    """The taus [s] at which slow noise moves the window means against each other: log-spaced from the shortest
    window to the span of the session's windows (first start to last end)."""
    g = prob.geom
    t0 = np.array([g.time_s[w.i0] for w in g.windows])
    dur = np.array([w.n * g.dt for w in g.windows])
    span = float(np.max(t0 + dur) - np.min(t0))
    lo = float(max(np.min(dur), g.dt))
    return np.geomspace(lo, max(span, lo), 48)


def slow_noise_assumption(prob: Problem, f: Fit, adq: dict, *, L_assumed: dict, slow: dict, source: str,
                          source_kind: str, record=None, precise: bool = True) -> dict:
    """What an adequacy verdict of ``f`` assumes of the slow noise between the segments.

    ``adq`` is the family of :func:`adequacy` on the factors ``L_assumed`` (the noise the verdict used), whose
    slow part per sensor axis is ``slow[sensor][axis] = (Tc, sigma)`` (Tc = inf: a random walk of density sigma),
    taken from ``source`` (``source_kind``). The same family is run on the noise the session measures within its
    segments alone (:func:`calib.diagnosis.noise.within_segment_blocks`). When that family fails and ``adq``
    passes, the verdict rests on the slow level: per sensor that needs it, the smallest fraction of its assumed
    between-segment variance with which the family passes (:func:`slow_level_needed`) gives the minimum bias
    instability X per axis (sigma or K times its square root), and :func:`record_minutes_needed` the length of a
    static record that tells X from none on the taus of the segment layout (:func:`segment_lags`).

    With a long static record (``record``; the tests use the upper end of its 95 % Allan band), the level is
    *measured* on an axis when the record resolves a slow noise there (the fit to its Allan point estimate keeps one
    by BIC, :func:`calib.diagnosis.noise.record_point_models`): the band is then an interval of a measured quantity.
    Otherwise the verdict rests on an assumed level (``rests_on_assumed_level``): the upper end of a band the record
    cannot close, or, without a record, the session's own
    within-segment random walk extended between the segments.

    ``precise`` false (``report_detail: false``: runs scored on their verdict alone, as the proof's seeds): whether
    a sensor needs a level in (0, 1] of its assumed one is decided as always (the family at the two ends), but the
    bisection for the smallest such level, and the record length that follows from it, are left out; the entries
    say so (``None`` and ``not_computed``). The verdict and ``rests_on_*`` are the same either way."""
    g = prob.geom
    out = {"source": source, "source_kind": source_kind, "record": str(record) if record else None,
           "record_minutes": record_minutes(record) if record else None,
           "levels": [], "rests_on_slow_level": False, "rests_on_assumed_level": False,
           "record_minutes_needed": None, "statement": ""}
    if prob.kind != "vector" or prob.noise is None:
        out["within_segment"] = None
        out["note"] = "the norm model's noise holds no slow part between segments: nothing assumed"
        return out
    Cw, Lw = within_segment_blocks(g, prob.noise)
    aw = adequacy(prob, f, L=Lw)
    out["within_segment"] = {"adequate": aw["adequate"], "alpha": aw["alpha"], "method": (
        "the same family on the noise measured within the segments alone (white noise and quantisation of the "
        "static segments' Allan deviation, its rate random walk within each window; no slow noise between the "
        "segments)"), "tests": [{k: t[k] for k in ("name", "chi2", "dof", "p", "p_holm", "rejected")}
                               for t in aw["tests"]]}
    if aw["adequate"] or not adq["adequate"]:
        return out
    out["rests_on_slow_level"] = True
    rejected = {(t["sensor"], t["axis"]) for t in aw["tests"] if t["rejected"] and t["scope"] == "sensor_axis"}
    involved = [s for s in SENSORS if any(t["rejected"] and (t.get("sensor") in (s, None)) for t in aw["tests"])]
    taus = segment_lags(prob)
    M = base_estimates(f.theta)[0]
    for s in involved:
        m = slow_level_needed(prob, f, L_assumed, Cw, s, iters=24 if precise else 0)
        if not m > 0:
            continue
        axes = [a for a in range(3) if (s, AXES[a]) in rejected] or list(range(3))
        for a in axes:
            tc, sig = slow[s][a]
            if not sig > 0:
                continue
            detected = None
            if record:      # a slow part the record's own Allan deviation resolves (BIC), not only one it allows
                pm = record_point_models(record)[s]
                detected = bool(pm.fit and pm.fit[a].get("slow_detected_bic", False) and pm.slow[a] != "none")
            unit = g.units_out[s]
            if not precise:
                out["levels"].append({"sensor": s, "axis": AXES[a], "unit": unit,
                                      "fraction_of_assumed_variance_needed": None, "minimum_for_adequacy": None,
                                      "record_minutes_needed": None, "record_resolves_it": detected,
                                      "not_computed": "report_detail false: the smallest level is not searched"})
                continue
            x = math.sqrt(m) * sig
            af = 3.0 * prob.noise.Q_shape[s][a] ** 2 / taus**2 + prob.noise.N_shape[s][a] ** 2 / taus
            need_min = float(record_minutes_needed(g.fs, taus, af, slow_avar(taus, tc, x)))
            ent = {"sensor": s, "axis": AXES[a], "unit": unit,
                   "assumed": ({"kind": "random walk", "K": sig, "unit": f"{unit} s^-1/2"} if math.isinf(tc) else
                               {"kind": "Gauss-Markov bias", "sigma": sig, "tc_s": tc, "unit": unit}),
                   "fraction_of_assumed_variance_needed": m,
                   "minimum_for_adequacy": x, "minimum_unit": f"{unit} s^-1/2" if math.isinf(tc) else unit,
                   "record_minutes_needed": need_min if math.isfinite(need_min) else None,
                   "record_resolves_it": detected}
            if M[s][a, a] != 0:       # in the input unit: over the scale factor (K E)_aa
                ent["minimum_for_adequacy_input_unit"] = x / abs(M[s][a, a]) / TO_MODEL[g.units_in[s]]
                ent["input_unit"] = g.units_in[s] + (" s^-1/2" if math.isinf(tc) else "")
            out["levels"].append(ent)
    out["rests_on_assumed_level"] = (not all(e["record_resolves_it"] for e in out["levels"])
                                     if out["levels"] else record is None)
    fails = "; ".join(f"{t['name']} chi2 {t['chi2']:.4g} on {t['dof']:.3g} (p Holm {t['p_holm']:.2g})"
                      for t in aw["tests"] if t["rejected"])

    def levels(es):
        if not precise:
            return "; ".join(f"{e['sensor']} {e['axis']}: a level above zero (its size not searched, "
                             "report_detail false)" for e in es)
        return "; ".join(
            f"{e['sensor']} {e['axis']} >= {e['minimum_for_adequacy']:.3g} {e['minimum_unit']}"
            + (f" ({e['minimum_for_adequacy_input_unit']:.3g} {e['input_unit']})" if "input_unit" in e else "")
            + f" (assumed {e['assumed'].get('sigma', e['assumed'].get('K')):.3g}"
            + (f", Tc {e['assumed']['tc_s']:g} s" if "tc_s" in e["assumed"] else "") + ")" for e in es)

    assumed = [e for e in out["levels"] if not e["record_resolves_it"]]
    measured = [e for e in out["levels"] if e["record_resolves_it"]]
    need = max((e["record_minutes_needed"] for e in assumed if e["record_minutes_needed"] is not None),
               default=math.nan)
    out["record_minutes_needed"] = need if math.isfinite(need) else None
    rec_min = out["record_minutes"]
    decides = (f"a static record of the same unit of {math.ceil(need)} min decides (calib diagnose --noise-record)"
               if math.isfinite(need) else "a long static record of the same unit decides")
    if record:
        decides = (f"the static record {Path(record).name} ({rec_min:.3g} min) does not resolve a slow noise there (its "
                   "Allan deviation keeps none by BIC: the tests take the upper end of its 95 % band, which it cannot "
                   "exclude); "
                   + (decides if not rec_min >= need else
                      f"{math.ceil(need)} min of record suffice to show that level, so the misfit is more than the slow "
                      "noise the record measures unless the bias instability sits at the top of its band"))
    parts = [f"against the noise measured within the segments alone the fit is off ({fails})"]
    if assumed or not out["levels"]:
        parts.append(f"it passes only with a bias instability between the segments of at least "
                     f"{levels(assumed) or 'the assumed level'}, assumed from {source}; {decides}")
    if measured:
        parts.append(f"the bias instability it needs on {', '.join(e['sensor'] + ' ' + e['axis'] for e in measured)} "
                     f"(at least {levels(measured)}) is measured by the static record {Path(record).name} "
                     f"({rec_min:.3g} min): its Allan deviation resolves a slow noise there")
    out["statement"] = "; ".join(parts)
    return out


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
