"""Generalised least-squares fits of the base model plus candidate terms (module doc of
:mod:`calib.diagnosis`, steps 1 and 4): linear amplitudes by whitened least squares, the clock offset and the
warm-up time constants of a bias drift by profile likelihood."""
from __future__ import annotations

import numpy as np
from scipy import optimize

from calib.diagnosis import kernels
from calib.diagnosis.library import DRIFT_TAUS
from calib.diagnosis.problem import UNPIVOTED_TOL, Fit, Problem, base_blocks, base_estimates, lstsq

def _dS_dlntau(c, tau: float) -> np.ndarray:
    """Derivative of a drift candidate's columns with respect to ln(tau) at a grid point: the three-point
    (second-order) Lagrange derivative on the non-uniform ln-tau grid of :data:`calib.diagnosis.library.DRIFT_TAUS`
    (one-sided at the ends of the grid)."""
    grid = sorted(c.S_by_tau)
    i = grid.index(tau)
    if 0 < i < len(grid) - 1:
        xm, x0, xp = np.log(grid[i - 1]), np.log(grid[i]), np.log(grid[i + 1])
        h1, h2 = x0 - xm, xp - x0
        return (-h2 / (h1 * (h1 + h2)) * c.S_by_tau[grid[i - 1]] + (h2 - h1) / (h1 * h2) * c.S_by_tau[tau]
                + h1 / (h2 * (h1 + h2)) * c.S_by_tau[grid[i + 1]])
    j = i + 1 if i == 0 else i - 1
    return (c.S_by_tau[grid[j]] - c.S_by_tau[tau]) / (np.log(grid[j]) - np.log(tau))


def columns(prob: Problem, key, taus):
    """The determined columns of candidate ``key`` (a drift term at its time constant in ``taus``, 900 s
    when not given)."""
    c = prob.cand(key)
    if c.kind == "drift":
        S = c.S_by_tau[taus.get(key, 900.0)]
    else:
        S = c.S
    return S[:, c.active]


def fit(prob: Problem, terms, *, delta=None, taus=None, keep_X=True, offset_column=True, delta_hint=None) -> Fit:
    """GLS fit of the base model plus ``terms`` (candidate keys). Nonlinear parameters (clock offset, drift
    time constants) are optimised by profile likelihood unless given."""
    terms = list(terms)
    taus = dict(taus or {})
    drift_keys = [k for k in terms if prob.cand(k).kind == "drift"]
    has_off = "time_offset" in terms
    if has_off and delta is None:
        return _fit_offset(prob, terms, taus, hint=delta_hint)
    missing = [k for k in drift_keys if k not in taus]
    if missing:
        return _fit_drift_taus(prob, terms, taus, delta, missing, offset_column)
    d = float(delta or 0.0) if has_off else 0.0
    yw = prob.wcache("y", lambda: prob.y)
    cols, wcols, slices, base = _linear_design(prob, terms, taus, d if has_off else None)
    active = {k: prob.cand(k).active for k in slices}
    names = list(prob.base_names) + [f"{k}:{prob.cand(k).names[j]}" for k in slices for j in prob.cand(k).active]
    pos = sum(c.shape[1] for c in cols)
    nonlinear_columns = offset_column and (has_off or drift_keys)
    th0 = _solve(prob, base, cols, wcols, yw, want_cov=False)[0] if nonlinear_columns else None
    for k in drift_keys if offset_column else ():
        # Gauss-Newton column of ln(tau) at the profiled grid value (amplitudes of a first solve): the joint
        # covariance then includes the time constant, so the warm-up intervals are not conditional on it
        c = prob.cand(k)
        amp = th0[slices[k]]
        J = _dS_dlntau(c, taus[k])[:, c.active] @ amp
        cols.append(J[:, None])
        wcols.append(prob.whiten(J[:, None]))
        slices[f"{k}#ln_tau"] = slice(pos, pos + 1)
        names.append(f"{k}:ln_tau_correction")
        pos += 1
    if has_off and offset_column:
        # Gauss-Newton column of the offset at d (with the base M of a first solve): the linear correction
        # is ~0 at the profile optimum and the joint covariance includes the offset
        M, _ = base_estimates(th0)
        J = prob.cand("time_offset").offset.design_delta(d, M, deriv=1)
        cols.append(J[:, None])
        wcols.append(prob.whiten(J[:, None]))
        slices["time_offset"] = slice(pos, pos + 1)
        active["time_offset"] = np.array([0])
        names.append("time_offset:offset_s")
    theta, cov, rank, rw = _solve(prob, base, cols, wcols, yw)
    A = np.hstack(cols)
    resid = prob.y - A @ theta
    if has_off and offset_column:
        theta = theta.copy()
        theta[slices["time_offset"]] += d   # the column is a correction about d: report the offset itself
    chi2 = float(rw @ rw)
    k = rank + ((len(drift_keys) + (1 if has_off else 0)) if not offset_column else 0)
    dof = prob.n - k - prob.n_noise_params
    return Fit(terms, theta, cov, chi2, dof, k, names, slices, resid, rw, delta=d, taus=dict(taus),
               active=active, X=A if keep_X else None)


def _solve(prob: Problem, base, cols, wcols, yw, want_cov=True):
    """Whitened least squares of the design ``cols`` (the base first, whitened extra columns ``wcols[1:]``):
    ``(theta, cov, rank, whitened residual)``. With the base factorised block by block (``base``,
    :class:`calib.diagnosis.problem.BaseQR`) only the extra columns are solved for; otherwise :func:`lstsq` of the
    whole whitened design."""
    extra = wcols[1:]
    if base is not None:
        Sw = np.hstack(extra) if extra else None
        return base.solve(yw, Sw, want_cov=want_cov, yp=_y_perp(prob, base, yw))
    if wcols[0] is None:
        wcols = [prob.whiten(cols[0])] + extra
    Aw = np.hstack(wcols)
    theta, cov, rank = lstsq(Aw, yw, want_cov=want_cov)
    return theta, cov, rank, yw - Aw @ theta


def _y_perp(prob: Problem, base, yw):
    """The whitened observations off the base (kept for the unpatched base, which every fit at zero offset shares)."""
    c = prob.__dict__.setdefault("_wc", {})
    if c.get("base_qr") is base:
        if "y_perp" not in c:
            c["y_perp"] = base.project(yw)
        return c["y_perp"]
    return base.project(yw)


def _linear_design(prob: Problem, terms, taus, d):
    """The columns of the linear part of a fit: ``[X, S_k...]`` unwhitened and ``[Xw or None, S_k...]`` whitened,
    the slice of each term and the base factorised block by block (None when it does not split: ``Xw`` is then
    given). ``d``: the clock offset of the base design (None: no offset term, the base design as it is). The
    whitened term columns and the factors of the unpatched base are cached on the problem (:meth:`Problem.wcache`:
    they depend on the noise model, fixed between re-estimates)."""
    if d is not None:
        X = prob.cand("time_offset").offset.patch_design(prob.X0, d)
        base = prob.base_qr(X)
        Xw = None if base is not None else prob.whiten(X)
    else:
        X = prob.X0
        base = prob.base_qr()
        Xw = None if base is not None else prob.wcache("X0", lambda: prob.X0)
    cols, wcols, slices = [X], [Xw], {}
    pos = X.shape[1]
    for k in terms:
        if k == "time_offset":
            continue
        c = prob.cand(k)
        tau = taus.get(k, 900.0) if c.kind == "drift" else None
        S = columns(prob, k, taus)
        cols.append(S)
        wcols.append(prob.wcache(("S", k, tau), lambda: S))
        slices[k] = slice(pos, pos + S.shape[1])
        pos += S.shape[1]
    return cols, wcols, slices, base


def profile_chi2(prob: Problem, terms, *, delta=None, taus=None) -> float:
    """The chi-square of ``fit(prob, terms, delta=delta, taus=taus, offset_column=False)`` -- the same number --
    without the fit's covariance, residuals and unwhitened design: what the profiles of the clock offset and of
    the drift time constants evaluate (hundreds of times per diagnosis)."""
    terms = list(terms)
    taus = dict(taus or {})
    has_off = "time_offset" in terms
    if (has_off and delta is None) or any(prob.cand(k).kind == "drift" and k not in taus for k in terms):
        return fit(prob, terms, delta=delta, taus=taus, offset_column=False).chi2   # a profile inside
    cols, wcols, _, base = _linear_design(prob, terms, taus, float(delta or 0.0) if has_off else None)
    yw = prob.wcache("y", lambda: prob.y)
    if base is not None:
        extra = wcols[1:]
        return base.chi2(yw, np.hstack(extra) if extra else None, yp=_y_perp(prob, base, yw))
    rw = _solve(prob, base, cols, wcols, yw, want_cov=False)[3]
    return float(rw @ rw)


def chi2_rank(prob: Problem, terms, taus=None):
    """``(chi2, k)`` of ``fit(prob, terms, taus=taus)`` -- the chi-square and the number of fitted parameters, what a
    BIC comparison reads -- without the fit's estimates and covariance when every term is linear (no clock offset,
    no drift term, whose fits add Gauss-Newton columns); otherwise from the fit itself."""
    terms = list(terms)
    taus = dict(taus or {})
    if any(prob.cand(k).kind != "linear" for k in terms):
        f = fit(prob, terms, taus=taus)
        return f.chi2, f.k
    _, wcols, _, base = _linear_design(prob, terms, taus, None)
    extra = wcols[1:]
    if base is None or not extra:
        f = fit(prob, terms, taus=taus)
        return f.chi2, f.k
    Sw = np.hstack(extra)
    ss, ok = base.unpivoted_chi2(Sw, _y_perp(prob, base, prob.wcache("y", lambda: prob.y)))
    if not ok:       # a nearly dependent column: the pivoted fit decides the rank
        f = fit(prob, terms, taus=taus)
        return f.chi2, f.k
    return ss, base.k + Sw.shape[1]


def _offset_profile(prob: Problem, terms, taus):
    """The function ``d -> profile_chi2(prob, terms, delta=d, taus=taus)`` (the same numbers to rounding), with
    what does not change with the offset -- the whitened observations and extra columns -- prepared once, and each
    evaluation one compiled call (:func:`calib.diagnosis.kernels.patched_chi2`) on the patched base."""
    om = prob.cand("time_offset").offset
    layout = base_blocks(prob)
    if layout is None or prob.padded() is None or any(prob.cand(k).kind == "drift" and k not in taus
                                                      for k in terms):
        return lambda d: profile_chi2(prob, terms, delta=float(d), taus=taus)
    _, wcols, _, _ = _linear_design(prob, [k for k in terms if k != "time_offset"], taus, None)
    extra = wcols[1:]
    Sw = np.ascontiguousarray(np.hstack(extra)) if extra else np.zeros((prob.n, 0))
    nS = np.linalg.norm(Sw, axis=0)
    nS[nS == 0] = 1.0
    yw = np.ascontiguousarray(prob.wcache("y", lambda: prob.y))
    Lpad = prob.padded()
    starts, sizes, bcols = layout

    def f(d):
        X = om.patch_design(prob.X0, float(d))
        ss, ok = kernels.patched_chi2(X, Lpad, starts, sizes, bcols, yw, Sw, nS, UNPIVOTED_TOL)
        return float(ss) if ok else profile_chi2(prob, terms, delta=float(d), taus=taus)

    return f


def _fit_offset(prob: Problem, terms, taus, hint=None):
    """Profile the clock offset: coarse scan on the library grid (or, with ``hint``, a bracket of +-10 ms
    around a previous estimate), then bounded Brent."""
    om = prob.cand("time_offset").offset
    lo, hi = om.bounds
    f = _offset_profile(prob, terms, taus)

    if hint is not None:
        a, b = max(lo, hint - 0.01), min(hi, hint + 0.01)
    else:
        grid = np.linspace(lo, hi, 21)
        vals = np.array([f(d) for d in grid])
        j = int(np.argmin(vals))
        a, b = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
    r = optimize.minimize_scalar(f, bounds=(a, b), method="bounded", options={"xatol": 1e-6})
    return fit(prob, terms, delta=float(r.x), taus=taus)


def _fit_drift_taus(prob: Problem, terms, taus, delta, missing, offset_column=True):
    """Profile the warm-up time constant of each drift term over the grid (coordinate-wise, two sweeps)."""
    cur = dict(taus)
    for k in missing:
        cur[k] = 900.0
    best = None
    for _ in range(2 if len(missing) > 1 else 1):
        for k in missing:
            res = []
            for tau in DRIFT_TAUS:
                t2 = dict(cur)
                t2[k] = tau
                res.append((profile_chi2(prob, terms, delta=delta, taus=t2), tau))
            cur[k] = min(res)[1]
    best = fit(prob, terms, delta=delta, taus=cur, offset_column=offset_column)
    return best
