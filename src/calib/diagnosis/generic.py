"""Beyond the library: an open search of the residuals with generic bases, and the forms a finding cannot tell apart.

The library (:mod:`calib.diagnosis.library`) holds named physics. A fit that adds library terms until the global
chi-square passes can still be wrong physics that happens to absorb the misfit. Two checks guard against that:

1. **Open search** (:func:`open_search`). After the final model, the residuals are tested against generic bases
   that name no physics, per sensor and axis, each a family of per-sample terms ``d_i`` (input-referred, reduced
   into observations exactly like the library's terms, :func:`calib.diagnosis.library.reduce_axis_terms`):

   * ``time``: Legendre polynomials of degree 1-3 of the session time and sinusoids of periods span/k,
     k = 1..6 -- a bias that moves in time (drift, oscillation, a step);
   * ``scale in time``: the axis' own input times degree 1-2 polynomials of time -- a scale factor that moves;
   * ``orientation`` (accelerometers): all monomials of degree 2-4 of the gravity direction components, i.e.
     the spherical harmonics of degree <= 4 of the direction of the specific force;
   * ``rate`` (gyros): the axis' rate squared, cubed, |w| and w|w| -- rate nonlinearity of any form;
   * ``per static stop``: for the accelerometers, the residual components of each static stop perpendicular to
     the measured gravity direction (what an attitude error of the stop produces), tested against the parallel
     one.

   Each family is projected out of the final design (whitened with the *measured* noise); the sum of squares of
   the whitened residual in the remaining span is chi-square with its rank as degrees of freedom under the
   null. The family of tests is controlled by Holm's step-down at ``adequacy_alpha``. A library term is accepted
   as the explanation only when no generic structure stays significant beside it.

2. **Form alternatives** (:func:`form_alternatives`). Some forms fit equally on a given path: a temperature
   coefficient and a drift in time when the temperature moved monotonically; a quadratic nonlinearity plus a
   scale asymmetry and a quartic one on a 45 deg grid. For each found term with a known rival form, the rival
   is fitted in its place; when its BIC is within ``alias_delta_bic`` of the final model's (or better) it is
   reported with the experiment that would separate the two. On the norm model (few static poses taken one
   after the other), each found term is also replaced by a *generic* basis -- biases drifting in time, the three
   biases or one axis's bias stepping at a segment boundary, or one axis's bias oscillating (period span/1 to
   span/8 in quarter steps; the step time and the period each cost one more BIC parameter) -- and when that fits
   within ``generic_delta_bic`` the term is not established (verdict ``inconclusive``).
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from calib.core.distributions import chi2_sf, f_sf
from calib.diagnosis.adequacy import holm, measured_factors
from calib.diagnosis.fitting import fit
from calib.diagnosis.geometry import AXES, SENSORS, TO_MODEL
from calib.diagnosis.library import reduce_axis_terms, sample_context
from calib.diagnosis.problem import Fit, Problem, base_estimates

#: periods of the sinusoids of the time family: the span divided by these
PERIOD_DIVISORS = (1, 2, 3, 4, 5, 6)


def _time_basis(t, t0, span):
    tau = 2.0 * (t - t0) / max(span, 1e-9) - 1.0
    leg = [np.polynomial.legendre.Legendre.basis(k)(tau) for k in (1, 2, 3)]
    per = []
    for k in PERIOD_DIVISORS:
        ph = 2.0 * math.pi * k * (t - t0) / max(span, 1e-9)
        per += [np.cos(ph), np.sin(ph)]
    return leg, per


def _context(prob: Problem):
    """The sample context of the problem's windows (:func:`calib.diagnosis.library.sample_context`, built once per
    geometry)."""
    return sample_context(prob.geom)


def _axis_columns(prob: Problem, ctx, M: dict, sensor: str, i: int, terms) -> np.ndarray:
    """Observation columns (n_obs, k) of the per-sample input-referred terms ``terms`` on axis ``i`` of ``sensor``,
    at the base K E ``M`` (reduced like the library's terms, :func:`calib.diagnosis.library.reduce_axis_terms`)."""
    scale = float(np.asarray(M[sensor], float)[i, i]) * TO_MODEL[prob.geom.units_in[sensor]]
    return reduce_axis_terms(prob.geom, ctx, terms, sensor, i, scale)


#: the base K E of a unit scale factor (the reduction of a term is linear in K_i: see :func:`_unit_columns`)
_UNIT_M = {s: np.eye(3) for s in SENSORS}


def _unit_columns(prob: Problem, key, build):
    """``build()`` -- observation columns of per-sample terms at unit scale factors (``_UNIT_M``) -- computed once
    per geometry under ``key``: the terms are functions of the window samples only, and the column of a term on
    axis i at the base K E ``M`` is the unit column times ``M[i, i]`` (:func:`calib.diagnosis.library.reduce_axis_terms`
    scales the term by K_i before the linear reduction)."""
    return prob.geom.derived(("generic",) + tuple(key), build)


def generic_families(prob: Problem, final: Fit) -> list[dict]:
    """The generic families of the vector model (module docstring), each ``{"family", "sensor", "axis",
    "description", "S"}`` with ``S`` (n_obs, k) in the observations' units at the final fit's K E."""
    if prob.kind != "vector":
        return []
    M, _ = base_estimates(final.theta)
    return [{**fam, "S": fam["S"] * M[fam["sensor"]][AXES.index(fam["axis"]), AXES.index(fam["axis"])]}
            for fam in _unit_columns(prob, ("families",), lambda: _generic_families_unit(prob))]


def _generic_families_unit(prob: Problem) -> list[dict]:
    """:func:`generic_families` at unit scale factors (geometry only)."""
    ctx = _context(prob)
    M = _UNIT_M
    t = ctx.t
    t0, span = float(t.min()), float(np.ptp(t))
    leg, per = _time_basis(t, t0, span)
    out = []
    for s in SENSORS:
        x = ctx.f if s == "accel" else ctx.w
        xs = x / max(float(np.max(np.abs(x))), 1e-300)  # unit-free input (g or rate over its largest value)
        for i in range(3):
            fams = {"time": (leg + per, "bias moving in time (Legendre degree 1-3 and sinusoids of period "
                                        "span/1..6)"),
                    "scale in time": ([xs[:, i] * leg[0], xs[:, i] * leg[1]],
                                      "scale factor moving in time (input x degree 1-2 polynomials of time)")}
            if s == "accel":
                u = ctx.f / np.maximum(np.linalg.norm(ctx.f, axis=1, keepdims=True), 1e-300)
                mons = []
                for deg in (2, 3, 4):
                    for c in itertools.combinations_with_replacement(range(3), deg):
                        mons.append(np.prod(u[:, list(c)], axis=1))
                fams["orientation"] = (mons, "output depending on the direction of gravity beyond the linear "
                                             "model (spherical harmonics of degree 2-4)")
            else:
                w = xs[:, i]
                fams["rate"] = ([w**2, w**3, np.abs(w), w * np.abs(w)],
                                "output depending on the rate beyond the linear model (w^2, w^3, |w|, w|w|)")
            for fam, (terms, desc) in fams.items():
                S = _axis_columns(prob, ctx, M, s, i, terms)
                out.append({"family": fam, "sensor": s, "axis": AXES[i], "description": desc, "S": S})
    return out


def norm_families(prob: Problem) -> list[dict]:
    """The generic families of the norm model: a bias of one accelerometer axis moving in time (Legendre degree 1
    and 2 of the session time) seen through the norm (dr/dd of each segment)."""
    ng = prob.norm_generic
    if prob.kind != "norm" or ng is None:
        return []
    t = np.asarray(ng["t"], float)
    tau = 2.0 * (t - t.min()) / max(float(np.ptp(t)), 1e-9) - 1.0
    out = []
    for i in range(3):
        S = np.column_stack([ng["G"][:, i] * tau, ng["G"][:, i] * (1.5 * tau**2 - 0.5)])
        out.append({"family": "time", "sensor": "accel", "axis": AXES[i], "description":
                    "accelerometer bias moving in time (Legendre degree 1-2), seen through the norm", "S": S})
    return out


def norm_step_columns(prob: Problem):
    """Norm model: for every segment boundary j (at least two segments on each side), the columns of a step of
    the three accelerometer biases between segment j - 1 and j, seen through the norm: ``[(j, S (m, 3))]``."""
    ng = prob.norm_generic
    if prob.kind != "norm" or ng is None:
        return []
    m = ng["G"].shape[0]
    out = []
    for j in range(2, m - 1):
        H = (np.arange(m) >= j).astype(float)
        out.append((j, ng["G"] * H[:, None]))
    return out


#: periods of the norm model's periodic rival: the session span divided by these
NORM_PERIODS = tuple(k / 4.0 for k in range(4, 33))   # span/1 ... span/8 in quarter steps


def norm_periodic_columns(prob: Problem):
    """Norm model: for every accelerometer axis i and period span/k (:data:`NORM_PERIODS`), the two columns of a
    bias of that axis oscillating in time (sine and cosine), seen through the norm: ``[(i, k, S (m, 2))]``. Few
    static poses taken one after the other can fit an oscillating bias with an attitude-dependent term."""
    ng = prob.norm_generic
    if prob.kind != "norm" or ng is None:
        return []
    # the segments' mid-times are the geometry's: their sines and cosines are computed once per geometry
    waves = prob.geom.derived(("norm", "periodic_waves"), lambda: _periodic_waves(ng["t"]))
    G = ng["G"]
    return [(i, k, np.column_stack([G[:, i] * sn, G[:, i] * cs])) for i in range(3) for k, sn, cs in waves]


def _periodic_waves(t):
    """``[(k, sin(k phase), cos(k phase))]`` over :data:`NORM_PERIODS` at the times ``t``, phase
    2 pi (t - t_0) / span."""
    t = np.asarray(t, float)
    span = max(float(np.ptp(t)), 1e-9)
    ph = 2.0 * math.pi * (t - t.min()) / span
    return [(k, np.sin(k * ph), np.cos(k * ph)) for k in NORM_PERIODS]


def _vector_step_tests(prob: Problem, final: Fit, L, Q, r_perp) -> list[dict]:
    """Vector model: per sensor axis, a step of the bias between two consecutive windows (at least two windows on
    each side), the boundary scanned; the largest chi-square (1 degree of freedom after the final design is
    projected out), Bonferroni over the boundaries. The column of a step is the constant-bias column of the axis
    on the windows after the boundary (a window lies wholly on one side)."""
    if prob.kind != "vector":
        return []
    geom, o = prob.geom, prob.geom.obs
    M, _ = base_estimates(final.theta)
    t_win = np.array([geom.time_s[w.i0] for w in geom.windows])
    order = np.argsort(t_win, kind="stable")
    rank_of = np.empty(len(order), int)
    rank_of[order] = np.arange(len(order))
    obs_rank = rank_of[np.asarray(o["window"])]
    bounds = np.arange(2, len(order) - 1)
    out = []
    for s in SENSORS:
        for i in range(3):
            B = _unit_columns(prob, ("bias", s, i),
                              lambda: _axis_columns(prob, _context(prob), _UNIT_M, s, i, [1.0])[:, 0])
            B = B * M[s][i, i]
            # every boundary at once: column j is the bias column on the windows from rank j on
            C = np.where(obs_rank[:, None] >= bounds[None, :], B[:, None], 0.0)
            live = np.any(C != 0.0, axis=0)
            gw = prob.whiten(C[:, live], L)
            g = gw - Q @ (Q.T @ gw)
            nn = np.sum(g * g, axis=0)
            ok = nn > 1e-12 * np.maximum(np.sum(gw * gw, axis=0), 1e-300)
            n_b = int(np.sum(ok))
            if n_b == 0:
                continue
            c2s = (g[:, ok].T @ r_perp) ** 2 / nn[ok]
            jbest = int(np.argmax(c2s))
            j, c2 = int(bounds[live][ok][jbest]), float(c2s[jbest])
            w0 = geom.windows[order[j]]
            out.append({"family": "step", "sensor": s, "axis": AXES[i],
                        "description": f"bias stepping at t = {geom.time_s[w0.i0]:.0f} s (before window {w0.label})",
                        "chi2": c2, "dof": 1.0, "p": float(min(1.0, n_b * chi2_sf(c2, 1))),
                        "rms": float("nan"), "unit": geom.units_out[s]})
    return out


def _orth(A, tol=1e-9):
    if A.size == 0:
        return np.zeros((A.shape[0], 0))
    u, sv, _ = np.linalg.svd(A, full_matrices=False)
    keep = sv > tol * (sv[0] if sv.size else 0.0)
    return u[:, keep]


def _stop_tests(prob: Problem, r_perp, final: Fit):
    """Per-stop attitude test of the accelerometer static means: residual components perpendicular to the
    gravity direction of each stop against the parallel one (chi-square of the perpendicular part)."""
    geom, o = prob.geom, prob.geom.obs
    si = SENSORS.index("accel")
    stat = [j for j, w in enumerate(geom.windows) if w.kind == "static"]
    if len(stat) < 3:
        return None
    # whitened residual per (window, axis) of the accel static means
    idx = {}
    for (s_, a), ids in o["blocks"].items():
        if s_ != si:
            continue
        for k in ids:
            if geom.windows[o["window"][k]].kind == "static" and o["row"][k] == 0:
                idx[(o["window"][k], a)] = k
    ctx = _context(prob)
    perp = par = 0.0
    n_perp = n_par = 0
    for j in stat:
        if not all((j, a) in idx for a in range(3)):
            continue
        f = ctx.f[ctx.slices[j]].mean(axis=0)
        u = f / max(np.linalg.norm(f), 1e-300)
        z = np.array([r_perp[idx[(j, a)]] for a in range(3)])
        zp = float(z @ u)
        par += zp * zp
        perp += float(z @ z) - zp * zp
        n_par += 1
        n_perp += 2
    if n_par < 3 or par <= 0:
        return None
    F = (perp / n_perp) / (par / n_par)
    p = float(f_sf(F, n_perp, n_par))
    return {"family": "per static stop", "sensor": "accel", "axis": "",
            "description": "static stops scattering perpendicular to gravity more than along it (attitude errors "
                           "of the stops: the table did not stop where the record says)",
            "chi2": perp, "dof": float(n_perp), "statistic": f"F = {F:.3g} on ({n_perp}, {n_par})", "p": p}


def open_search(prob: Problem, final: Fit, alpha: float | None = None) -> dict:
    """Test the final fit's residuals against every generic family (module docstring) on the measured noise.
    Returns ``{"tests": [...], "significant": [...], "alpha", "method"}``; each test has family, sensor, axis,
    description, chi2, dof, p, p_holm, significant, and the RMS (output unit) of the structure it fits."""
    alpha = float(prob.settings.get("adequacy_alpha", 0.01) if alpha is None else alpha)
    if final.X is None or (prob.kind != "vector" and prob.norm_generic is None):
        return {"tests": [], "significant": [], "alpha": alpha, "method": "not run: no design to search beside"}
    L = measured_factors(prob)
    Xw = prob.whiten(final.X, L)
    Q = _orth(Xw)
    rw = prob.whiten(np.asarray(prob.y, float), L)
    r_perp = rw - Q @ (Q.T @ rw)
    tests, sizes = [], []
    for fam in generic_families(prob, final) + norm_families(prob):
        G = prob.whiten(fam["S"], L)
        G = G - Q @ (Q.T @ G)
        U = _orth(G, 1e-7)
        k = U.shape[1]
        if k == 0:
            continue
        proj = U.T @ r_perp
        c2 = float(proj @ proj)
        tests.append({k_: fam[k_] for k_ in ("family", "sensor", "axis", "description")} |
                     {"chi2": c2, "dof": float(k), "p": float(chi2_sf(c2, k)), "rms": None,
                      "unit": prob.geom.units_out[fam["sensor"]]})
        sizes.append((tests[-1], fam, G))
    tests += _vector_step_tests(prob, final, L, Q, r_perp)
    steps = norm_step_columns(prob)
    if steps:
        # a step of the biases at an unknown segment boundary: the largest chi-square over the boundaries,
        # Bonferroni over their number
        best = None
        for j, S in steps:
            G = prob.whiten(S, L)
            G = G - Q @ (Q.T @ G)
            U = _orth(G, 1e-7)
            if U.shape[1] == 0:
                continue
            c2 = float(np.sum((U.T @ r_perp) ** 2))
            if best is None or c2 > best[1]:
                best = (j, c2, U.shape[1])
        if best is not None:
            j, c2, k = best
            tests.append({"family": "step", "sensor": "accel", "axis": "",
                          "description": f"accelerometer biases stepping between static segments {j - 1} and {j}",
                          "chi2": c2, "dof": float(k),
                          "p": float(min(1.0, len(steps) * chi2_sf(c2, k))), "rms": float("nan"),
                          "unit": prob.geom.units_out["accel"]})
    st = _stop_tests(prob, r_perp, final) if prob.kind == "vector" else None
    if st is not None:
        tests.append(st | {"rms": float("nan"), "unit": ""})
    if not tests:
        return {"tests": [], "significant": [], "alpha": alpha, "method": "no generic family could be formed"}
    rej, adj = holm([t["p"] for t in tests], alpha)
    for t, r, a in zip(tests, rej, adj):
        t["p_holm"] = float(a)
        t["significant"] = bool(r)
    detail = prob.settings.get("report_detail", True)
    for t, fam, G in sizes:
        # size of the structure in output units: the generic fit's prediction, unwhitened, RMS over its sensor
        # (without the report's detail, for the significant families only: what the verdict's reason quotes)
        if detail or t["significant"]:
            coef, *_ = np.linalg.lstsq(G, r_perp, rcond=None)
            pred = fam["S"] @ coef
            m = prob.geom.obs["sensor"] == SENSORS.index(fam["sensor"])
            t["rms"] = float(np.sqrt(np.mean(pred[m] ** 2)))
    sig = [t for t in tests if t["significant"]]
    return {"tests": tests, "significant": sig, "alpha": alpha,
            "method": "generic bases projected out of the final design, chi-square of the whitened residual in "
                      "their span on the measured noise; Holm step-down over the families"}


# ----------------------------------------------------------------------------------------------------------
# form alternatives
# ----------------------------------------------------------------------------------------------------------
_TEMPERATURE_VS_TIME = ("a temperature profile that is not monotonic in time (warm the unit, then let it cool) or a "
                        "second session at another temperature separates a temperature coefficient from a drift in "
                        "time")
_WARMUP_VS_WALK = ("a repeat of the session after a cold start, or a long static record of the same unit, separates "
                   "a repeatable warm-up from a random bias walk")
#: rival forms of found terms: (found keys that the rival replaces, rival name, builder id, experiment)
RIVALS = [r for s in ("accel", "gyro") for r in (
    ({f"temperature_sensitivity/{s}"}, f"{'accelerometer' if s == 'accel' else s} scale factor and bias drifting "
     "linearly in time (no temperature dependence)", ("drift", s), _TEMPERATURE_VS_TIME),
    ({f"bias_drift/{s}"}, f"{'accelerometer' if s == 'accel' else s} bias drifting as a random walk or a slow "
     "oscillation (noise, not a warm-up)", ("time", s), _WARMUP_VS_WALK))] + [
    ({"accel_quadratic_nonlinearity/accel", "accel_scale_asymmetry/accel"}, "fourth-order accelerometer "
     "nonlinearity k4 x^4 (with a quadratic term)", ("quartic", "accel"),
     "static positions at more distinct tilts per axis (e.g. 15 or 30 deg steps instead of 45 deg) separate x^4 "
     "from x^2 and |x| x"),
]


def _rival_columns(prob: Problem, final: Fit, builder) -> np.ndarray | None:
    """Columns of the rival form ``builder`` = (kind, sensor) at the final fit's K E (unit columns cached per
    geometry, :func:`_unit_columns`)."""
    kind, sensor = builder
    M, _ = base_estimates(final.theta)
    S, axis = _unit_columns(prob, ("rival", kind, sensor), lambda: _rival_columns_unit(prob, kind, sensor))
    return S * np.diag(M[sensor])[axis][None, :]


def _rival_columns_unit(prob: Problem, kind, sensor):
    """:func:`_rival_columns` at unit scale factors, and the axis of every column."""
    ctx = _context(prob)
    M = _UNIT_M
    x = ctx.f if sensor == "accel" else ctx.w
    xs = x / max(float(np.max(np.abs(x))), 1e-300)
    t = ctx.t
    tau = 2.0 * (t - t.min()) / max(float(np.ptp(t)), 1e-9) - 1.0
    cols, axis = [], []
    for i in range(3):
        if kind == "drift":
            terms = [tau, xs[:, i] * tau]
        elif kind == "quartic":
            terms = [x[:, i] ** 4, x[:, i] ** 2]
        else:  # time
            leg, per = _time_basis(t, float(t.min()), float(np.ptp(t)))
            terms = leg[:2] + per[:4]
        cols.append(_axis_columns(prob, ctx, M, sensor, i, terms))
        axis += [i] * len(terms)
    return np.hstack(cols), np.array(axis)


def _bic_with(prob: Problem, f0: Fit, S: np.ndarray, base=None) -> tuple[float, float]:
    """chi-square and BIC of the fit ``f0`` with the columns ``S`` added (GLS on the problem's noise).
    ``base``: :func:`_whitened_base` of ``f0`` when many column sets are tried against the same fit."""
    return _bic_with_whitened(prob, f0, prob.whiten(S), base)


def _bic_with_whitened(prob: Problem, f0: Fit, Sw: np.ndarray, base=None) -> tuple[float, float]:
    """:func:`_bic_with` of the columns whitened already (``Sw``)."""
    Xw, r0 = base if base is not None else _whitened_base(prob, f0)
    A = np.hstack([Xw, Sw])
    yw = prob.wcache("y", lambda: prob.y)
    coef, _, rank, _ = np.linalg.lstsq(A, yw, rcond=None)   # rank: singular values > max(m, n) eps s_max, as
    r = yw - A @ coef                                           # numpy.linalg.matrix_rank counts them
    chi2 = float(r @ r)
    extra = int(rank) - r0
    return chi2, chi2 + (f0.k + extra) * math.log(prob.n)


#: a rival set is solved by lstsq in any case when a lower bound of the smallest singular value of [design, columns]
#: is below this fraction of their Frobenius norm (lstsq's rank cut is max(m, n) eps of the largest)
_SAFE_SV = 1e-10
#: the chi-square found by projection and lstsq's are taken to lie within this times (1 + the condition number bound)
#: times the whitened data's sum of squares of each other (a backward-stable least-squares residual moves by about
#: eps (1 + 2 kappa) |y|; this is some 4500 eps: room for the size of the problem)
_CHI2_REL = 1e-12


def _best_rival(prob: Problem, f0: Fit, base, cands) -> tuple[str, float, float]:
    """``(name, chi2, BIC)`` of the smallest BIC over the rival column sets ``cands`` = ``[(name, Sw, extra)]``
    (whitened columns; ``extra``: BIC added for a scanned parameter, or None): what the first smallest of
    :func:`_bic_with_whitened` over every set is. Only the sets that can be smallest are solved by lstsq: every
    set's BIC is first found by projection within a tolerance (:func:`_projected_bics`), and a set whose BIC so found
    lies, less its tolerance, above the smallest BIC plus tolerance of any set cannot be smallest (lstsq's values of
    the others are the result: the same numbers). A set whose rank the projection cannot vouch for is solved by
    lstsq; when lstsq's BIC of a set lies outside the projection's tolerance, every set is."""
    def solved(j):
        name, Sw, extra = cands[j]
        chi2, bic = _bic_with_whitened(prob, f0, Sw, base)
        return name, chi2, bic if extra is None else bic + extra

    def smallest(js):
        return min((solved(j) for j in js), key=lambda c: c[2])

    every = range(len(cands))
    proj = _projected_bics(prob, f0, base, cands)
    if proj is None:
        return smallest(every)
    bic, tol, safe = proj
    top = float(np.min((bic + tol)[safe])) if safe.any() else math.inf
    pick = [j for j in every if not safe[j] or bic[j] - tol[j] <= top]
    got = [solved(j) for j in pick]
    if any(safe[j] and not abs(g[2] - bic[j]) <= tol[j] for j, g in zip(pick, got)):
        return smallest(every)
    return min(got, key=lambda c: c[2])


def _projected_bics(prob: Problem, f0: Fit, base, cands):
    """BIC of the fit ``f0`` with each column set of ``cands`` added (:func:`_best_rival`), by projection: the
    residual of the data off ``f0``'s whitened design (an SVD of the design), less its part in the span of each set's
    columns with the design projected out (an SVD per set, the sets of equal width at once), and the set's width as
    its extra rank. Returns ``(bic, tol, safe)``: the tolerance of each (:data:`_CHI2_REL`, with the bound of the
    condition number of [design, columns] from the two SVDs: 1/s_min <= 1/s_X + |C|/(s_X s_P) + 1/s_P, C the
    columns' part in the design's span), and ``safe`` where the width is the rank lstsq finds (that bound of s_min
    above :data:`_SAFE_SV` of the norm); None when the design is rank deficient or a value is not finite."""
    Xw, r0 = base
    m, p = Xw.shape
    if r0 != p or p >= m:
        return None
    u, s, _ = np.linalg.svd(Xw, full_matrices=False)
    yw = prob.wcache("y", lambda: prob.y)
    r = yw - u @ (u.T @ yw)
    rr = float(r @ r)
    yy = float(yw @ yw)
    xf2 = float(np.sum(Xw * Xw))
    logn = math.log(prob.n)
    n = len(cands)
    bic, tol, safe = np.empty(n), np.empty(n), np.zeros(n, bool)
    groups = {}
    for j, (_, Sw, _) in enumerate(cands):
        groups.setdefault(Sw.shape[1], []).append(j)
    for w, js in groups.items():
        S = np.stack([cands[j][1] for j in js])
        C = u.T @ S
        up, sp, _ = np.linalg.svd(S - u @ C, full_matrices=False)
        c = np.einsum("kmw,m->kw", up, r)
        norm = np.sqrt(xf2 + np.sum(S * S, axis=(1, 2)))
        with np.errstate(divide="ignore", invalid="ignore"):
            s_lo = 1.0 / (1.0 / s[-1] + np.sqrt(np.sum(C * C, axis=(1, 2))) / (s[-1] * sp[:, -1]) + 1.0 / sp[:, -1])
        safe[js] = (w + p <= m) & (s_lo > _SAFE_SV * norm)
        tol[js] = _CHI2_REL * (1.0 + norm / s_lo) * yy
        extra = np.array([0.0 if cands[j][2] is None else cands[j][2] for j in js])
        bic[js] = rr - np.sum(c * c, axis=1) + (f0.k + w) * logn + extra
    safe &= np.isfinite(tol)
    if not (np.all(np.isfinite(bic)) and math.isfinite(yy)):
        return None
    return bic, tol, safe


def _whitened_base(prob: Problem, f0: Fit):
    """The whitened design of ``f0`` and its rank (what :func:`_bic_with` needs of the fit it extends)."""
    Xw = prob.whiten(f0.X)
    return Xw, int(np.linalg.matrix_rank(Xw))


def generic_rivals(prob: Problem, final: Fit) -> list[dict]:
    """Norm model: each found term replaced by a generic bias model (no physics named; module docstring): biases
    moving in time, stepping (all three or one axis) or one axis oscillating. When that fits as well (BIC within
    ``generic_delta_bic``), the data do not establish the term: few static poses taken one after the other cannot
    tell an attitude-dependent term from a bias that moved during the session."""
    fams = norm_families(prob)
    if not fams or not final.terms:
        return []
    dbic = float(prob.settings.get("generic_delta_bic", 6.0))
    # every rival's columns whitened at once for all the found terms (the norm model's rows are one block, whitened
    # column by column: a column of these is the whitening of that column alone)
    steps, periodic = norm_step_columns(prob), norm_periodic_columns(prob)
    mats = [np.hstack([f["S"] for f in fams])] + [S for _, S in steps] + [S for _, _, S in periodic]
    ends = np.cumsum([0] + [S.shape[1] for S in mats])
    W = prob.whiten(np.hstack(mats))
    drift, *rest = [W[:, a:b] for a, b in zip(ends[:-1], ends[1:])]
    steps = [(j, S) for (j, _), S in zip(steps, rest)]
    periodic = [(i, per, S) for (i, per, _), S in zip(periodic, rest[len(steps):])]
    out = []
    for k in final.terms:
        rest = [t for t in final.terms if t != k]
        f0 = fit(prob, rest, taus={t: v for t, v in final.taus.items() if t in rest}) if rest else fit(prob, [])
        b0 = _whitened_base(prob, f0)
        cands = [("accelerometer biases drifting in time (Legendre degree 1-2; a generic basis, no physics named)",
                  drift, None)]
        for j, S in steps:
            cands.append((f"accelerometer biases stepping between static segments {j - 1} and {j} (a generic "
                          "basis, no physics named)", S, math.log(prob.n)))   # + the step time
        for j, S in steps:
            for i in range(3):   # one axis stepping: a bias jump of a single accelerometer
                cands.append((f"accelerometer {AXES[i]} bias stepping between static segments {j - 1} and {j} (a "
                              "generic basis, no physics named)", S[:, i:i + 1], math.log(prob.n)))
        for i, per, S in periodic:
            cands.append((f"accelerometer {AXES[i]} bias oscillating with period span/{per:g} (a generic basis, no "
                          "physics named)", S, math.log(prob.n)))              # + the period
        name, chi2, bic = _best_rival(prob, f0, b0, cands)
        if bic <= final.bic(prob.n) + dbic:
            out.append({"replaces": [k], "alternative": name, "generic": True, "chi2": chi2,
                        "chi2_found": final.chi2, "delta_bic": bic - final.bic(prob.n),
                        "experiment": "repeat the poses in another order (or return to the first pose at the end): "
                                      "an attitude-dependent term repeats with the pose, a bias moving in time does "
                                      "not"})
    return out


def form_alternatives(prob: Problem, final: Fit) -> list[dict]:
    """Rival forms of the found terms that fit this path as well (module docstring)."""
    if prob.kind == "norm":
        return generic_rivals(prob, final)
    if prob.kind != "vector" or not final.terms:
        return []
    n = prob.n
    dbic = float(prob.settings.get("alias_delta_bic", 2.0))
    out = []
    for keys, name, builder, experiment in RIVALS:
        hit = [k for k in final.terms if k in keys]
        if not hit:
            continue
        rest = [k for k in final.terms if k not in keys]
        f0 = fit(prob, rest, delta=final.delta if "time_offset" in rest else None,
                 taus={k: v for k, v in final.taus.items() if k in rest})
        chi2, bic_alt = _bic_with(prob, f0, _rival_columns(prob, final, builder))
        bic_fin = final.bic(n)
        if bic_alt <= bic_fin + dbic:
            out.append({"replaces": sorted(hit), "alternative": name, "chi2": chi2, "chi2_found": final.chi2,
                        "delta_bic": bic_alt - bic_fin, "experiment": experiment})
    return out
