"""The Cramér–Rao bound beside every estimate the diagnosis reports: the Fisher information of the window
reductions it observes, under the noise it measured, computed without the estimator.

The diagnosis observes window reductions ``o = W^T N`` of the rate readings N (:mod:`calib.diagnosis.geometry`:
static means, whole-revolution means and gyro table-angle harmonics). Their expected value is a function of the
parameters -- the 24 base parameters of ``N = M x + b`` and the found terms' -- whose derivatives are the base
design and the library's signatures (:mod:`calib.diagnosis.library`: the registry's terms at the window samples,
reduced like the data). Their noise is the noise the diagnosis measured per sensor axis
(:class:`calib.diagnosis.noise.NoiseFit`): white rate noise of density N, the pulse counter's carried remainder Q
and a slow part (a first-order Gauss-Markov bias of correlation time Tc, or a random walk). This module forms, per
sensor axis, the exact covariance of the reductions under that noise from the per-sample reduction weights
(:func:`reduction_covariance`: no window-mean closed form, no random-walk equivalent of the diagnosis's own noise
model) and the Gaussian Fisher information

    J = sum over sensor axes of D_r^T Sigma_r^-1 D_r,

``D_r`` the derivatives of the reductions of that axis. No fit runs here and no residual is read: the information
is evaluated at the reported point (the base scale factors and misalignments the signatures are built at, the
profiled warm-up time constant and clock offset, the warm-up amplitudes that set the information about the time
constant). The profiled shape parameters (the warm-up time constant of a bias drift) are free columns of ``J``, as in
the proof's bound of the same reductions, so the bounds of the warm-up amplitudes include what not knowing it costs.
``sigma_crb`` of a parameter is ``sqrt((J^-1)_ii)`` with every other column free (the base parameters as nuisances);
a parameter a combination of the others can replace (:func:`calib.core.information.seen_inverse`) gets no number.
"""
from __future__ import annotations

import functools
import math

import numba
import numpy as np
from scipy import linalg

from calib.core.information import seen_inverse
from calib.diagnosis.analysis import ASYMMETRY_FACTOR
from calib.diagnosis.geometry import SENSORS, TO_MODEL, rows_of
from calib.diagnosis.library import _reduce_term, sample_context, zero_params
from calib.diagnosis.problem import Fit, Problem, base_estimates
from calib.sim import effects

#: relative tolerance of a combination the information does not see (eigenvalue of the unit-diagonal information
#: below this times the largest), as :func:`calib.sim.fisher.bounds_from`
NULL_TOL = 1e-9
#: relative step of the central difference of a profiled time constant
SHAPE_STEP = 1e-3
#: why a parameter has no bound
NOT_DETERMINED = ("the information of the window reductions does not determine it: a combination of the other "
                  "parameters (base model, found terms) changes every reduction as it does")
NO_SIGNATURE = "it changes no window reduction of this path (its signature is zero)"
NOT_ESTIMATED = ("not estimated by the diagnosis (held at zero: its signature is weak beside the term's other "
                 "parameters or mostly absorbed by the base model, see identifiability): sigma_crb is its bound were "
                 "it estimated beside them, which widens theirs")

WHAT = ("Cramér–Rao bound (1 sigma) of each reported estimate: sqrt of the diagonal of the inverse Gaussian Fisher "
        "information of the window reductions the diagnosis observes (static means, whole-revolution means and gyro "
        "table-angle harmonics), J = sum over sensor axes of D^T Sigma^-1 D, computed without the estimator (no fit, "
        "no residuals)")
OBSERVATIONS = ("the window reductions of the recording's own segment table and table angle; D their derivatives "
                "(the base design and the found terms' signatures at the reported point). The samples outside the "
                "windows (moves, spin-up and spin-down, partial revolutions) are in no reduction: the bound is that of "
                "the reductions, not of the sample stream")
NOISE = ("the noise the diagnosis measured, per sensor axis: white rate noise N, the pulse counter's carried "
         "remainder Q and the slow part (Gauss-Markov bias of correlation time Tc, or random walk); Sigma the exact "
         "covariance of the reductions under it, from the per-sample reduction weights")
NUISANCES = ("the 24 base parameters (M = K E and b per triad) and every parameter the diagnosis estimates of the "
             "found terms are free, those it holds at zero are held (as fitted); a bias drift's warm-up time constant "
             "(profiled by the diagnosis) is a free column, its derivative at the estimated warm-up amplitudes")
RATIO = "se_over_crb = the estimator's standard error (se) / sigma_crb; 1 is efficient on these observations"
STREAM = {"computed": False,
          "why": ("the stream bound (every sample under the exact noise covariance) needs the per-sample path outside "
                  "the windows (moves, ramps), which the diagnosis's geometry does not hold; the proof's tables give "
                  "it for synthetic sessions (calib.studies.diagnosis_efficiency)")}


def _first_order(w, a):  # pragma: no cover - compiled
    """``y_i = w_i + a y_i-1`` (y_-1 = 0): the first-order recursion of a Gauss-Markov bias over a window (what
    ``scipy.signal.lfilter([1], [1, -a], w)`` computes, bit for bit, without loading scipy.signal)."""
    y = np.empty_like(w)
    acc = 0.0
    for i in range(w.size):
        acc = w[i] + a * acc
        y[i] = acc
    return y


@functools.cache
def _compiled_first_order():
    """:func:`_first_order` compiled (numba, cached on disk) at its first use: setting up the compiled function
    costs about 10 ms, which a diagnosis that finds nothing never needs."""
    return numba.njit(cache=True, nogil=True)(_first_order)


def reduction_covariance(rows, white: float, gm_var: float, a: float, quant, rw_var: float = 0.0) -> np.ndarray:
    """Covariance ``W^T Sigma W`` of window reductions ``rows`` ((i0, i1, weights) each, in time order) under the
    exact noise of one channel: white noise of variance ``white`` per sample, a first-order Gauss-Markov bias with
    autocovariance ``gm_var a^|k|``, the pulse counter's carried remainder (``r_k-1 - r_k``; ``quant`` times the
    variance 1/12 of a uniform remainder: autocovariance ``quant/6``, ``-quant/12`` at lag 1; True / False for
    counts) and a random walk of increment variance ``rw_var`` per sample. The bias terms between windows factor
    (``a^(j - i)`` over disjoint supports), within a window they are two first-order recursions. The random walk
    starts at the first window's first sample: its level there is a constant on every sample, which a free bias
    parameter absorbs (the bound of every other parameter is the same)."""
    m = len(rows)
    q_scale = float(quant)
    gm = bool(gm_var)
    u, v, filt, dq = np.zeros(m), np.zeros(m), [], []
    for r, (i0, i1, w) in enumerate(rows):
        if gm:
            pw = a ** np.arange(i1 - i0)
            u[r] = w @ pw[::-1]              # sum_i w_i a^(i1 - 1 - i): the weights seen from the window's end
            v[r] = w @ pw                    # sum_j w_j a^(j - i0): from its start
            fwd = _compiled_first_order()(w, a)
            bwd = _compiled_first_order()(w[::-1], a)[::-1]
            filt.append(fwd + bwd - w)       # sum_j a^|i - j| w_j within the window
        dq.append(np.diff(np.concatenate([[0.0], w, [0.0]])))   # sum_k w_k (r_k-1 - r_k) = -sum_j r_j dq_j
    i0s = np.array([r[0] for r in rows])
    i1s = np.array([r[1] for r in rows])
    later = i0s[None, :] > i0s[:, None]                        # row q's window after row r's
    gap = np.where(later, i0s[None, :] - (i1s[:, None] - 1), 0)
    M = np.where(later, gm_var * np.outer(u, v) * a ** gap, 0.0) if gm else np.zeros((m, m))
    if q_scale:                                                # adjacent windows share one carried remainder
        for r, q in zip(*np.nonzero(later & (gap == 1))):
            M[r, q] += dq[r][-1] * dq[q][0] / 12.0 * q_scale
    if rw_var:
        # b_k = sum_{j <= k} e_j: Cov(o, p) = rw_var sum_j T_o(j) T_p(j), T_o(j) = sum_{i >= j} w_oi; for a window
        # wholly before another, T_p = its weight sum over the earlier one's support
        start = int(i0s.min())
        tails = [np.cumsum(w[::-1])[::-1] for _, _, w in rows]
        tot = np.array([t[0] for t in tails])
        U = np.array([(i0 - start) * t[0] + t[1:].sum() + t[0] for (i0, _, _), t in zip(rows, tails)])
        M += np.where(later, rw_var * np.outer(U, tot), 0.0)
    Sr = M + M.T
    for r, (i0, i1, w) in enumerate(rows):                     # rows of one window (its mean and harmonics)
        for q in np.flatnonzero((i0s == i0) & (i1s == i1)):
            Sr[r, q] = white * float(w @ rows[q][2]) + (gm_var * float(w @ filt[q]) if gm else 0.0) + \
                (float(dq[r] @ dq[q]) / 12.0 * q_scale if q_scale else 0.0)
            if rw_var:
                Sr[r, q] += rw_var * ((i0 - start) * tot[r] * tot[q] + float(tails[r] @ tails[q]))
    return Sr


def window_rows(geom, sensor: str) -> list:
    """``(i0, i1, weights)`` of every observation of one axis of ``sensor``, in the order of its block of
    observations (windows in time order, the rows of a window together)."""
    return [(w.i0, w.i1, np.ascontiguousarray(w.W[:, q])) for w in geom.windows for q in range(rows_of(sensor, w))]


def axis_noise(nz, sensor: str, axis: int, dt: float) -> dict:
    """The per-sample noise of one sensor axis of the rate readings from the diagnosis's noise ``nz``
    (:class:`calib.diagnosis.noise.NoiseFit`), as the arguments of :func:`reduction_covariance`: white variance
    ``N^2 / dt``, carried remainder variance ``Q^2 / dt^2`` (``quant``: in units of 1/12), the Gauss-Markov bias
    (stationary variance ``sigma^2``, ``a = exp(-dt / Tc)``) or the random walk (``K^2 dt`` per sample)."""
    tc, sig = nz.slow[sensor][axis]
    out = {"white": float(nz.N[sensor][axis]) ** 2 / dt, "quant": 12.0 * float(nz.Q[sensor][axis]) ** 2 / dt ** 2,
           "gm_var": 0.0, "a": 0.0, "rw_var": 0.0}
    if sig > 0 and math.isinf(tc):
        out["rw_var"] = float(sig) ** 2 * dt
    elif sig > 0:
        out["gm_var"], out["a"] = float(sig) ** 2, math.exp(-dt / float(tc))
    return out


def information(geom, nz, X, factors: dict | None = None) -> np.ndarray:
    """Fisher information ``sum D^T Sigma^-1 D`` of the observation columns ``X`` (n_obs, p) over the six sensor-axis
    blocks of ``geom`` under the noise ``nz`` (:func:`axis_noise`, :func:`reduction_covariance`); a block no column
    touches is skipped. ``factors``: the Cholesky factors of the blocks' covariances, filled and reused (one noise,
    several designs)."""
    X = np.asarray(X, float)
    factors = {} if factors is None else factors
    J = np.zeros((X.shape[1], X.shape[1]))
    for (si, a), idx in geom.obs["blocks"].items():
        D = X[idx]
        use = np.flatnonzero(np.any(D != 0.0, axis=0))
        if use.size == 0:
            continue
        if (si, a) not in factors:
            factors[(si, a)] = np.linalg.cholesky(
                reduction_covariance(window_rows(geom, SENSORS[si]), **axis_noise(nz, SENSORS[si], a, geom.dt)))
        A = linalg.solve_triangular(factors[(si, a)], D[:, use], lower=True)
        J[np.ix_(use, use)] += A.T @ A
    return J


def bounds_from(J: np.ndarray, n: int) -> list:
    """``(bound or None, reason)`` of the first ``n`` parameters of information ``J`` with every other column free;
    None (with the reason) for a parameter the information does not determine."""
    d = np.diag(J)
    null, inv, s = seen_inverse(J, NULL_TOL, var_floor=1e-300)
    out = []
    for r in range(n):
        if not d[r] > 0:
            out.append((None, NO_SIGNATURE))
        elif null.size and np.linalg.norm(null[r]) > 1e-6:
            out.append((None, NOT_DETERMINED))
        else:
            out.append((float(math.sqrt(inv[r, r]) / s[r]), ""))
    return out


def _drift_tau_column(prob: Problem, M: dict, key: str, tau: float, amp: np.ndarray) -> np.ndarray:
    """Derivative of the reductions with respect to the warm-up time constant of bias drift ``key`` at ``tau`` with
    warm-up amplitudes ``amp`` (3,): central differences of the registry's term at the window samples, reduced like
    the library's signatures (at the base ``M``)."""
    geom = prob.geom
    sensor = prob.cand(key).sensor
    ctx = sample_context(geom)
    pre = "accel" if sensor == "accel" else "gyro"
    wkey = f"{pre}_warmup_{'ug' if sensor == 'accel' else 'deg_h'}"
    KE = np.asarray(M[sensor], float)
    Kd = np.diag(KE).copy()
    Em = {s: np.asarray(M[s], float) / np.diag(np.asarray(M[s], float))[:, None] for s in SENSORS}
    tctx = ctx.temperature if ctx.temperature is not None else np.full(ctx.t.shape, 25.0)
    sctx = effects.SensorContext(ctx.t, ctx.f, ctx.w, effects.rows_times(ctx.f, Em["accel"]),
                                 effects.rows_times(ctx.w, Em["gyro"]), ctx.w_nb, ctx.dw_nb, tctx, Em["accel"],
                                 Em["gyro"])
    h = SHAPE_STEP * tau
    out = []
    for t in (tau + h, tau - h):
        p = zero_params("bias_drift")
        p.update({f"{pre}_tau_s": t, wkey: [float(x) for x in amp]})
        da, dg = effects.REGISTRY["bias_drift"].apply(sctx, p)
        out.append(_reduce_term(geom, ctx, da if sensor == "accel" else dg, sensor, Kd,
                                TO_MODEL[geom.units_in[sensor]]))
    return (out[0] - out[1]) / (2.0 * h)


def _term_columns(prob: Problem, final: Fit, key: str, M: dict):
    """(every parameter name of term ``key``, its columns at the reported point (n_obs, p), the shape columns)."""
    c = prob.cand(key)
    if c.kind == "offset":
        return list(c.names), c.offset.design_delta(float(final.delta), M, deriv=1)[:, None], []
    if c.kind != "drift":
        return list(c.names), np.asarray(c.S, float), []
    tau = final.taus.get(key, 900.0)
    S = np.asarray(c.S_by_tau[tau], float)
    act = np.asarray(final.active.get(key, c.active)).tolist()
    amp = np.zeros(3)
    for j, v in zip(act, final.theta[final.slices[key]]):
        if j < 3:                                   # the warm-up amplitudes (the trends follow)
            amp[j] = v
    shape = [] if not np.any(amp) else [_drift_tau_column(prob, M, key, tau, amp)]
    return list(c.names), S, shape


def _patched_base(prob: Problem, final: Fit) -> np.ndarray:
    """The base design at the reported clock offset (the table inputs at the shifted times) when one is found."""
    if "time_offset" in final.terms:
        return prob.cand("time_offset").offset.patch_design(prob.X0, float(final.delta))
    return prob.X0


def attach_bounds(prob: Problem, final: Fit, found: list, base_parameters: list) -> dict:
    """Add ``sigma_crb`` and ``se_over_crb`` to every parameter of every ``found`` term of the final fit ``final``
    (the internal model parameter of an asymmetry too; as fitted: the parameters the diagnosis estimates free, those
    it holds at zero held) and to every entry of ``base_parameters`` (bounds of the base model alone, as their
    ``se_before``), and a ``bounds_not_estimated`` list per found term (the parameters it holds at zero: their bound
    were they estimated, or None and why not); returns the report's ``bounds`` block. Nothing is computed when
    nothing was found or the model is not the vector model (the norm model observes nonlinear norms of the static
    means)."""
    block = {"what": WHAT, "observations": OBSERVATIONS, "noise": NOISE, "nuisances": NUISANCES, "ratio": RATIO,
             "stream_bound": STREAM}
    if not found:
        return {**block, "computed": False, "why": "no term found: no estimate beyond the base model to bound"}
    if prob.kind != "vector" or prob.noise is None:
        return {**block, "computed": False,
                "why": ("the norm model observes nonlinear norms of the static means under a noise scaled by the base "
                        "fit's reduced chi-square, not a per-sensor-axis noise model: no bound is computed")}
    try:
        return {**block, **_attach(prob, final, found, base_parameters)}
    except (np.linalg.LinAlgError, ValueError) as exc:     # a bound never changes the diagnosis: it says why not
        for ent in [p for f in found for p in f["parameters"]] + list(base_parameters):
            for e in (ent, ent.get("internal_model_parameter") or {}):
                for k in ("sigma_crb", "se_over_crb", "crb_note"):
                    e.pop(k, None)
        for f in found:
            f.pop("bounds_not_estimated", None)
        return {**block, "computed": False,
                "why": f"the information of the window reductions could not be formed or inverted ({exc})"}


def _attach(prob: Problem, final: Fit, found: list, base_parameters: list) -> dict:
    """:func:`attach_bounds` on the vector model with something found."""
    M, _ = base_estimates(final.theta)
    X0 = _patched_base(prob, final)
    names, cols, shapes, spans, fitted = [], [], [], {}, []
    for k in final.terms:
        nm, S, sh = _term_columns(prob, final, k, M)
        c = prob.cand(k)
        act = set(np.asarray(final.active.get(k, c.active)).tolist()) if c.kind != "offset" else {0}
        spans[k] = (len(names), nm)
        fitted += [len(names) + j for j in range(len(nm)) if j in act]
        names += nm
        cols.append(S)
        shapes += sh
    n_terms = len(names)
    X = np.column_stack(cols + [np.asarray(s)[:, None] for s in shapes] + [X0])
    factors = {}
    J = information(prob.geom, prob.noise, X, factors)
    rest = list(range(n_terms, X.shape[1]))
    # as fitted: the parameters the diagnosis estimates free, the ones it holds at zero held (the proof's convention)
    b_fit = dict(zip(fitted, bounds_from(J[np.ix_(fitted + rest, fitted + rest)], len(fitted))))
    b_all = bounds_from(J, n_terms)            # every parameter of the found terms free
    for f in found:
        start, nm = spans[f["key"]]
        for p in f["parameters"]:
            inner = p.get("internal_model_parameter")
            j = nm.index(inner["name"] if inner else p["name"])
            b, why = b_fit[start + j]
            for ent, k in ((p, ASYMMETRY_FACTOR), (inner, 1.0)) if inner else ((p, 1.0),):
                _set(ent, None if b is None else k * b, why)
        f["bounds_not_estimated"] = [
            {"name": n, "sigma_crb": b_all[start + j][0],
             "note": b_all[start + j][1] or NOT_ESTIMATED}
            for j, n in enumerate(nm) if start + j not in b_fit]
    nb = len(base_parameters)
    b_base = bounds_from(information(prob.geom, prob.noise, prob.X0, factors), prob.X0.shape[1])
    for ent, (b, why) in zip(base_parameters, b_base[:nb]):
        _set(ent, b, why, se_key="se_before")
    return {"computed": True, "n_parameters": len(fitted) + len(shapes) + X0.shape[1],
            "shape_parameters_free": len(shapes)}


def _set(ent: dict, b, why: str, se_key: str = "se") -> None:
    ent["sigma_crb"] = b
    ent["se_over_crb"] = (float(ent[se_key]) / b) if b else None
    if b is None:
        ent["crb_note"] = why
