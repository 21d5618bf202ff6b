"""Identifiability of the effect library on a recording's path (module doc of :mod:`calib.diagnosis`, step 3):
the fraction of each signature the base parameters absorb, the determined parameters of every candidate,
principal angles between visible signatures, and what separates two look-alikes."""
from __future__ import annotations

import numpy as np

from calib.diagnosis.fitting import columns
from calib.diagnosis.problem import Fit, Problem, lstsq
from calib.sim import effects

def typical_scale(c) -> np.ndarray:
    """Typical magnitude of every parameter of a candidate: the largest |value| of the registry default of
    its key (calib.sim.effects), the yardstick for 'determined' (a 1-sigma error above it means the path cannot
    say anything useful about that parameter)."""
    d = effects.REGISTRY[c.effect].defaults
    out = []
    for key, _ in c.keys:
        v = np.abs(np.asarray(d[key], dtype=float))
        out.append(float(v.max()) if v.size and v.max() > 0 else 1.0)
    return np.array(out)


def prepare_library(prob: Problem):
    """Absorbed fraction (geometric, whitened) and the determined parameters of every candidate: a parameter
    is dropped when its visible (unabsorbed, whitened) signature is below ``visible_rel`` of the strongest
    parameter of the same registry key (same units: e.g. the off-axis lever-arm components, seen only through
    the installation errors), or when its standard error with the base model exceeds ten times the effect's
    typical magnitude (registry default; dropped one at a time, worst first)."""
    st_rel = prob.settings["visible_rel"]
    base = prob.base_qr()          # the base factorised block by block (None: the whole design at once)
    if base is None:
        Xw = prob.whiten(prob.X0)
        Q, _ = np.linalg.qr(Xw)
    yw = prob.wcache("y", lambda: prob.y)
    for c in prob.lib:
        if c.untestable or c.S is None:
            c.active = np.arange(0)
            c.visible = np.zeros(c.p)
            c.absorbed = np.ones(c.p)
            c.se0 = np.full(c.p, np.inf)
            continue
        Sw = prob.whiten(c.S)
        P = base.project(Sw) if base is not None else Sw - Q @ (Q.T @ Sw)
        nrm = np.linalg.norm(Sw, axis=0)
        vis = np.linalg.norm(P, axis=0)
        c.visible = vis
        c.absorbed = 1.0 - np.divide(vis, nrm, out=np.zeros_like(vis), where=nrm > 0)
        scale = 10.0 * typical_scale(c)   # hopeless: 1 sigma beyond ten times the typical magnitude
        keys = [k for k, _ in c.keys] if c.keys else [""] * c.p
        keep = []
        thr_abs = prob.settings["absorbed_untestable"]
        for j in range(c.p):
            same = [i for i in range(c.p) if keys[i] == keys[j]]
            if vis[j] > 0 and vis[j] >= st_rel * max(vis[same]) and c.absorbed[j] <= thr_abs:
                keep.append(j)
        if prob.kind != "vector":          # typical magnitudes are those of the navigation-grade unit
            c.se0 = np.full(c.p, np.nan)
            c.active = np.array(sorted(keep), dtype=int)
            continue
        se = np.full(c.p, np.inf)
        k0 = prob.X0.shape[1]
        while keep:
            if base is not None:
                cov = base.solve(yw, Sw[:, keep])[1]
            else:
                _, cov, _ = lstsq(np.hstack([Xw, Sw[:, keep]]), yw)
            s = np.sqrt(np.clip(np.diag(cov)[k0:], 0.0, None))
            s[~np.isfinite(s) | (s == 0)] = np.inf
            ratio = s / scale[keep]
            se[:] = np.inf
            se[keep] = s
            j = int(np.argmax(ratio))
            if ratio[j] <= 1.0:
                break
            keep.pop(j)
        c.se0 = se
        c.active = np.array(sorted(keep), dtype=int)


def visible_basis(prob: Problem, Q, key, taus=None, rows=None):
    c = prob.cand(key)
    if c.kind == "offset":
        S = c.S
    else:
        S = columns(prob, key, taus or {})
    Sw = prob.whiten(S)
    if rows is not None:
        Sw = Sw[rows]
    P = Sw - Q @ (Q.T @ Sw)
    U, s, _ = np.linalg.svd(P, full_matrices=False)
    if s.size == 0 or s[0] <= 0:
        return np.zeros((P.shape[0], 0))
    return U[:, s > 1e-6 * s[0]]


def principal_angle_deg(A, B) -> float:
    """Smallest principal angle [deg] between the column spaces of orthonormal A and B."""
    if A.shape[1] == 0 or B.shape[1] == 0:
        return float("nan")
    s = np.linalg.svd(A.T @ B, compute_uv=False)
    return float(np.degrees(np.arccos(np.clip(s.max(), -1.0, 1.0))))


def library_geometry(prob: Problem, rows=None, terms=(), pairs_with=None):
    """Absorbed fraction, visible rank and pairwise smallest principal angles of the testable candidates,
    against the base model plus ``terms`` (whitened; optionally on a subset of observation ``rows``).
    ``pairs_with``: only the angles of the pairs that hold one of these keys (and no absorbed fractions): what the
    aliases of the found terms read, when the report is not to list the rest."""
    if pairs_with is not None and not pairs_with:
        return {}, []
    X = prob.X0
    extra = [columns(prob, k, {}) for k in terms if prob.cand(k).kind != "offset"]
    A = np.hstack([X] + extra) if extra else X
    Aw = prob.whiten(A)
    if rows is not None:
        Aw = Aw[rows]
    Q, R = np.linalg.qr(Aw)
    d = np.abs(np.diag(R))
    Q = Q[:, d > 1e-10 * d.max()]
    keys = [c.key for c in prob.lib if not c.untestable and c.key not in terms]
    info, bases = {}, {}
    for k in keys:
        c = prob.cand(k)
        S = c.S if c.kind == "offset" else columns(prob, k, {})
        Sw = prob.whiten(S)
        if rows is not None:
            Sw = Sw[rows]
        nrm = np.linalg.norm(Sw)
        P = Sw - Q @ (Q.T @ Sw)
        vis = np.linalg.norm(P)
        bases[k] = visible_basis(prob, Q, k, rows=rows)
        if pairs_with is not None:
            continue
        info[k] = {"absorbed_fraction": float(1.0 - vis / nrm) if nrm > 0 else 1.0,
                   "visible_rank": int(bases[k].shape[1]), "n_parameters": int(c.p),
                   "determined_parameters": [c.names[j] for j in c.active] if c.kind != "offset" else c.names}
    angles = []
    for i, a in enumerate(keys):
        for b in keys[i + 1:]:
            if pairs_with is not None and a not in pairs_with and b not in pairs_with:
                continue
            ang = principal_angle_deg(bases[a], bases[b])
            angles.append((a, b, ang))
    return info, angles


def term_signal(final: Fit, key):
    """The whitened-able prediction of one found term at its estimates (its columns times its parameters,
    the Gauss-Newton ln-tau column of a drift term included; for the clock offset J * offset) and the
    column indices of everything else in the final model."""
    own = [sl for k, sl in final.slices.items() if k == key or k.startswith(f"{key}#")]
    idx = np.concatenate([np.arange(sl.start, sl.stop) for sl in own]) if own else np.arange(0)
    sig = final.X[:, idx] @ final.theta[idx]
    rest = np.setdiff1d(np.arange(final.X.shape[1]), idx)
    return sig, rest


def discrimination_noncentrality(prob: Problem, final: Fit, key, other) -> float:
    """lambda = |P_perp [rest of the final model, candidate ``other``] W s|^2, s the found term's signal at
    its estimated magnitude: the expected chi-square by which the found term beats ``other`` in its place.
    Below (z_0.975 + z_0.95)^2 = 13.0 the path cannot tell the two apart with 95 % power at this magnitude."""
    sig, rest = term_signal(final, key)
    c = prob.cand(other)
    Sb = c.S if c.kind == "offset" else columns(prob, other, final.taus)
    k0 = prob.X0.shape[1]
    base = prob.base_qr(final.X[:, :k0]) if "time_offset" in final.terms else prob.base_qr()
    if base is not None and np.all(rest[:k0] == np.arange(k0)):
        # the base eliminated block by block: the rest of the final model and the candidate on what it leaves
        E = prob.whiten(np.hstack([final.X[:, rest[k0:]], np.atleast_2d(Sb.T).T]))
        ss, ok = base.unpivoted_chi2(E[:, np.linalg.norm(E, axis=0) > 0], base.project(prob.whiten(sig)))
        if ok:
            return ss
    B = prob.whiten(np.hstack([final.X[:, rest], np.atleast_2d(Sb.T).T]))
    B = B[:, np.linalg.norm(B, axis=0) > 0]
    Q, R = np.linalg.qr(B / np.linalg.norm(B, axis=0))
    keep = np.abs(np.diag(R)) > 1e-9 * np.abs(R[0, 0])
    Q = Q[:, keep]
    sw = prob.whiten(sig)
    r = sw - Q @ (Q.T @ sw)
    return float(r @ r)


def separating_segments(prob: Problem, a_key, b_key, top=5):
    """Windows that carry the information separating candidate a from b: the part of a's visible signature
    orthogonal to (base + b), its energy per window (whitened)."""
    Xw = prob.whiten(prob.X0)
    Sa = prob.whiten(prob.cand(a_key).S if prob.cand(a_key).kind == "offset" else columns(prob, a_key, {}))
    Sb = prob.whiten(prob.cand(b_key).S if prob.cand(b_key).kind == "offset" else columns(prob, b_key, {}))
    Q, _ = np.linalg.qr(np.hstack([Xw, Sb]))
    P = Sa - Q @ (Q.T @ Sa)
    e = np.sum(P**2, axis=1)
    o = prob.geom.obs
    per = {}
    for k in range(prob.n):
        lab = prob.geom.windows[o["window"][k]].label
        per[lab] = per.get(lab, 0.0) + e[k]
    tot = sum(per.values()) or 1.0
    best = sorted(per.items(), key=lambda kv: -kv[1])[:top]
    return [{"segment": lab, "share": v / tot} for lab, v in best]
