"""Forward stepwise selection of candidate terms (module doc of :mod:`calib.diagnosis`, step 3): the candidate
with the largest BIC gain is added while its gain exceeds ``min_delta_bic`` and its likelihood-ratio test has
p < ``alpha``; terms smooth in time are tested against a re-profiled noise."""
from __future__ import annotations

import math

import numpy as np

from calib.core.distributions import chi2_sf
from calib.diagnosis.fitting import columns, fit
from calib.diagnosis.geometry import SENSORS
from calib.diagnosis.noise import covariance_blocks, profile_noise, reml_slow
from calib.diagnosis.problem import Fit, Problem
from calib.diagnosis.vector import reml_design

def testable_keys(prob: Problem):
    """Candidates with at least one determined parameter."""
    return [c.key for c in prob.lib if not c.untestable and c.active.size > 0]


def is_slow(c) -> bool:
    """Terms smooth in time (bias drift, temperature sensitivity): tested against a re-estimated noise."""
    return c.kind == "drift" or c.effect == "temperature_sensitivity"


def _design_blocks(prob: Problem, key):
    c = prob.cand(key)
    si = SENSORS.index(c.sensor)
    return [(si, a) for a in range(3)]


def _slow_statistic(prob: Problem, cur: Fit, key, memo: dict | None = None):
    """-2 log likelihood-ratio of adding the slow term ``key`` with the noise of its sensor's blocks
    re-profiled (full ML: level, bias-instability sigma and Tc) under both designs; the drift time constant
    profiled over a coarse grid. Returns (statistic, extra parameters, tau or None). ``memo``: a dict kept for
    one fit ``cur`` (one step of the selection) that holds the profile of ``cur``'s own design per sensor, which
    every slow candidate of that sensor shares."""
    c = prob.cand(key)
    blocks = _design_blocks(prob, key)
    Xc = cur.X
    y = prob.y

    def nll(X):
        r = profile_noise(prob.geom, prob.noise, y, X, prob.parts, prob.cache, blocks=blocks, method="ml",
                             update=False)
        return sum(v[0] for v in r.values())

    memo = {} if memo is None else memo
    if tuple(blocks) not in memo:
        memo[tuple(blocks)] = nll(Xc)
    n0 = memo[tuple(blocks)]
    best = (np.inf, None)
    taus = (300.0, 900.0, 2700.0) if c.kind == "drift" else (None,)
    for tau in taus:
        S = columns(prob, key, {key: tau} if tau else {})
        v = nll(np.hstack([Xc, S]))
        if v < best[0]:
            best = (v, tau)
    k = int(c.active.size) + (1 if c.kind == "drift" else 0)
    return n0 - best[0], k, best[1]


def renoise(prob: Problem, terms, taus=None, delta=0.0):
    """Re-estimate the noise (REML) with ``terms`` added to the fixed effects and reset the whitening."""
    extra = []
    for k in terms:
        c = prob.cand(k)
        if c.kind == "offset":
            continue
        if is_slow(c):
            extra.append(columns(prob, k, taus or {}))
    X = np.hstack([reml_design(prob)] + extra)
    reml_slow(prob.geom, prob.noise, prob.y, X, prob.parts, prob.cache)
    _, prob.L = covariance_blocks(prob.geom, prob.noise, prob.parts, prob.cache)
    prob.forget_whitened()


#: the largest magnitude of each library parameter that physics allows in any inertial sensor a user calibrates
#: here (MEMS to navigation grade), in the registry's units: a fit beyond it is a degenerate explanation (a free
#: term trading against the base parameters), never a finding. |delta g|: the geodetic normal-gravity formula and
#: local anomalies keep a site's g within 0.05 m s-2 of the value a user takes for it.
PHYSICAL_LIMITS = {
    "delta_g_m_s2": 0.05, "delta_lat_deg": 1.0, "offset_s": 1.0,
    "k2_ug_per_g2": 1e5, "k3_ug_per_g3": 1e5, "k_cross_ug_per_g2": 1e5,
    "asym_ppm": 5e4, "k_ppm_per_deg_s": 1e4, "lever_arms_m": 0.5, "G_deg_h_per_g": 3600.0,
    "accel_bias_ug_per_degC": 2e3, "accel_scale_ppm_per_degC": 2e3, "gyro_bias_deg_h_per_degC": 360.0,
    "gyro_scale_ppm_per_degC": 2e3, "accel_warmup_ug": 1e5, "gyro_warmup_deg_h": 3600.0,
    "accel_trend_ug_per_h": 1e5, "gyro_trend_deg_h_per_h": 3600.0,
}
#: a fit whose chi-square falls below this fraction of its degrees of freedom fits the noise away
CHI2_COLLAPSE = 0.01


def degenerate(prob: Problem, f: Fit, key) -> str:
    """Why the fit ``f`` with candidate ``key`` is a degenerate explanation ('' when it is not): a parameter
    beyond :data:`PHYSICAL_LIMITS`, a chi-square collapsing below :data:`CHI2_COLLAPSE` of its degrees of freedom,
    or a candidate the fit could not determine (rank deficient). The decision does not depend on the size of the
    misfit the candidate removes."""
    c = prob.cand(key)
    if f.chi2 < CHI2_COLLAPSE * max(f.dof, 1):
        return f"chi-square collapses to {f.chi2:.3g} on {f.dof} degrees of freedom (the term fits the noise away)"
    sl = f.slices.get(key)
    if sl is None:
        return ""
    vals = f.theta[sl]
    se = np.sqrt(np.clip(np.diag(f.cov)[sl], 0.0, None))
    idx = f.active.get(key, c.active) if key != "time_offset" else np.array([0])
    if c.kind != "offset" and len(idx) != len(vals):
        return "rank deficient: its parameters are not determined next to the base model"
    for j, v, e in zip(idx, vals, se):
        name = c.names[j]
        lim = PHYSICAL_LIMITS.get(name.split("[")[0])
        # beyond physical sense when its 99 % interval excludes every sensible value (a weakly determined
        # component whose estimate wanders past the limit within its error is not evidence of degeneracy)
        if lim is not None and abs(v) - 2.576 * e > lim:
            return (f"{name} = {v:.4g} +- {e:.2g} {c.units[j]} is beyond physical sense (|value| <= {lim:g}, "
                    "excluded by its 99 % interval)")
    return ""


def stepwise(prob: Problem, base: Fit | None = None):
    """Forward selection by BIC with a likelihood-ratio test. Returns (final fit, steps, candidate table of
    the last step). Terms smooth in time are tested with the noise re-profiled (:func:`_slow_statistic`);
    when one is selected the noise is re-estimated with it as a fixed effect."""
    st = prob.settings
    n = prob.n
    cur = base or fit(prob, [])
    steps = []
    keys = testable_keys(prob)
    last_table = []
    refused = prob.__dict__.setdefault("degenerate", {})
    for _ in range(st["max_steps"]):
        table = []
        memo = {}      # the noise profile of cur's design, shared by the slow candidates of this step
        for k in keys:
            if k in cur.terms or k in refused:
                continue
            c = prob.cand(k)
            if is_slow(c) and prob.kind == "vector":
                dchi, dk, tau = _slow_statistic(prob, cur, k, memo)
                f = None
            else:
                f = fit(prob, cur.terms + [k], taus=cur.taus,
                        delta_hint=cur.delta if "time_offset" in cur.terms else None)
                dchi = cur.chi2 - f.chi2
                dk = f.k - cur.k
                tau = None
                why = degenerate(prob, f, k)
                if why and dchi > 0:
                    refused[k] = why
                    continue
            if dk <= 0:
                continue
            dbic = dchi - dk * math.log(n)
            p = float(chi2_sf(max(dchi, 0.0), dk))
            table.append({"term": k, "delta_chi2": float(dchi), "delta_k": int(dk), "delta_bic": float(dbic),
                          "p_lrt": p, "fit": f, "tau": tau,
                          "statistic": "-2 ln LR, noise re-profiled" if is_slow(c) else "delta chi-square"})
        table.sort(key=lambda r: -r["delta_bic"])
        last_table = table
        ok = [r for r in table if r["delta_bic"] > st["min_delta_bic"] and r["p_lrt"] < st["alpha"]]
        if not ok:
            break
        best = ok[0]
        terms = cur.terms + [best["term"]]
        if best["fit"] is None:   # a slow term: re-estimate the noise with it, refit everything
            taus_new = {**cur.taus, best["term"]: best["tau"]} if best["tau"] else cur.taus
            trial = fit(prob, terms, taus=taus_new)
            why = degenerate(prob, trial, best["term"])
            if why:
                refused[best["term"]] = why
                continue
            renoise(prob, terms, taus_new)
            new = fit(prob, terms)
        else:
            new = best["fit"]
        steps.append({k: v for k, v in best.items() if k != "fit"} | {"chi2_after": new.chi2})
        cur = new
    return cur, steps, last_table
