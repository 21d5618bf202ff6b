"""Cramér–Rao bound of the gyro drift estimated from the navigation errors of a stationary INS (He 2019).

The estimators of :mod:`calib.drift.psobe` (PSOBE, linear least squares, Kalman filter) all see the same data:
the east and north velocity errors and the latitude and longitude errors of a pure-inertial navigation of a
stationary unit, at the output instants ``t_k = k dt_out`` (k = 1..N) of the estimation window. This module
computes how well *any* unbiased estimator can determine the drift from those data, from the generative model
alone; it runs no estimator and no filter.

Model (the linear stationary error model of :mod:`calib.nav.errormodel`, vertical channel removed)::

    y = J theta + n,    n ~ N(0, Sigma)

* ``y`` (4N): [vE, vN, L, lambda] errors [m/s, m/s, rad, rad] stacked over the N output instants.
* ``theta`` (5): the constant gyro drift on the three body axes [rad/s] and the horizontal accelerometer bias in
  the navigation frame (nabla_E, nabla_N) [m/s^2]. The accelerometer bias enters the model only through its
  horizontal components (C_b^n nabla)_E,N, so these two, not the three body-frame biases the Kalman filter
  carries, are the parameters the data can determine: the third (vertical) component drives only the removed
  vertical channel. The drift bound does not depend on how the nuisance parameters are written.
* ``J`` (4N x 5): column j is the response of the observed errors to a unit step of theta_j, from the
  state-transition expm(A t) of the augmented model (Earth rate at the site's latitude, Schuler and Foucault
  dynamics), including the initial errors the initial condition ties to theta (levelling, gyrocompassing).
* ``Sigma`` (4N x 4N): the covariance of the observed errors caused by the sensor noise the simulator draws:
  white gyro rate noise (angle random walk, PSD ``q_gyro`` [rad^2/s] per axis) and white accelerometer noise
  (velocity random walk, PSD ``q_accel`` [m^2/s^3] per axis) propagated through the same model, plus an
  optional white measurement noise on each observed channel. The physical static session of
  :func:`calib.sim.static_session.simulate_static_session` draws no bias instability, so there is none here.

The noise is Gaussian and its covariance does not depend on theta, so the Fisher information is
``F = J^T Sigma^-1 J`` and the bound is ``CRB = F^-1``. Sigma is never formed and inverted: the noise is written
as ``n = K w`` with ``w`` standard normal (the discretised process noise of each output interval, exact by Van
Loan's integral, and the measurement noise), the rows of K are scaled to unit variance, and one QR decomposition
``K^T = Q R`` gives the Cholesky factor of the scaled Sigma (``Sigma_s = R^T R``); ``F`` is then the Gram
matrix of ``R^-T J`` (a triangular solve). Dense sampling makes Sigma ill conditioned (positions are integrals
of velocities); its condition number is reported with the bound (about 1.7e11 for 1 h and 7e11 for 3 h at 60 s,
which leaves the bound accurate to ~1e-5 relative: the tests check it against closed forms to that level).

Beside the bound, what He 2019's own criterion J lets an estimator reach, from the same model: the spread and
offset of its least-squares minimiser (:func:`cost_lsq_limit`, the sandwich of the columns the fit carries),
the offset of J's own minimum on the noise-free data (:func:`cost_offset`) and its spread over the noise
(:func:`cost_minimum_spread`, Monte Carlo of the model: J is a sum of absolute errors, its minimum a median).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize

from calib.core import earth
from calib.core.earth import STANDARD_GRAVITY
from calib.nav import errormodel
from calib.sim.settings import STATIC_PHYSICAL_DEFAULTS

PARAMETERS = ("eps_x", "eps_y", "eps_z", "nabla_E", "nabla_N")
UNITS = ("rad s-1", "rad s-1", "rad s-1", "m s-2", "m s-2")
OBSERVED = ("vE_err", "vN_err", "lat_err", "lon_err")
_OBS_STATE = (3, 4, 5, 6)  # indices of the observed channels in the error state of calib.nav.errormodel
CONDITIONS = ("true_attitude", "leveled", "self_aligned")
#: a parameter combination whose effect on the noise-free data cancels to below this share of the parameters' own
#: effects is not in the data (the model's exact cancellations leave ~1e-10)
NULL_TOL = 1e-7


@dataclass
class DriftBound:
    """The Cramér–Rao bound of :data:`PARAMETERS` and how it was obtained."""

    names: tuple
    units: tuple
    sigma: np.ndarray  # (p,) 1-sigma bound; inf where the data do not determine the parameter
    covariance: np.ndarray  # (p, p) F^+ (the bound on the determined parameters)
    fisher: np.ndarray  # (p, p)
    identifiable: np.ndarray  # (p,) bool
    n_observations: int  # 4 N
    cond_sigma: float  # condition number of the observation covariance, channels scaled to unit variance
    cond_fisher: float  # condition number of the Fisher matrix scaled to unit diagonal (seen combinations)
    null: np.ndarray  # (p, k) parameter combinations [parameter units] the data do not see

    def sigma_deg_h(self):
        """The drift part of :attr:`sigma` in deg/h."""
        return self.sigma[:3] / earth.DEG_PER_H


def observation_times(window_h: float, dt_out: float) -> np.ndarray:
    """The estimators' output instants [s]: k dt_out, k = 1..N, N = round(window / dt_out)."""
    n = int(round(window_h * 3600.0 / dt_out))
    if n < 1:
        raise ValueError(f"drift window {window_h} h is shorter than one output interval of {dt_out} s")
    return np.arange(1, n + 1) * float(dt_out)


def noise_psd(session: dict, sample_rate_hz: float):
    """White-noise PSDs of the simulator's physical static session: (gyro [rad^2/s], accel [m^2/s^3]) per axis.

    Gyro ``model: arw``: per-sample angle sigma ARW sqrt(dt), PSD ARW^2 (ARW in rad/sqrt(s)); ``model: white``:
    per-sample rate sigma ``white_deg_h``, PSD white^2 dt. Accelerometer ``accel_vrw_ug_rthz``: PSD
    (VRW 1e-6 g0)^2. Missing keys take the simulator's defaults.
    """
    gn = {**STATIC_PHYSICAL_DEFAULTS["gyro_noise"], **(session.get("gyro_noise") or {})}
    dt = 1.0 / float(sample_rate_hz)
    if gn["model"] == "arw":
        q_g = (float(gn["arw_deg_rth"]) * earth.DEG / 60.0) ** 2
    elif gn["model"] == "white":
        q_g = (float(gn["white_deg_h"]) * earth.DEG_PER_H) ** 2 * dt
    else:
        raise ValueError(f"navigation_session.gyro_noise.model = {gn['model']!r}: expected arw or white")
    vrw = float(session.get("accel_vrw_ug_rthz", STATIC_PHYSICAL_DEFAULTS["accel_vrw_ug_rthz"]))
    return q_g, (vrw * 1e-6 * STANDARD_GRAVITY) ** 2


def initial_state_map(condition: str, lat: float, C_bn, h: float = 0.0) -> np.ndarray:
    """x(0) = L theta (7 x 5) for the initial condition of the navigation.

    ``true_attitude``: zero. ``leveled``: the accelerometers level the platform so that the horizontal biases
    are cancelled at the start: phi_E = -nabla_N / g, phi_N = nabla_E / g. ``self_aligned``: levelling and
    gyrocompassing (the heading error that holds phi_E constant): phi_U = (W sin L phi_N - eps_E) / (W cos L),
    eps_E = (C_b^n eps)_E.
    """
    if condition not in CONDITIONS:
        raise ValueError(f"drift.initial_condition = {condition!r}: expected one of {', '.join(CONDITIONS)}")
    C = np.asarray(C_bn, float)
    g = float(earth.normal_gravity(lat, h))
    L = np.zeros((errormodel.NX, len(PARAMETERS)))
    if condition == "true_attitude":
        return L
    L[0, 4] = -1.0 / g
    L[1, 3] = 1.0 / g
    if condition == "self_aligned":
        wN, wU = earth.OMEGA_IE * math.cos(lat), earth.OMEGA_IE * math.sin(lat)
        L[2, :] = wU * L[1, :] / wN
        L[2, 0:3] -= C[0, :] / wN
    return L


def sensitivity_matrix(t, lat, C_bn, h=0.0, condition="true_attitude") -> np.ndarray:
    """J (4N x 5): the observed errors [vE, vN, L, lambda] at the times ``t`` per unit of each parameter.

    Rows are ordered time-major (the four channels of t_1, then of t_2, ...).
    """
    C = np.asarray(C_bn, float)
    nx, p = errormodel.NX, len(PARAMETERS)
    A = np.zeros((nx + p, nx + p))
    A[:nx, :nx] = errormodel.f_matrix(lat, h)
    A[0:3, nx:nx + 3] = -C  # phi' = ... - C_b^n eps
    A[3, nx + 3] = A[4, nx + 4] = 1.0  # dv' = ... + (nabla_E, nabla_N)
    Z0 = np.zeros((nx + p, p))
    Z0[:nx] = initial_state_map(condition, lat, C, h)
    Z0[nx:] = np.eye(p)
    X = errormodel.transition(np.asarray(t, float), A, Z0)  # (N, nx + p, p)
    return X[:, list(_OBS_STATE), :].reshape(-1, p)


def noise_factor(t, lat, h=0.0, q_gyro=0.0, q_accel=0.0, meas_sigma=None) -> np.ndarray:
    """K with Sigma = K K^T: the observed errors caused by the sensor noise, n = K w, w standard normal.

    ``t`` a uniform grid k dt, k = 1..N (the process noise of each interval [t_{k-1}, t_k] is one block of w).
    ``meas_sigma`` (4,) optional white measurement noise per channel [m/s, m/s, rad, rad].
    The gyro noise enters phi' through -C_b^n w_g; C_b^n is orthonormal, so its covariance is q_gyro I whatever
    the attitude. The accelerometer noise enters the horizontal velocity errors (q_accel I_2).
    """
    t = np.asarray(t, float)
    dt = t[0]
    if t.ndim != 1 or dt <= 0 or np.max(np.abs(np.diff(t) - dt), initial=0.0) > 1e-9 * dt:
        raise ValueError("observation times must be the uniform grid k dt, k = 1..N")
    nx, N = errormodel.NX, t.size
    F = errormodel.f_matrix(lat, h)
    Qc = np.zeros((nx, nx))
    Qc[0:3, 0:3] = q_gyro * np.eye(3)
    Qc[3:5, 3:5] = q_accel * np.eye(2)
    Phi, Qd = errormodel.discretize(F, Qc, dt)
    w, V = np.linalg.eigh(Qd)
    Lq = V * np.sqrt(np.clip(w, 0.0, None))  # Qd = Lq Lq^T
    H = np.zeros((4, nx))
    H[range(4), _OBS_STATE] = 1.0
    # block (k, m) = H Phi^(k-m) Lq for m <= k (the noise of interval m, propagated to t_k)
    blocks = np.empty((N, 4, nx))
    P = np.eye(nx)
    for j in range(N):
        blocks[j] = H @ P @ Lq
        P = Phi @ P
    K = np.zeros((4 * N, nx * N))
    for k in range(N):
        K[4 * k:4 * k + 4, :nx * (k + 1)] = blocks[k::-1].transpose(1, 0, 2).reshape(4, -1)
    if meas_sigma is not None:
        K = np.hstack([K, np.diag(np.tile(np.asarray(meas_sigma, float), N))])
    return K


@dataclass
class ObservationNoise:
    """The observation covariance Sigma = K K^T in the form the Fisher information needs: the rows' standard
    deviations ``s`` (sqrt diag Sigma) and the triangular ``R`` with ``Sigma_s = R^T R`` for the row-scaled Sigma,
    with ``cond`` the condition number of Sigma_s. It depends on the noise and the output instants only, so the
    bounds of several parameter sets over the same data share it (:func:`drift_bounds`)."""

    s: np.ndarray
    R: np.ndarray
    cond: float


def observation_noise(K) -> ObservationNoise:
    """:class:`ObservationNoise` of ``Sigma = K K^T`` by a QR decomposition of the row-scaled K^T (no inverse of
    Sigma). Raises if Sigma is singular to working precision."""
    K = np.asarray(K, float)
    s = np.linalg.norm(K, axis=1)  # sqrt(diag Sigma)
    if np.any(s == 0):
        raise ValueError(f"{int(np.sum(s == 0))} observations carry no noise: the Fisher information is unbounded "
                         "(give the channels a measurement noise)")
    R = np.linalg.qr((K / s[:, None]).T, mode="r")  # Sigma_s = R^T R
    d = np.abs(np.diag(R))
    if d.min() <= 1e-15 * d.max():
        raise ValueError("the observation covariance is singular to working precision: observe less densely")
    sv = np.linalg.svd(R, compute_uv=False)
    return ObservationNoise(s, R, float((sv[0] / sv[-1]) ** 2))


def fisher_information(J, K):
    """F = J^T Sigma^-1 J with Sigma = K K^T (``K`` or its :class:`ObservationNoise`), by a triangular solve with
    the Cholesky factor of the row-scaled Sigma (no inverse of Sigma).

    Returns (F, condition number of the unit-diagonal Sigma). Raises if Sigma is singular to working precision.
    """
    J = np.asarray(J, float)
    noise = K if isinstance(K, ObservationNoise) else observation_noise(K)
    W = scipy.linalg.solve_triangular(noise.R, J / noise.s[:, None], trans="T")  # R^-T J_s
    return W.T @ W, noise.cond


def null_directions(J, scale, tol=NULL_TOL) -> np.ndarray:
    """Parameter combinations the noise-free observations do not see: an orthonormal basis (p x k) of the null
    space of ``J diag(1/scale)``, in units of ``scale`` (k = 0: every parameter enters the data).

    ``scale`` is each parameter's own effect (the norm of its column without the initial errors the initial
    condition ties to it): a combination whose effect cancels to below ``tol`` of that is not in the data (the
    levelled tilt cancels the horizontal accelerometer bias, the gyrocompassed heading the east drift).
    """
    Js = np.asarray(J, float) / np.asarray(scale, float)
    _, sv, Vt = np.linalg.svd(Js, full_matrices=True)
    sv = np.concatenate([sv, np.zeros(Js.shape[1] - sv.size)])
    return Vt[sv < tol * sv.max()].T


def bound_from_fisher(F, scale=None, null=None):
    """(covariance, sigma, identifiable, cond) from a Fisher matrix, saying which parameters it determines.

    ``null`` (p x k, in units of ``scale``) the combinations the data do not see (:func:`null_directions`). A
    parameter is determined when no such combination moves it; the bound of the determined ones is the inverse
    of the information restricted to the seen combinations (a Cholesky solve), the others get sigma = inf.
    ``cond`` is the condition number of that restricted information scaled to unit diagonal.
    """
    F = 0.5 * (np.asarray(F, float) + np.asarray(F, float).T)
    p = F.shape[0]
    s = np.ones(p) if scale is None else np.asarray(scale, float)
    Fs = F / np.outer(s, s)  # information on theta * scale
    if null is None or null.shape[1] == 0:
        Q = np.eye(p)
        ident = np.ones(p, bool)
    else:
        Q = scipy.linalg.null_space(null.T)  # orthonormal basis of the seen combinations
        ident = np.linalg.norm(null, axis=1) < 1e-6
    Fr = Q.T @ Fs @ Q
    d = np.sqrt(np.diag(Fr))
    Fn = Fr / np.outer(d, d)
    ev = np.linalg.eigvalsh(Fn)
    if ev[0] <= 1e-14 * ev[-1]:
        raise ValueError("the Fisher information is singular beyond the structural null directions")
    cov_r = scipy.linalg.cho_solve(scipy.linalg.cho_factor(Fn), np.eye(Fn.shape[0])) / np.outer(d, d)
    cov = (Q @ cov_r @ Q.T) / np.outer(s, s)
    cov[~ident, :] = np.nan
    cov[:, ~ident] = np.nan
    sigma = np.where(ident, np.sqrt(np.abs(np.diag(np.nan_to_num(cov)))), np.inf)
    return cov, sigma, ident, float(ev[-1] / ev[0])


def drift_bound(window_h, dt_out, lat, C_bn, h=0.0, q_gyro=0.0, q_accel=0.0, condition="true_attitude",
                meas_sigma=None, accel_bias_known=False) -> DriftBound:
    """The Cramér–Rao bound of the drift (and the horizontal accelerometer bias) over ``window_h`` hours observed
    every ``dt_out`` s, for white gyro and accelerometer noise of PSDs ``q_gyro`` [rad^2/s], ``q_accel``
    [m^2/s^3]. ``accel_bias_known``: the bound when the accelerometer bias is given (drift-only estimators:
    the model they fit), else the bias is a nuisance parameter estimated with the drift."""
    return drift_bounds(window_h, dt_out, lat, C_bn, h, q_gyro, q_accel, condition, meas_sigma,
                        accel_bias_known=(accel_bias_known,))[0]


def drift_bounds(window_h, dt_out, lat, C_bn, h=0.0, q_gyro=0.0, q_accel=0.0, condition="true_attitude",
                 meas_sigma=None, accel_bias_known=(False, True)) -> tuple:
    """:func:`drift_bound` for each entry of ``accel_bias_known``, in that order, over the same data: the
    sensitivities and the observation noise (its QR decomposition, the costly part) are computed once. Each bound
    is the same, to the bit, as :func:`drift_bound` of that entry alone."""
    t = observation_times(window_h, dt_out)
    J_all = sensitivity_matrix(t, lat, C_bn, h, condition)
    scale_all = np.linalg.norm(sensitivity_matrix(t, lat, C_bn, h, "true_attitude"), axis=0)
    noise = observation_noise(noise_factor(t, lat, h, q_gyro, q_accel, meas_sigma))
    out = []
    for known in accel_bias_known:
        p = 3 if known else len(PARAMETERS)
        J, scale = J_all[:, :p], scale_all[:p]
        F, cond_s = fisher_information(J, noise)
        null = null_directions(J, scale)
        cov, sigma, ident, cond_f = bound_from_fisher(F, scale, null)
        out.append(DriftBound(PARAMETERS[:p], UNITS[:p], sigma, cov, F, ident, J.shape[0], cond_s, cond_f,
                              null / scale[:, None]))
    return tuple(out)


# ======================================================================================================
# The spread and offset of the least-squares minimiser of He 2019's channel-weighted cost (no estimator run)
# ======================================================================================================
def vertical_bias_sensitivity(t, lat, C_bn, theta, h=0.0, condition="true_attitude") -> np.ndarray:
    """(4N,) the observed errors [vE, vN, L, lambda] at the times ``t`` per unit vertical accelerometer bias
    nabla_U [m/s^2], time-major like :func:`sensitivity_matrix`.

    The linear model has no such column: a vertical bias drives only the vertical channel (held by the
    navigation). It reaches the horizontal channels at second order, through the tilt: the computed specific
    force is (I - [phi x]) (g + nabla_U) e_U, so nabla_U adds to the horizontal velocity rates what g does, scaled
    by nabla_U / g, times the tilt phi(t) the constants ``theta`` (:data:`PARAMETERS` [rad/s, m/s^2]) produce.
    The column therefore depends on the truth. The navigation's own column also carries the tilt the noise adds
    (about a tenth of it over 3 h), which is left out: over 3 h it moves the least-squares spread of
    :func:`cost_lsq_limit` by ~0.1 %; over 1 h, where the noise's tilt is a larger share, the fit on navigated
    data spreads up to ~10 % more than that limit.
    """
    C = np.asarray(C_bn, float)
    nx = errormodel.NX
    F = errormodel.f_matrix(lat, h)
    g = float(earth.normal_gravity(lat, h))
    A = np.zeros((2 * nx + 1, 2 * nx + 1))
    A[:nx, :nx] = F
    A[nx:2 * nx, nx:2 * nx] = F
    A[nx + 3:nx + 5, 0:3] = F[3:5, 0:3] / g  # the tilt coupling of g, per unit of g
    A[0:3, 2 * nx] = -C @ np.asarray(theta, float)[:3]  # the drift's tilt rate (a constant input)
    A[3, 2 * nx], A[4, 2 * nx] = theta[3], theta[4]
    z0 = np.zeros(2 * nx + 1)
    z0[:nx] = initial_state_map(condition, lat, C, h) @ np.asarray(theta, float)
    z0[2 * nx] = 1.0
    X = errormodel.transition(np.asarray(t, float), A, z0[:, None])[..., 0]  # (N, 2 nx + 1)
    return X[:, [nx + i for i in _OBS_STATE]].reshape(-1)


@dataclass
class CostLsqLimit:
    """What the least-squares minimiser of the channel-weighted cost does over noise realisations, from the model:
    ``sigma`` (3,) its 1-sigma spread and ``bias`` (3,) its mean minus the truth, for the drift [rad/s]."""

    sigma: np.ndarray
    bias: np.ndarray
    parameters: tuple  # the columns fitted

    def sigma_deg_h(self):
        return self.sigma / earth.DEG_PER_H

    def bias_deg_h(self):
        return self.bias / earth.DEG_PER_H


def _unit_columns(M):
    """(M / s, s): the columns of ``M`` scaled to unit norm (``s`` their norms); a column the initial condition
    cancels (the gyrocompassed east drift) stays zero."""
    s = np.linalg.norm(M, axis=0)
    s[s == 0] = 1.0
    return M / s, s


def _drift_columns(window_h, dt_out, lat, C_bn, weights, h, condition):
    """(J, w, Mu, s): the model's columns at the output instants, the channel weights tiled over them, and the
    weighted drift columns scaled to unit norm (:func:`_unit_columns`)."""
    t = observation_times(window_h, dt_out)
    J = sensitivity_matrix(t, lat, C_bn, h, condition)
    w = np.tile(np.asarray(weights, float), t.size)
    Mu, s = _unit_columns(J[:, :3] * w[:, None])
    return J, w, Mu, s


def _lad_drift(Mu, s, y, what):
    """The drift minimising sum |y - Mu c| (c = drift x s), exactly: the dual linear programme of least absolute
    deviations (maximise y^T d with Mu^T d = 0, -1 <= d <= 1; HiGHS), whose equality multipliers are the
    minimiser. ``what`` names the data in the error message."""
    res = scipy.optimize.linprog(-y, A_eq=Mu.T, b_eq=np.zeros(Mu.shape[1]), bounds=(-1.0, 1.0), method="highs")
    if res.status != 0:
        raise RuntimeError(f"the minimum of J on {what}: {res.message}")
    return -res.eqlin.marginals / s


def cost_lsq_limit(window_h, dt_out, lat, C_bn, theta, weights, h=0.0, q_gyro=0.0, q_accel=0.0,
                   condition="true_attitude", fit_accel_bias=True, fit_vertical_bias=True,
                   meas_sigma=None) -> CostLsqLimit:
    """Spread and offset of the drift that minimises sum_k sum_c (w_c e_c(t_k))^2, the squared form of He 2019's
    cost (eq. 18): every output instant counts alike, each channel c (vE, vN, L, lambda) by its weight ``weights``
    (4,) per unit of the model's units [m/s, m/s, rad, rad] (rho_c times the position unit's factor).

    ``theta`` (5,) the true :data:`PARAMETERS`. Fitted: the drift, and with ``fit_accel_bias`` the accelerometer
    bias on all three axes as :func:`calib.drift.psobe.linear_lsq` does -- the horizontal components
    (nabla_E, nabla_N) and the vertical one, whose column (:func:`vertical_bias_sensitivity`) is the tilt the
    truth produces (``fit_vertical_bias`` False: the horizontal ones only, the parameters the Cramér–Rao bound
    carries). Without ``fit_accel_bias`` the drift alone is fitted: the accelerometer bias in the data then
    shifts the minimiser, which ``bias`` gives (the noise-free fit's drift minus the truth).

    The fit is linear in the data, so its covariance is the sandwich P W Sigma W P^T with P the pseudo-inverse of
    W M (M the fitted columns, W the weights), Sigma = K K^T of :func:`noise_factor`. For the columns of the
    Cramér–Rao bound it is at least that bound, equal only when the weights whiten the noise: J weights every
    instant alike while the navigation errors are integrals of the noise, strongly correlated in time. The
    vertical bias, which the bound does not carry (the data hardly determine it), takes part of that correlated
    noise with it and so lowers the drift's spread over long windows.
    """
    t = observation_times(window_h, dt_out)
    J = sensitivity_matrix(t, lat, C_bn, h, condition)
    cols = [J[:, :3]]
    names = PARAMETERS[:3]
    if fit_accel_bias:
        cols.append(J[:, 3:5])
        names = PARAMETERS
        if fit_vertical_bias:
            cols.append(vertical_bias_sensitivity(t, lat, C_bn, theta, h, condition)[:, None])
            names = PARAMETERS + ("nabla_U",)
    w = np.tile(np.asarray(weights, float), t.size)
    Mu, s = _unit_columns(np.hstack(cols) * w[:, None])
    P = np.linalg.pinv(Mu) / s[:, None]  # minimum-norm least squares, columns scaled to unit norm
    G = P[:3] @ (noise_factor(t, lat, h, q_gyro, q_accel, meas_sigma) * w[:, None])
    sigma = np.sqrt(np.sum(G * G, axis=1))
    bias = P[:3] @ (w * (J @ np.asarray(theta, float))) - np.asarray(theta, float)[:3]
    return CostLsqLimit(sigma, bias, names)


def cost_offset(window_h, dt_out, lat, C_bn, theta, weights, h=0.0, condition="true_attitude") -> np.ndarray:
    """(3,) the offset [rad/s] from the truth of the drift that minimises He 2019's cost J (eq. 18) itself -- the
    weighted sum of the absolute errors, sum_k sum_c w_c |e_c(t_k)| -- on the noise-free data of ``theta``
    (:data:`PARAMETERS`), fitting the drift alone as PSOBE does: the horizontal accelerometer bias in the data,
    which the drift-only model cannot represent, moves J's minimum. ``weights`` as :func:`cost_lsq_limit`.

    A linear programme, solved exactly (:func:`_lad_drift`).
    """
    J, w, Mu, s = _drift_columns(window_h, dt_out, lat, C_bn, weights, h, condition)
    theta = np.asarray(theta, float)
    return _lad_drift(Mu, s, w * (J @ theta), "the noise-free model") - theta[:3]


def cost_minimum_spread(window_h, dt_out, lat, C_bn, theta, weights, rng, n_draws=400, h=0.0, q_gyro=0.0,
                        q_accel=0.0, condition="true_attitude", meas_sigma=None):
    """(sigma (3,), offset (3,)) [rad/s]: the spread over noise realisations of the drift that minimises He 2019's
    J itself (the weighted sum of absolute errors, :func:`cost_offset`) over the drift alone, and its mean offset
    from the truth, by Monte Carlo of the linear model: ``n_draws`` realisations y = J theta + K w (``rng`` a
    :func:`calib.core.seeds.stream`), each minimised exactly.

    J's minimum has no closed form (it is a median, not a mean); each draw is minimised exactly
    (:func:`_lad_drift`). The spread's sampling error is about 1 / sqrt(2 n_draws) relative (3.5 % for 400).
    """
    J, w, Mu, s = _drift_columns(window_h, dt_out, lat, C_bn, weights, h, condition)
    K = noise_factor(observation_times(window_h, dt_out), lat, h, q_gyro, q_accel, meas_sigma)
    theta = np.asarray(theta, float)
    Y = w[:, None] * ((J @ theta)[:, None] + K @ rng.standard_normal((K.shape[1], n_draws)))
    est = np.array([_lad_drift(Mu, s, Y[:, r], f"draw {r} of the linear model") for r in range(n_draws)])
    est -= theta[:3]
    return est.std(0, ddof=1), est.mean(0)
