"""Cramér–Rao bound of a triad's calibration parameters (Liu 2021: N = K E x + b) from the segment means.

How precisely *could* any unbiased estimator determine K, E and b of one triad from the data a calibration
sees? The answer depends on the measurement model and the noise alone; this module computes it without running
an estimator (no optimiser, no fit, no residuals).

Data and model
--------------
The observations are window means of the rate reading (static positions, whole-revolution rotation windows),
per output axis i (the axes' noise is independent)::

    y_m,i = M_i . x_m + b_i + n_m,i,        n_.,i ~ N(0, C_i)

* ``M = K E`` (3 x 3), ``b`` (3,): the 12 parameters, written ``theta = [vec(M) row-major, b]``.
* ``x_m`` the window's mean input in the body frame [input unit]. Two ways to know it:

  - ``vector``: x_m known (nominal table attitudes, table rate): the classical calibration's and eq. 25's model;
  - ``norm``: only |x_m| known (g, or the table rate / Earth rate), its direction is an unknown nuisance
    (two angles per window). This is the information the norm objectives (Liu 2021 eqs. 7 and 26) work with:
    they see only |M^-1 (y - b)| or |y+ - y-|.

* ``C_i`` (n x n): the covariance of the window means of axis i from a noise model
  (:class:`calib.signal.noisecov.MeanNoiseModel`: white rate noise, quantisation and the slow Gauss-Markov /
  random-walk bias, correlated between windows), from the simulator's noise densities or measured on a recording.

Gaussian noise whose covariance does not depend on theta: the Fisher information is ``F = sum_i J_i^T C_i^-1 J_i``
over [theta, nuisance] (J_i the derivatives of the means of axis i), and the nuisance directions are profiled
out by the Schur complement (the information on theta when the directions are unknown).

What the data do not determine
------------------------------
In the ``norm`` model a rotation of the whole triad, M -> M R, moves every input direction and leaves every norm
unchanged: F has (at least) a 3-dimensional null space and the paper's 12 parameters (K, the six installation
errors) are not determined individually. A parameter or function is *determined* when no null direction moves it
(its bound is then the inverse of the information restricted to the seen combinations); otherwise its bound is
``inf`` and it is reported as not determined, never as a number. What the norm determines is M M^T and b, i.e. the
lower-triangular (Cholesky) gauge ``tri9`` of :mod:`calib.calibration.objectives`; its bound is ``G F^+ G^T`` with
G the derivative of the gauge map (an estimable function: G is orthogonal to the null space).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from calib.calibration import objectives as ob
from calib.core.information import seen_inverse
from calib.core.triad import PARAM_NAMES

#: eigenvalues of the unit-diagonal information below this share of the largest are structural null directions
#: (the rotation of the norm model cancels to round-off, ~1e-15)
NULL_TOL = 1e-10
#: a parameter (or function) with a component above this in a null direction is not determined
NULL_COMPONENT = 1e-6
THETA_NAMES = tuple(f"M[{'xyz'[i]},{'xyz'[j]}]" for i in range(3) for j in range(3)) + ("bx", "by", "bz")
FORMS = ("paper12", "tri9")
OBSERVE = ("vector", "norm")


@dataclass
class Observations:
    """Window means of one triad as the bound sees them: inputs ``x`` (n, 3) [input unit], ``cov`` (3, n, n) the
    covariance of the means per output axis [output unit^2], ``bias`` (n,) bool (False for a difference of two
    windows, which cancels b). ``source`` says which windows."""

    x: np.ndarray
    cov: np.ndarray
    bias: np.ndarray
    source: str = ""

    @property
    def n(self) -> int:
        return self.x.shape[0]


@dataclass
class CalibrationBound:
    """The Cramér–Rao bound of one triad's parameters in one form.

    ``sigma`` (p,) 1-sigma bound, ``inf`` where the data do not determine the parameter; ``determined`` (p,);
    ``covariance`` (p, p) (NaN rows/columns for the undetermined); ``fisher`` (12, 12) the information on
    [vec(M), b] with the nuisance directions profiled out; ``null`` (12, k) the combinations of [vec(M), b] the
    data do not see (scaled to unit information diagonal)."""

    sensor: str
    form: str
    observe: str
    names: tuple
    sigma: np.ndarray
    determined: np.ndarray
    covariance: np.ndarray
    fisher: np.ndarray
    null: np.ndarray
    n_windows: int
    source: str = ""

    def as_dict(self) -> dict:
        """{name: sigma or None (not determined)}."""
        return {n: (float(s) if d else None) for n, s, d in zip(self.names, self.sigma, self.determined)}

    def describe(self, name: str) -> str:
        """The bound of ``name`` as text: the number, or why there is none."""
        k = self.names.index(name)
        if self.determined[k]:
            return f"{self.sigma[k]:.4g}"
        return ("not determined: a rotation of the whole triad leaves every norm unchanged (the norm sees only "
                "(K E)(K E)^T and b)" if self.observe == "norm" else "not determined by these windows")


def _tangents(x):
    """Two unit vectors orthogonal to each row of ``x`` (n, 3): (n, 2, 3)."""
    u = x / np.linalg.norm(x, axis=1, keepdims=True)
    e = np.eye(3)[np.argmin(np.abs(u), axis=1)]
    t1 = np.cross(u, e)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(u, t1)
    return np.stack([t1, t2], axis=1)


def jacobians(M, obs: Observations, observe: str):
    """Per output axis i, d(mean of axis i)/d[theta (12), nuisance (2 n if norm)]: (3, n, 12 + q)."""
    if observe not in OBSERVE:
        raise ValueError(f"observe = {observe!r}: expected one of {', '.join(OBSERVE)}")
    M = np.asarray(M, dtype=float)
    x = np.asarray(obs.x, dtype=float)
    n = x.shape[0]
    q = 2 * n if observe == "norm" else 0
    J = np.zeros((3, n, 12 + q))
    for i in range(3):
        J[i, :, 3 * i:3 * i + 3] = x
        J[i, :, 9 + i] = np.asarray(obs.bias, dtype=float)
    if q:
        # x_m = |x_m| u_m: a turn of u_m by a small angle along t_k moves the mean by |x_m| M t_k
        T = _tangents(x) * np.linalg.norm(x, axis=1)[:, None, None]  # (n, 2, 3)
        D = np.einsum("ij,nkj->ink", M, T)  # (3, n, 2)
        for m in range(n):
            J[:, m, 12 + 2 * m:14 + 2 * m] = D[:, m, :]
    return J


def information(M, observations, observe: str) -> np.ndarray:
    """Fisher information (12, 12) on [vec(M) row-major, b] of the window means ``observations`` (a list of
    :class:`Observations` of one triad, independent of one another) under ``observe`` ('vector' | 'norm'), the
    nuisance directions of the norm model profiled out (Schur complement)."""
    F = np.zeros((12, 12))
    for obs in observations:
        J = jacobians(M, obs, observe)
        Fo = np.zeros((J.shape[2], J.shape[2]))
        for i in range(3):
            c = scipy.linalg.cho_factor(np.asarray(obs.cov[i], dtype=float))
            Fo += J[i].T @ scipy.linalg.cho_solve(c, J[i])
        Ftt, Ftn, Fnn = Fo[:12, :12], Fo[:12, 12:], Fo[12:, 12:]
        if Fnn.size:
            Ftt = Ftt - Ftn @ np.linalg.solve(Fnn, Ftn.T)
        F += Ftt
    return 0.5 * (F + F.T)


def _null_and_inverse(F):
    """(null (12, k) in unit-diagonal coordinates, pseudo-inverse of F on the seen combinations, scale)."""
    # a parameter the data do not touch at all keeps a scale of 1e-8 of the largest: its column is zero whatever s
    null, inv, s = seen_inverse(F, NULL_TOL, rel_floor=1e-8)
    return null, inv / np.outer(s, s), s


def gauge_jacobian(M, b, form: str):
    """(parameters of ``form`` (p,), d parameters / d[vec(M), b] (p, 12)) at the true M, b.

    ``paper12``: [K, E offdiag, b] of M itself (Liu 2021 eq. 8). ``tri9``: of the lower-triangular factor L of
    M M^T (the norm's gauge): dL = L Phi(L^-1 dS L^-T), dS = dM M^T + M dM^T, Phi = the lower triangle with the
    diagonal halved."""
    M = np.asarray(M, dtype=float)
    b = np.asarray(b, dtype=float)
    G = np.zeros((12 if form == "paper12" else 9, 12))
    if form == "paper12":
        G[:9, :9] = ob.paper_jacobian(M)
        G[9:, 9:] = np.eye(3)
        return ob.paper_vector(M, b), G
    if form != "tri9":
        raise ValueError(f"form = {form!r}: expected one of {', '.join(FORMS)}")
    L, _ = ob.lower_triangular_gauge(M)
    Li = np.linalg.inv(L)
    dL = np.zeros((9, 9))  # d vec(L) / d vec(M)
    for k in range(9):
        dM = np.zeros(9)
        dM[k] = 1.0
        dM = dM.reshape(3, 3)
        X = Li @ (dM @ M.T + M @ dM.T) @ Li.T
        Phi = np.tril(X) - 0.5 * np.diag(np.diag(X))
        dL[:, k] = (L @ Phi).ravel()
    # tri9 = [L00, L11, L22, L10/L11, L20/L22, L21/L22, b]
    P = np.zeros((6, 9))
    P[0, 0] = P[1, 4] = P[2, 8] = 1.0
    P[3, 3], P[3, 4] = 1.0 / L[1, 1], -L[1, 0] / L[1, 1] ** 2
    P[4, 6], P[4, 8] = 1.0 / L[2, 2], -L[2, 0] / L[2, 2] ** 2
    P[5, 7], P[5, 8] = 1.0 / L[2, 2], -L[2, 1] / L[2, 2] ** 2
    G[:6, :9] = P @ dL
    G[6:, 9:] = np.eye(3)
    return ob.Form("tri9").from_KE_b(L, b), G


def bound(sensor: str, M, b, observations, observe: str, form: str = "paper12") -> CalibrationBound:
    """The Cramér–Rao bound of the parameters of ``form`` ('paper12' | 'tri9') of one triad at the true ``M``,
    ``b`` from its window means ``observations`` (list of :class:`Observations`) under ``observe``
    ('vector' | 'norm'). A parameter moved by a null direction of the information gets sigma = inf."""
    F = information(M, observations, observe)
    null, inv, s = _null_and_inverse(F)
    _, G = gauge_jacobian(M, b, form)
    Gs = G / s[None, :]  # derivative per unit-information step of theta
    moved = np.linalg.norm(Gs @ null, axis=1) if null.size else np.zeros(G.shape[0])
    det = moved <= NULL_COMPONENT * np.maximum(np.linalg.norm(Gs, axis=1), 1e-300)
    cov = G @ inv @ G.T
    cov[~det, :] = np.nan
    cov[:, ~det] = np.nan
    sigma = np.where(det, np.sqrt(np.abs(np.diag(np.nan_to_num(cov)))), np.inf)
    names = PARAM_NAMES if form == "paper12" else ob.FORM_NAMES["tri9"]
    return CalibrationBound(sensor, form, observe, tuple(names), sigma, det, cov, F, null,
                            int(sum(o.n for o in observations)), "; ".join(o.source for o in observations if o.source))


# ----------------------------------------------------------------------------------------------------------
# the calibration's windows (calib.signal.segments) as observations
# ----------------------------------------------------------------------------------------------------------
def bound_of_parameters(F, T, names, free=None):
    """Bound of a parameterisation ``p`` of the triad with ``theta = theta(p)``, ``T = d theta / d p`` (12, q) (e.g.
    a gauge that fixes the triad's rotation, as the field calibration's): the information on p is ``T^T F T``.
    ``free`` (q,) bool: the parameters estimated (the others held at their values: known). Returns
    ``(sigma (q,), determined (q,))``: inf / False for the held ones and for those a null direction of the
    information moves."""
    T = np.asarray(T, dtype=float)
    q = T.shape[1]
    free = np.ones(q, bool) if free is None else np.asarray(free, bool)
    Fp = T.T @ F @ T
    Fp = 0.5 * (Fp + Fp.T)[np.ix_(free, free)]
    null, inv, _ = _null_and_inverse(Fp)
    moved = np.linalg.norm(null, axis=1) if null.size else np.zeros(int(free.sum()))
    det = np.zeros(q, bool)
    sigma = np.full(q, np.inf)
    det[free] = moved <= NULL_COMPONENT
    sigma[free] = np.where(det[free], np.sqrt(np.abs(np.diag(inv))), np.inf)
    return sigma, det


def joint_observations(groups, model) -> Observations:
    """Several window groups of one triad as one :class:`Observations` with their joint covariance (the slow
    bias correlates windows of different groups): ``groups`` a list of (inputs (n_g, 3), t_start (n_g,),
    duration (n_g,), source)."""
    x = np.concatenate([g[0] for g in groups])
    t0 = np.concatenate([g[1] for g in groups])
    T = np.concatenate([g[2] for g in groups])
    return Observations(x, model.mean_cov_axes(t0, T), np.ones(x.shape[0], bool),
                        " + ".join(g[3] for g in groups))


def session_groups(static, pairs=None) -> list:
    """The (inputs, t_start, duration, source) groups of a calibration session: static positions and, if given,
    the + and - rotation windows (the order of :func:`calib.signal.noisecov.eq25_cov`: plus, minus, static)."""
    groups = []
    if pairs is not None:
        xm, dx = pairs.mean_input(), pairs.delta_input()
        groups.append((xm + 0.5 * dx, pairs.t_plus, pairs.duration_plus, f"{pairs.n} + rotations"))
        groups.append((xm - 0.5 * dx, pairs.t_minus, pairs.duration_minus, f"{pairs.n} - rotations"))
    groups.append((static.true_inputs(), static.t_start_s, static.duration_s, f"{static.n} static positions"))
    return groups


#: the bounds a calibration session gets (key: sensor, observation model, form, what it is the bound of)
SESSION_BOUNDS = (
    ("accel", "accel", "norm", "tri9", "the default's accelerometer fit: Liu 2021 eq. 7 on the static means, "
                                      "norm-observed, in the lower-triangular gauge it determines"),
    ("accel_paper12", "accel", "norm", "paper12", "the paper's 12 accelerometer parameters from the norm "
                                                  "(Liu 2021 eq. 7): the installation errors and K not determined"),
    ("gyro", "gyro", "vector", "paper12", "the default's gyro fit: eq. 25 components and biases, known rotation "
                                          "axes and attitudes, on the + / - rotation and static means"),
    ("gyro_norm", "gyro", "norm", "paper12", "the gyro seen only through norms (Liu 2021 eqs. 26 and 7: |N+ - N-| "
                                             "and the static norm)"),
)


def session_bounds(inp, true_accel12, true_gyro12, models: dict) -> dict:
    """The bounds of :data:`SESSION_BOUNDS` of one calibration session: ``inp`` its windows
    (:class:`calib.signal.segments.CalibrationInputs`; only the nominal inputs and the window times are used, not
    the means), ``true_*12`` the paper's 12-vectors of the true triads, ``models`` ``{"accel" | "gyro":
    MeanNoiseModel}`` (the simulator's or a measured noise). Returns {key: :class:`CalibrationBound`}."""
    obs = {"accel": [joint_observations(session_groups(inp.accel_static), models["accel"])],
           "gyro": [joint_observations(session_groups(inp.gyro_static, inp.gyro_pairs), models["gyro"])]}
    truth = {"accel": ob.Form("paper12").KE_b(true_accel12), "gyro": ob.Form("paper12").KE_b(true_gyro12)}
    return {key: bound(sensor, *truth[sensor], obs[sensor], observe, form)
            for key, sensor, observe, form, _ in SESSION_BOUNDS}


def bounds_json(bounds: dict) -> dict:
    """{key: {"observe", "form", "sigma": {name: sigma or None (not determined)}}} of :func:`session_bounds`."""
    what = {k[0]: k[4] for k in SESSION_BOUNDS}
    return {k: {"observe": b.observe, "form": b.form, "windows": b.n_windows, "of": what.get(k, ""),
                "sigma": b.as_dict()} for k, b in bounds.items()}


def efficiency(std, sigma_crb) -> float:
    """Empirical std of the estimates / the bound (NaN where the bound is not finite)."""
    return float(std / sigma_crb) if (sigma_crb is not None and math.isfinite(sigma_crb) and sigma_crb > 0) \
        else math.nan


# ----------------------------------------------------------------------------------------------------------
# the bound beside the default calibration's estimates
# ----------------------------------------------------------------------------------------------------------
#: the default calibration's estimators and the observation model of their bound (key = sensor)
DEFAULT_BOUNDS = {
    "accel": ("norm", "tri9", "eq. 7 sees only the norm of every static mean: the input directions are unknown "
                              "(profiled out), the lower-triangular gauge is what the norm determines"),
    "gyro": ("vector", "paper12", "eq. 25 components and biases: known rotation axes and rates, nominal attitudes "
                                  "of the static positions, on the + / - rotation and static means"),
}

#: the noise of the window means the bound uses, by whether the calibration measured a long static record
NOISE_OF_BOUND = {
    "measured": "the noise model the default calibration fitted (session's static segments + the long static "
                "record: white, quantisation and the slow bias, correlated between windows)",
    "segments": "independent window means with the sigma the default calibration starts from (Allan deviation of "
                "the session's own static segments at tau = window duration); no slow bias instability (no long "
                "static record)",
}


def independent_observations(groups, sigmas) -> Observations:
    """Window groups (:func:`session_groups` order) as independent means with per-window, per-axis std
    ``sigmas`` (list of (n_g, 3) arrays in the same order) [output unit]: diagonal covariance per axis."""
    x = np.concatenate([g[0] for g in groups])
    s = np.concatenate([np.asarray(v, dtype=float) for v in sigmas])
    cov = np.stack([np.diag(s[:, i] ** 2) for i in range(3)])
    return Observations(x, cov, np.ones(x.shape[0], bool), " + ".join(g[3] for g in groups))


def _estimate_directions(static, M, b):
    """Inputs of the static positions as the estimate implies them: |input| = the reference, direction
    M^-1 (mean - b) (for a norm model without nominal attitudes)."""
    u = np.linalg.solve(np.asarray(M, float), (static.means - np.asarray(b, float)).T).T
    return static.reference * u / np.linalg.norm(u, axis=1, keepdims=True)


def default_bounds(inp, accel_Mb, gyro_Mb, models: dict | None = None) -> dict:
    """The Cramér–Rao bounds at the default calibration's estimates: ``accel_Mb`` = (K E, b) of the accelerometer
    estimate in the frame of the inputs used (body frame with nominal attitudes), ``gyro_Mb`` the gyro's (or
    None), ``inp`` the session's windows (:class:`calib.signal.segments.CalibrationInputs`), ``models``
    ``{"accel" | "gyro": MeanNoiseModel}`` the measured noise model (None: the windows' own sigmas, independent).

    Returns ``{sensor: (CalibrationBound or None, reason)}``: None with the reason when the windows cannot
    give the bound (the vector model of the gyros needs the nominal attitudes)."""
    out = {}
    noise = "measured" if models is not None else "segments"
    a = inp.accel_static
    if a.attitude is not None:
        groups = session_groups(a)
        src = "nominal attitudes"
    else:
        groups = [(_estimate_directions(a, *accel_Mb), a.t_start_s, a.duration_s, f"{a.n} static positions")]
        src = "directions implied by the estimate (no nominal attitudes)"
    obs = (joint_observations(groups, models["accel"]) if models is not None
           else independent_observations(groups, [a.sigma]))
    observe, form, _ = DEFAULT_BOUNDS["accel"]
    out["accel"] = (bound("accel", *accel_Mb, [obs], observe, form), f"{noise}; inputs: {src}")
    g = inp.gyro_static
    if gyro_Mb is None or inp.gyro_pairs is None:
        out["gyro"] = (None, "no gyro estimate (no rotation pairs)")
    elif g.attitude is None or inp.gyro_pairs.attitude is None:
        out["gyro"] = (None, "the vector model needs the nominal attitudes of the windows; the recording has none")
    else:
        p = inp.gyro_pairs
        groups = session_groups(g, p)
        obs = (joint_observations(groups, models["gyro"]) if models is not None
               else independent_observations(groups, [p.sigma_plus, p.sigma_minus, g.sigma]))
        observe, form, _ = DEFAULT_BOUNDS["gyro"]
        out["gyro"] = (bound("gyro", *gyro_Mb, [obs], observe, form), f"{noise}; inputs: nominal")
    return out


def beside_estimates(names, se, found, note: str) -> dict:
    """The bound beside one triad's estimates: ``names`` / ``se`` (NaN: not determined by the estimate) of the
    estimate, ``found`` a :class:`CalibrationBound` of the same parameters (or None), ``note`` why there is
    none. Returns {"sigma_crb": {name: float | None}, "se_over_crb": {name: float | None}, "null_reason":
    {name: why the entry is None}}: None never stands for a number."""
    sig, ratio, why = {}, {}, {}
    for n, s in zip(names, se):
        if found is None:
            sig[n], ratio[n], why[n] = None, None, note
            continue
        k = found.names.index(n)
        if not found.determined[k] or not math.isfinite(found.sigma[k]) or found.sigma[k] <= 0:
            sig[n], ratio[n], why[n] = None, None, found.describe(n)
            continue
        sig[n] = float(found.sigma[k])
        ratio[n] = float(s / found.sigma[k]) if np.isfinite(s) else None
        if ratio[n] is None:
            why[n] = "the estimate reports no standard error (not determined by its objective)"
    return {"sigma_crb": sig, "se_over_crb": ratio, "null_reason": why}
