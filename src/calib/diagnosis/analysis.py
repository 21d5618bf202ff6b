"""Name it and model it (module doc of :mod:`calib.diagnosis`, steps 3-5): selection, the refit with the found
terms, their estimates and intervals, aliases, tested-and-absent terms with upper bounds, untestable terms,
goodness of fit before and after, and the verdict."""
from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np

from calib.core.distributions import chi2_sf
from calib.diagnosis.adequacy import adequacy, measured_factors, slow_noise_assumption, unexplained_entries
from calib.diagnosis.blas import solve_lower
from calib.diagnosis.fitting import chi2_rank, fit
from calib.diagnosis.generic import form_alternatives, open_search
from calib.diagnosis.geometry import ROWS, SENSORS
from calib.diagnosis.term_identifiability import discrimination_noncentrality, library_geometry, separating_segments
from calib.diagnosis.library import EXPERIMENTS, build_library
from calib.diagnosis.locate import block_table, locate
from calib.diagnosis.noise import covariance_blocks, profile_noise, shape_eig, with_measured_slow
from calib.diagnosis.problem import Fit, Problem, base_estimates, lstsq
from calib.diagnosis.selection import is_slow, renoise, stepwise, testable_keys

def slow_se_marginal(prob: Problem, f: Fit, key) -> np.ndarray | None:
    """Standard errors of a sensor term marginalised over the slow noise of its sensor instead of conditioned
    on its point estimate (used for every found sensor term, and for the bounds of absent slow terms). The
    window means a term is learned from share the bias instability, whose level and correlation time rest
    on a few independent slow samples (for a slow term the two also trade off), so the GLS standard error at
    the estimated noise alone undercovers. Over the grid of the restricted likelihood of
    the final design (Tc x level, :func:`calib.diagnosis.noise.profile_noise`), with weights w ~ exp(-dnll/2)
    (points with dnll <= 9.21, i.e. weight >= 1 %), the law of total variance gives
    se^2 = E_w[se^2 | noise] + Var_w[estimate | noise] (the GLS fits of the grid points:
    :func:`_gls_over_slow_grid`). None when the model is not the vector model or the fit keeps no design."""
    c = prob.cand(key)
    if (prob.kind != "vector" or prob.noise is None or f.X is None or key not in f.slices
            or c.sensor not in SENSORS):     # site and clock terms: conditional standard errors
        return None
    s, si = c.sensor, SENSORS.index(c.sensor)
    grid = {}
    profile_noise(prob.geom, prob.noise, prob.y, f.X, prob.parts, prob.cache, blocks=[(si, a) for a in range(3)],
                     method="reml", update=False, grid_out=grid)
    pts = grid.get(s, [])
    if not pts:
        return None
    nmin = min(p[0] for p in pts)
    use = [p for p in pts if p[0] - nmin <= 9.21]
    th, var = _gls_over_slow_grid(prob, f.X, s, [(tc, rho, lam) for _, tc, rho, lam in use], f.slices[key])
    w = np.array([math.exp(-0.5 * (nll - nmin)) for nll, *_ in use])
    w = w / np.sum(w)
    mean = w @ th
    return np.sqrt(w @ var + w @ (th - mean) ** 2)


def _gls_over_slow_grid(prob: Problem, X, sensor: str, points, sl):
    """GLS estimates ``theta[sl]`` and variances ``diag(cov)[sl]`` of the design ``X`` at every noise point
    ``(tc, rho, lam)`` of ``sensor`` (its three axis blocks at covariance ``lam (C_fast + rho A_slow(tc))``, the
    other sensor at the problem's noise), as :func:`calib.diagnosis.problem.lstsq` of the whitened problem gives
    them.

    Nothing is refactorised per point: the sensor's blocks are whitened by the cached eigen-decomposition of
    their noise shape (:func:`calib.diagnosis.noise.shape_eig`: ``W = (lam (I + rho diag(lam_e)))^-1/2 V^T L0^-1``,
    a row scaling per point of ``V^T L0^-1 X``, computed once per Tc), the other sensor's rows (fixed) are
    reduced once to their triangular factor (``Xo = Qo Ro``: the stacked problem ``[W X_s; Ro]`` has the same
    normal equations and the same solution; the columns of the other sensor alone are eliminated in that
    factorisation), and the points of one Tc are solved together by a batched QR of
    the column-normalised stacked design. A point whose factor is close to rank deficient (where the rank cut of
    ``lstsq`` could act) is solved by ``lstsq`` itself."""
    geom, nz = prob.geom, prob.noise
    si = SENSORS.index(sensor)
    y = np.asarray(prob.y, float)
    _, L = covariance_blocks(geom, nz, prob.parts, prob.cache)    # the problem's noise for the other sensor
    other = [(k, idx) for k, idx in geom.obs["blocks"].items() if k[0] != si]
    mine = [(a, geom.obs["blocks"][(si, a)]) for a in range(3)]
    Xo = np.vstack([solve_lower(L[k], X[idx]) for k, idx in other])
    yo = np.concatenate([solve_lower(L[k], y[idx]) for k, idx in other])
    # columns that touch the sensor's rows (P) and those of the other sensor alone (O): O is eliminated once, in
    # the QR of the other sensor's rows ordered [O, P] (its R_PP rows carry all they say about P: theta_P and its
    # covariance are those of the full problem); kept in the grid problem when that factor is near singular
    P = np.flatnonzero(np.any(X[np.concatenate([idx for _, idx in mine])] != 0, axis=0))
    O = np.setdiff1d(np.arange(X.shape[1]), P)
    Qo, Ro = np.linalg.qr(Xo[:, np.concatenate([O, P])])
    dO = np.abs(np.diag(Ro)[:O.size])
    if (O.size and (Ro.shape[0] < Ro.shape[1] or not dO.min() > 1e-6 * np.linalg.norm(Xo[:, O], axis=0).max())) \
            or not np.all(np.isin(np.arange(sl.start, sl.stop), P)):
        P, O = np.arange(X.shape[1]), np.arange(0)
        Qo, Ro = np.linalg.qr(Xo)
    yo = (Qo.T @ yo)[O.size:]
    Ro = Ro[O.size:, O.size:]
    sl = np.searchsorted(P, np.arange(sl.start, sl.stop))
    th = np.empty((len(points), sl.size))
    var = np.empty_like(th)
    for tc in dict.fromkeys(p[0] for p in points):
        sel = [i for i, p in enumerate(points) if p[0] == tc]
        rho = np.array([points[i][1] for i in sel])
        lev = np.array([points[i][2] for i in sel])
        Zx, Zy, scale = [], [], []
        for a, idx in mine:
            L0, lam_e, V = shape_eig(geom, nz, prob.parts, sensor, a, tc, prob.cache)
            Zx.append(V.T @ solve_lower(L0, X[idx][:, P]))
            Zy.append(V.T @ solve_lower(L0, y[idx]))
            scale.append(1.0 / np.sqrt(lev[:, None] * (1.0 + rho[:, None] * lam_e[None, :])))
        scale = np.concatenate(scale, axis=1)                                  # (points, rows of the sensor)
        Zx, Zy = np.vstack(Zx), np.concatenate(Zy)
        ne = _normal_equations_at(scale, Zx, Zy, Ro, yo)
        if ne is not None:
            th_ne, var_ne, good = ne
            for j in np.flatnonzero(good):
                th[sel[j]], var[sel[j]] = th_ne[j, sl], var_ne[j, sl]
            if good.all():
                continue
            sel = [sel[j] for j in np.flatnonzero(~good)]
            scale = scale[~good]
        A = np.concatenate([scale[:, :, None] * Zx[None],
                            np.broadcast_to(Ro, (len(sel),) + Ro.shape)], axis=1)
        b = np.concatenate([scale * Zy[None], np.broadcast_to(yo, (len(sel), yo.size))], axis=1)
        nrm = np.linalg.norm(A, axis=1)
        k = A.shape[2]
        # R of [A / |A|, b]: its last column holds Q^T b (Householder applied to b; Q is never formed)
        Rb = np.linalg.qr(np.concatenate([A / np.where(nrm > 0, nrm, 1.0)[:, None, :], b[:, :, None]], axis=2),
                          mode="r")
        R, z = Rb[:, :k, :k], Rb[:, :k, k]
        d = np.abs(np.diagonal(R, axis1=1, axis2=2))
        ok = d.min(axis=1) > 1e-6 * d.max(axis=1)
        Ri = np.linalg.inv(R[ok])
        th_ok = np.einsum("gkj,gj->gk", Ri, z[ok]) / nrm[ok]
        var_ok = np.sum(Ri**2, axis=2) / nrm[ok] ** 2
        for j, i in enumerate(np.asarray(sel)[ok]):
            th[i], var[i] = th_ok[j, sl], var_ok[j, sl]
        for g in np.flatnonzero(~ok):
            theta, cov, _ = lstsq(A[g], b[g])
            th[sel[g]], var[sel[g]] = theta[sl], np.diag(cov)[sl]
    return th, np.clip(var, 0.0, None)


#: the largest Frobenius condition number of a column-normalised grid problem solved by its normal equations
#: (their rounding error is about its square times the machine epsilon: <= 1e-8 relative; a point above it is
#: solved by the QR of the stacked design, as before)
NE_COND_MAX = 1e4


def _normal_equations_at(scale, Zx, Zy, Ro, yo):
    """Estimates and variances of every grid point of one Tc from the normal equations of the stacked problem
    ``[scale_p * Zx; Ro] theta = [scale_p * Zy; yo]`` (columns normalised, Cholesky), which a row scaling leaves
    the same except for ``Zx^T diag(scale_p^2) Zx``: one batched product instead of a QR of each stacked design.
    Returns ``(theta, var, good)`` with ``good`` the points whose normalised problem is well enough conditioned
    (:data:`NE_COND_MAX`) for the normal equations to agree with the QR to 1e-8 (with one step of iterative
    refinement); None when a Cholesky fails."""
    s2 = scale**2                                                             # (points, rows)
    N = (Zx.T[None, :, :] * s2[:, None, :]) @ Zx + (Ro.T @ Ro)[None]          # (points, k, k)
    c = (s2 * Zy[None]) @ Zx + (Ro.T @ yo)[None]                              # (points, k)
    d = np.sqrt(np.diagonal(N, axis1=1, axis2=2))
    if not np.all(d > 0):
        return None
    try:
        Lc = np.linalg.cholesky(N / (d[:, :, None] * d[:, None, :]))
    except np.linalg.LinAlgError:
        return None
    Li = np.linalg.inv(Lc)
    cond = np.sqrt(np.sum(Lc**2, axis=(1, 2)) * np.sum(Li**2, axis=(1, 2)))
    good = np.isfinite(cond) & (cond <= NE_COND_MAX)

    def solve(rhs):                                                           # D^-1 L^-T L^-1 D^-1 rhs
        return np.einsum("gji,gj->gi", Li, np.einsum("gij,gj->gi", Li, rhs / d)) / d

    theta = solve(c)
    # one step of iterative refinement on the residuals of the stacked problem: the observations are ~1e6 times
    # their residual, and the normal equations' rounding scales with the size of what they solve for
    theta += solve((s2 * (Zy[None] - theta @ Zx.T)) @ Zx + (yo[None] - theta @ Ro.T) @ Ro)
    var = np.sum(Li**2, axis=1) / d**2                                        # diag(D^-1 (L L^T)^-1 D^-1)
    return theta, var, good


def param_entries(prob: Problem, f: Fit, key, marginal: bool | None = None):
    """Value, standard error and 95 % interval of every determined parameter of ``key`` in the fit ``f``.
    ``marginal`` (default: for terms smooth in time): standard errors marginalised over the slow-noise
    parameters (:func:`slow_se_marginal`) instead of conditioned on their estimate."""
    c = prob.cand(key)
    sl = f.slices[key]
    se = np.sqrt(np.clip(np.diag(f.cov)[sl], 0.0, None))
    how = "normal, GLS standard error"
    if is_slow(c) if marginal is None else marginal:
        marg = slow_se_marginal(prob, f, key)
        if marg is not None:
            se = marg
            how = "normal, standard error marginalised over the slow noise (Tc, level; likelihood weights)"
    vals = f.theta[sl]
    idx = f.active.get(key, c.active) if key != "time_offset" else np.array([0])
    out = []
    for j, v, s in zip(idx, vals, se):
        ent = {"name": c.names[j], "value": float(v), "ci95": [float(v - 1.96 * s), float(v + 1.96 * s)],
               "se": float(s), "unit": c.units[j], "axis": c.axes[j], "interval": how}
        out.append(standard_entry(c.effect, ent))
    return out


#: the library's asymmetry terms and the standard their reported figure follows. The term d |y| scales the input
#: by K(1 + d) above zero and K(1 - d) below, so the field's scale factor asymmetry (K+ - K-) / Kbar (IEEE Std 528,
#: 1293, 952) is 2 d: the reported figure is the standard one, the internal d is kept labelled as such
STANDARD_ASYMMETRY = {"accel_scale_asymmetry": "IEEE Std 1293 (accelerometers)",
                      "gyro_scale_asymmetry": "IEEE Std 528 / 952 (gyros)"}
#: the standard name of the asymmetry figure and its value per unit of the internal parameter
ASYMMETRY_NAME, ASYMMETRY_FACTOR = "scale_factor_asymmetry_ppm", 2.0
ASYMMETRY_DEFINITION = ("(K+ - K-) / Kbar, K+ and K- the scale factors for positive and negative inputs, Kbar their "
                        "mean")
INTERNAL_ASYMMETRY = ("the library's model parameter d of the term d |y| (scale K(1 + d) for y > 0, K(1 - d) below): "
                      "half the standard scale factor asymmetry")


def standard_entry(effect: str, ent: dict) -> dict:
    """The reported entry of one parameter: for the asymmetry terms the standard scale factor asymmetry
    (:data:`STANDARD_ASYMMETRY`: name ``scale_factor_asymmetry_ppm[axis]``, value, interval and standard error
    2 x the internal ``asym_ppm``), with the internal parameter kept under ``internal_model_parameter``; any other
    parameter as it is."""
    if effect not in STANDARD_ASYMMETRY:
        return ent
    k = ASYMMETRY_FACTOR
    out = {"name": f"{ASYMMETRY_NAME}[{ent['axis']}]" if ent.get("axis") else ASYMMETRY_NAME,
           "value": k * ent["value"], "ci95": [k * ent["ci95"][0], k * ent["ci95"][1]], "se": k * ent["se"],
           "unit": "ppm", "axis": ent.get("axis"), "interval": ent.get("interval"),
           "quantity": "scale factor asymmetry", "standard": STANDARD_ASYMMETRY[effect],
           "definition": ASYMMETRY_DEFINITION,
           "internal_model_parameter": {**ent, "meaning": INTERNAL_ASYMMETRY}}
    return out


def _aliases(prob: Problem, final: Fit, key, geometry_angles):
    """Candidates that fit as well as the found term ``key`` in its place: BIC within ``alias_delta_bic`` of
    the final model (what this realisation of the noise shows), visible signatures closer than
    ``alias_angle_deg`` (geometry), or a discrimination non-centrality below ``alias_noncentrality`` (what
    the path can tell apart at the estimated magnitude, whatever this noise realisation did)."""
    st = prob.settings
    n = prob.n
    others = [k for k in testable_keys(prob) if k not in final.terms]
    rest = [t for t in final.terms if t != key]
    out = []
    for b in others:
        try:
            if "time_offset" in rest + [b]:
                fb = fit(prob, rest + [b], taus=final.taus,
                         delta_hint=final.delta if "time_offset" in final.terms else None)
                chi2_b, k_b = fb.chi2, fb.k
            else:     # only the chi-square and the parameter count enter the comparison
                chi2_b, k_b = chi2_rank(prob, rest + [b], final.taus)
            lam = discrimination_noncentrality(prob, final, key, b) if final.X is not None else math.inf
        except (np.linalg.LinAlgError, ValueError):
            continue
        dbic = (chi2_b - final.chi2) + (k_b - final.k) * math.log(n)
        ang = geometry_angles.get(frozenset((key, b)), float("nan"))
        if (dbic < st["alias_delta_bic"] or (np.isfinite(ang) and ang < st["alias_angle_deg"])
                or lam < st["alias_noncentrality"]):
            c = prob.cand(b)
            out.append({"effect": c.effect, "sensor": c.sensor, "key": b, "delta_bic_vs_found": float(dbic),
                        "signature_angle_deg": None if not np.isfinite(ang) else float(ang),
                        "discrimination_noncentrality": float(lam)})
    out.sort(key=lambda d: d["delta_bic_vs_found"])
    return out


def _absent(prob: Problem, final: Fit, table):
    tab = {r["term"]: r for r in table}
    out = []
    for k in testable_keys(prob):
        if k in final.terms:
            continue
        c = prob.cand(k)
        try:
            fk = fit(prob, final.terms + [k], taus={**final.taus, k: 900.0} if c.kind == "drift" else final.taus,
                     delta_hint=final.delta if "time_offset" in final.terms else None)
        except (np.linalg.LinAlgError, ValueError):
            continue
        pars = param_entries(prob, fk, k)
        bounds = [{"name": p["name"], "upper_bound_abs": max(abs(p["ci95"][0]), abs(p["ci95"][1])), "value": p["value"],
                   "se": p["se"], "unit": p["unit"],
                   **({k: p[k] for k in ("standard", "definition", "internal_model_parameter") if k in p})}
                  for p in pars]
        undet = [c.names[j] for j in range(c.p) if j not in set(c.active.tolist())]
        r = tab.get(k, {})
        out.append({"effect": c.effect, "sensor": c.sensor, "key": k, "upper_bound_95": bounds,
                    "undetermined_parameters": undet, "delta_bic": r.get("delta_bic"), "p_lrt": r.get("p_lrt"),
                    "note": "bound conditional on tau = 900 s" if c.kind == "drift" else ""})
    return out


def _untestable(prob: Problem):
    thr = prob.settings["absorbed_untestable"]
    out = []
    for c in prob.lib:
        if c.untestable:
            out.append({"effect": c.effect, "sensor": c.sensor, "key": c.key, "why": c.untestable,
                        "experiment": c.experiment})
        elif c.active.size == 0:
            if c.effect in EXPERIMENTS:
                why, exp = EXPERIMENTS[c.effect]
            else:
                why, exp = "", ""
            absorbed = float(np.max(c.absorbed)) if c.absorbed.size else 1.0
            why = (why + "; " if why else "") + (
                f"the base parameters absorb {100 * absorbed:.4g} % of its signature" if absorbed > thr else
                "its signature is too weak on this path: the 1-sigma error of every parameter exceeds the effect's "
                "typical magnitude")
            if not exp:
                exp = "add segments that excite it (see the signature table) or repeat the session to average noise"
            out.append({"effect": c.effect, "sensor": c.sensor, "key": c.key, "why": why, "experiment": exp,
                        "absorbed_fraction": absorbed})
    return out


def refine_signatures(prob: Problem, final: Fit) -> Fit:
    """One Gauss-Newton step on the signatures of the found terms: they were computed at the base model's
    K E, which a large missing term biases (the base fit absorbs part of it); rebuild them at the K E of the
    final fit and refit. The library becomes a new list (a library shared between problems is not changed).
    The clock offset's design already uses the current K E."""
    keys = {k for k in final.terms if prob.cand(k).kind != "offset"}
    if not keys or prob.kind != "vector":
        return final
    M, b = base_estimates(final.theta)
    fresh = {c.key: c for c in build_library(prob.geom, M, b, only=keys)}
    lib = []
    for c in prob.lib:
        if c.key in fresh:
            c = copy.copy(c)
            c.S, c.S_by_tau = fresh[c.key].S, fresh[c.key].S_by_tau
        lib.append(c)
    prob.lib = lib
    prob.forget_whitened()
    return fit(prob, final.terms, taus=final.taus, delta_hint=final.delta if "time_offset" in final.terms else None)


def _chi2_measured(prob: Problem, f: Fit):
    """chi-square and rank of the GLS refit of ``f``'s design on the measured noise (:mod:`adequacy`)."""
    Lm = measured_factors(prob)
    A = prob.whiten(f.X, Lm)
    yw = prob.whiten(np.asarray(prob.y, float), Lm)
    theta, _, rank = lstsq(A, yw)
    r = yw - A @ theta
    return float(r @ r), int(rank)


def confirm_on_measured_noise(prob: Problem, final: Fit):
    """The search selects terms on the noise it estimates from the window means; a term is kept only when its
    likelihood-ratio test on the *measured* noise passes too (p < ``alpha``). The least significant unconfirmed
    term is dropped and the rest refitted, until every kept term is confirmed. Returns the fit and the dropped
    terms with their p-values."""
    alpha = float(prob.settings.get("alpha", 0.001))
    dropped = []
    while final.terms and final.X is not None:
        c2, r1 = _chi2_measured(prob, final)
        worst = None
        for k in final.terms:
            rest = [t for t in final.terms if t != k]
            f0 = fit(prob, rest, taus={t: v for t, v in final.taus.items() if t in rest},
                     delta_hint=final.delta if "time_offset" in rest else None)
            c0, r0 = _chi2_measured(prob, f0)
            dfree = max(r1 - r0, 1) + (1 if prob.cand(k).kind in ("drift", "offset") else 0)
            p = float(chi2_sf(max(c0 - c2, 0.0), dfree))
            if p >= alpha and (worst is None or p > worst[1]):
                worst = (k, p)
        if worst is None:
            break
        dropped.append({"key": worst[0], "p_measured_noise": worst[1],
                        "why": "selected on the noise estimated from the window means, not significant on the "
                               "measured noise"})
        rest = [t for t in final.terms if t != worst[0]]
        final = fit(prob, rest, taus={t: v for t, v in final.taus.items() if t in rest},
                    delta_hint=final.delta if "time_offset" in rest else None) if rest else fit(prob, [])
    return final, dropped


def _slow_basis(prob: Problem, estimated: bool = False) -> dict:
    """The slow part per sensor axis of the noise an adequacy verdict used, where it comes from and what kind of
    source that is (:func:`calib.diagnosis.adequacy.slow_noise_assumption`): the level estimated from the window
    means (``estimated``), the long static record of the ``noise_record`` setting (the upper end of its 95 % Allan
    band), or else the rate random walk of the session's own within-segment Allan deviation extended between the
    segments (the default of :func:`calib.diagnosis.vector.setup_problem`)."""
    nz, rec = prob.noise, prob.settings.get("noise_record")
    if nz is None:       # the norm model: no slow part between the segments in its noise
        return {"slow": {}, "source_kind": "none", "source": prob.noise_basis}
    if estimated:
        return {"slow": nz.slow, "source_kind": "estimated from the window means",
                "source": "restricted maximum likelihood from the window means: " + "; ".join(
                    f"{s} {'xyz'[a]}: {nz.describe(s, a)}" for s in SENSORS for a in range(3))}
    if rec:
        name = Path(rec).name
        return {"slow": with_measured_slow(nz, prob.geom, rec).slow, "record": rec,
                "source_kind": "measured static record",
                "source": f"the long static record {name} (upper end of its 95 % Allan band)"}
    return {"slow": {s: [(math.inf, float(nz.K_allan[s][a])) for a in range(3)] for s in SENSORS},
            "source_kind": "default: the session's within-segment Allan random walk extended between the segments",
            "source": ("the rate random walk fitted to the Allan deviation of the session's static segments, extended "
                       "between the segments (not measured there)")}


def analyse(prob: Problem) -> dict:
    """Steps 1-5 on a set-up problem; returns the report content (without file paths)."""
    st = prob.settings
    base0 = fit(prob, [])
    final, steps, table = stepwise(prob, base0)
    # noise re-estimated with the selected terms as fixed effects, then everything refitted under it
    if final.terms and prob.kind == "vector":
        renoise(prob, final.terms, final.taus, final.delta)
    base = fit(prob, [])
    final = fit(prob, final.terms, taus=final.taus,
                delta_hint=final.delta if "time_offset" in final.terms else None) if final.terms else base
    final = refine_signatures(prob, final)
    final, unconfirmed = confirm_on_measured_noise(prob, final)
    # report_detail false (the proof's per-seed runs, which score the verdict and the findings only): the angles the
    # aliases of the found terms read, no absorbed fractions, separations or location of the misfit
    detail = st.get("report_detail", True)
    info, angles = library_geometry(prob, pairs_with=None if detail else set(final.terms))
    ang_map = {frozenset((a, b)): v for a, b, v in angles}
    groups = []
    for a, b, v in angles:
        if np.isfinite(v) and v < st["alias_angle_deg"]:
            groups.append({"members": [a, b], "angle_deg": v})
    found = []
    step_info = {s["term"]: s for s in steps}
    for k in final.terms:
        c = prob.cand(k)
        # a found term's intervals do not condition on the estimated slow noise: the window means it is
        # learned from share the bias instability, whose level and Tc rest on few independent samples
        pars = param_entries(prob, final, k, marginal=True)
        ent = {"effect": c.effect, "sensor": c.sensor, "key": k,
               "axes": sorted({p["axis"] for p in pars if p["axis"] and abs(p["value"]) > 1.96 * p["se"]}),
               "parameters": pars,
               "undetermined_parameters": [c.names[j] for j in range(c.p) if j not in set(c.active.tolist())]
               if c.kind != "offset" else [],
               "delta_bic": step_info.get(k, {}).get("delta_bic"), "p_lrt": step_info.get(k, {}).get("p_lrt"),
               "aliases": _aliases(prob, final, k, ang_map)}
        if c.kind == "drift":
            ent["tau_s"] = final.taus.get(k)
            ent["note"] = ("tau profiled on a grid; its uncertainty and that of the slow noise enter the "
                           "intervals (Gauss-Newton ln-tau column, standard errors marginalised over the slow noise)")
        found.append(ent)
    sig = prob.sigma()
    gof = {}
    for name, f in (("before", base), ("after", final)):
        gof[name] = {"chi2": f.chi2, "dof": f.dof, "p": f.p, "by_sensor_axis": block_table(prob, f)}
    rms = {}
    o = prob.geom.obs
    for name, f in (("before", base), ("after", final)):
        d = {}
        for si, s in enumerate(SENSORS):
            for kind in ("static", "rotation"):
                for r in range(3):
                    m = (o["sensor"] == si) & (o["row"] == r) & np.array(
                        [prob.geom.windows[w].kind == kind for w in o["window"]])
                    if m.any():
                        zr = f.resid[m] / sig[m]
                        d[f"{s}_{kind}_{ROWS[r]}"] = {"rms": float(np.sqrt(np.mean(f.resid[m] ** 2))),
                                                         "rms_over_sigma": float(np.sqrt(np.mean(zr**2))),
                                                         "unit": prob.geom.units_out[s]}
        rms[name] = d
    nb = len(prob.base_names)
    se_b = np.sqrt(np.diag(base.cov)[:nb])
    th0 = prob.base_theta if prob.kind == "norm" else np.zeros(nb)
    moved = [{"name": nm, "before": float(th0[i] + base.theta[i]), "after": float(th0[i] + final.theta[i]),
              "se_before": float(se_b[i]),
              "moved_by_se": float((final.theta[i] - base.theta[i]) / se_b[i]) if se_b[i] > 0 else 0.0}
             for i, nm in enumerate(prob.base_names)]
    # adequacy on the measured noise (the session's Allan deviation, and a long static record's slow part when
    # given); the noise the search estimated from the window means is only used to say "inconclusive"
    adq = {"before": adequacy(prob, base), "after": adequacy(prob, final)}
    adq["noise"] = prob.noise_basis
    slow_measured = bool(st.get("noise_record")) and prob.kind == "vector"
    # beyond the library: generic structure left beside the final model, and rival forms of what was found
    search = open_search(prob, final)
    rivals = form_alternatives(prob, final) if found else []
    # a generic rival (no physics named) that fits as well means the data do not establish the found term
    generic_rival = [r for r in rivals if r.get("generic")]
    explained = adq["after"]["adequate"] and not search["significant"] and not generic_rival
    unexplained = [] if adq["after"]["adequate"] else unexplained_entries(prob, final, adq["after"])
    unexplained += [{"name": f"{t['sensor']} {t['axis']}".strip() + f": {t['family']}", "scope": "generic",
                     "sensor": t["sensor"], "axis": t["axis"], "family": t["family"], "chi2": t["chi2"],
                     "dof": t["dof"], "p_holm": t["p_holm"], "shape": t["description"],
                     "rms_residual": t["rms"], "rms_noise": float("nan"), "excess_rms": t["rms"], "unit": t["unit"]}
                    for t in search["significant"]]
    where = "; ".join(f"{u['name']} (chi2 {u['chi2']:.4g} on {u['dof']:.3g}, {u['shape']})" for u in unexplained[:4])
    raw = prob.raw_chi2
    scatter = (f"; the segment means scatter beyond the measured sensor noise (chi2 {raw[0]:.4g} on {raw[1]}): it may be "
               "hand placement or motion during the static segments, or physics outside the library"
               if raw is not None and raw[2] < st["chi2_p_adequate"] else "")
    helped = (" after " + ", ".join(f["key"] for f in found) + " (which helped)") if found else ""
    adq_estimated = adequacy(prob, final, L=prob.L) if not slow_measured else None
    if not found and adq["before"]["adequate"] and not search["significant"]:
        verdict, reason = "adequate", ("the base model fits within the measured noise in every subset tested and no "
                                       "candidate term passes the tests")
    elif found and explained:
        verdict = "missing_physics"
        reason = ("terms beyond the base model are needed and explain the data (the final model passes every "
                  "adequacy test on the measured noise and no generic structure stays beside it): "
                  + ", ".join(f["key"] for f in found))
        if rivals:
            reason += ("; on this path the data fit as well " + "; ".join(
                f"with {r['alternative']} in place of {', '.join(r['replaces'])} (separate them: {r['experiment']})"
                for r in rivals))
    elif found and generic_rival and adq["after"]["adequate"] and not search["significant"]:
        verdict = "inconclusive"
        reason = ("the data fit within the measured noise with " + ", ".join(f["key"] for f in found)
                  + ", but as well with " + "; ".join(f"{r['alternative']} in place of {', '.join(r['replaces'])}"
                                                      for r in generic_rival)
                  + ": the poses do not establish the term (" + generic_rival[0]["experiment"] + ")")
    elif not slow_measured and adq_estimated["adequate"]:
        verdict = "inconclusive"
        if prob.kind == "norm":
            reason = (f"misfit remains{helped} beyond the noise measured within the static segments ({where}): the "
                      f"segment means scatter {math.sqrt(max(prob.overdispersion, 1.0)):.3g} times more than it -- hand "
                      "placement, motion during the segments, slow noise or physics outside the library; the data "
                      "cannot tell which (longer, steadier static poses, or a recording with nominal attitudes, "
                      "would)")
        else:
            reason = (f"misfit remains{helped} beyond the noise measured within the segments ({where}), but within "
                      "what slow noise between the segments could do, which this session cannot measure: a long "
                      "static record of the same unit (noise_record setting, calib diagnose --noise-record) decides"
                      + scatter)
    else:
        verdict = "unexplained"
        reason = f"misfit remains{helped} that no term of the library explains: {where or 'see adequacy'}" + scatter
    # what the verdict assumes of the slow noise between the segments, and the same tests on the noise measured
    # within the segments alone: an adequate (or explained) fit that passes only with a slow level the data do not
    # measure is inconclusive, with the level it needs and the static record that would decide
    if verdict == "inconclusive" and adq_estimated is not None and adq_estimated["adequate"] and prob.kind == "vector":
        slow = _slow_basis(prob, estimated=True)
        sna = slow_noise_assumption(prob, final, adq_estimated, L_assumed=prob.L, precise=detail, **slow)
        if sna["statement"]:
            reason += "; " + sna["statement"]
    else:
        slow = _slow_basis(prob)
        judged = base if verdict == "adequate" else final
        sna = slow_noise_assumption(prob, judged, adq["before" if verdict == "adequate" else "after"],
                                    L_assumed=measured_factors(prob), precise=detail, **slow)
        if verdict in ("adequate", "missing_physics") and sna["rests_on_assumed_level"]:
            what = ("the base model is adequate" if verdict == "adequate" else
                    "the found terms (" + ", ".join(f["key"] for f in found) + ") explain the data")
            verdict, explained = "inconclusive", False
            reason = f"{what} only if the slow noise the tests assume is there: {sna['statement']}"
        elif sna["statement"]:
            reason += "; " + sna["statement"]
    adq["slow_noise"] = sna
    separations = []
    tk = testable_keys(prob)
    if detail and prob.kind == "vector" and "latitude_error" in tk and "gyro_g_sensitivity/gyro" in tk:
        rot_rows = np.flatnonzero(np.array([prob.geom.windows[w].kind == "rotation" for w in o["window"]])
                                  & (o["row"] == 0))
        info_r, ang_r = library_geometry(prob, rows=rot_rows)
        am = {frozenset((a, b)): v for a, b, v in ang_r}
        separations.append({
            "pair": ["latitude_error", "gyro_g_sensitivity/gyro"],
            "angle_deg_all_segments": ang_map.get(frozenset(("latitude_error", "gyro_g_sensitivity/gyro"))),
            "angle_deg_rotation_means_only": am.get(frozenset(("latitude_error", "gyro_g_sensitivity/gyro"))),
            "absorbed_fraction_rotation_means_only": {k: info_r[k]["absorbed_fraction"] for k in
                                                      ("latitude_error", "gyro_g_sensitivity/gyro") if k in info_r},
            "separating_segments_latitude": separating_segments(prob, "latitude_error", "gyro_g_sensitivity/gyro"),
            "separating_segments_g_sensitivity": separating_segments(prob, "gyro_g_sensitivity/gyro",
                                                                      "latitude_error"),
            "note": ("on the rotation means alone the gyro bias, the g-sensitivity and a latitude error all add a "
                     "constant vector per rotation axis; the static positions (g-sensitivity: pattern with the "
                     "gravity direction; latitude: tilt of the Earth-rate direction, scale pinned by the rotations) "
                     "and the table-angle harmonics (Earth-rate magnitude Omega cos L) separate them")})
    over = {f"{t['sensor']} {t['axis']}": t["overdispersion"] for t in adq["after"]["tests"]
            if t["scope"] == "sensor_axis"}
    return {
        "verdict": verdict, "verdict_reason": reason, "explained": bool(explained),
        "unexplained": unexplained, "adequacy": adq, "overdispersion": over, "open_search": search,
        "form_alternatives": rivals, "not_confirmed": unconfirmed,
        "degenerate_candidates": [{"key": k, "why": w} for k, w in prob.__dict__.get("degenerate", {}).items()],
        "goodness_of_fit": gof,
        "locate": locate(prob, base) if detail else {"summary": [], "not_computed": "setting report_detail: false"},
        "identifiability": {"candidates": info, "pairwise_angles_deg": [
            {"a": a, "b": b, "angle_deg": v} for a, b, v in sorted(angles, key=lambda x: x[2]) if np.isfinite(v)],
            "alias_groups_geometric": groups, "separations": separations},
        "selection": {"steps": steps, "last_step_candidates": [{k: v for k, v in r.items() if k != "fit"}
                                                               for r in table]},
        "found": found,
        "absent": _absent(prob, final, table) if st.get("absent_bounds", True) else None,
        "untestable": _untestable(prob),
        "base_parameters": moved,
        "residual_rms": rms,
        "_fits": (base, final),
    }
