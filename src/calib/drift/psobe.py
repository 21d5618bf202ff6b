"""Gyro-drift estimation from pure-inertial navigation errors (He 2019) and its baselines (least squares, Kalman filter).

The Cramér–Rao bound of the same problem, from the generative model without running any estimator, is in
:mod:`calib.drift.bound`.

Scenario (He 2019 §IV.A): a stationary IMU at known position, zero velocity; the first ``window_h`` hours
of the recording are navigated; a candidate drift triplet ``eps`` [deg/h, body frame] is compensated
(subtracted from the gyro output) and the navigation errors against the known truth are scored by

    J = rho_1 sum |e_VE| + rho_2 sum |e_VN| + rho_3 sum |e_Lat| + rho_4 sum |e_Lon|     (He 2019 eq. 18)

summed at the output interval. Velocity errors in m/s; latitude and longitude errors in the unit chosen in
config (``arcmin`` by default, or ``m`` -- north and east distance -- or ``rad``). The choice weights the
position terms against the velocity terms and therefore moves the PSO estimate; the study reports both.

The particles of one generation navigate together in one compiled pass
(:func:`calib.nav.strapdown.navigate_multi`) over increments pre-integrated once from the 100 Hz samples.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib.core import earth
from calib.io import recording
from calib.nav import reader
from calib.nav import strapdown
from calib.core.earth import DEG_PER_H
from calib.drift.pso import accuracy
from calib.nav import errormodel

POSITION_UNITS = ("arcmin", "m", "rad")
ARCMIN = math.pi / 180.0 / 60.0


@dataclass
class Window:
    """Navigation-rate increments of the estimation window and the known truth."""

    Dtheta: np.ndarray  # (m, 3) rad
    Dv: np.ndarray  # (m, 3) m/s
    dt_nav: float
    init: strapdown.NavInit
    lat0: float
    lon0: float
    h0: float
    n_samples: int
    sample_rate_hz: float


def load_window(path, window_h: float, nav_rate_hz: float, attitude_rad=(0.0, 0.0, 0.0), longitude_deg=0.0,
                chunk=None, progress=None) -> Window:
    """Pre-integrate the first ``window_h`` hours of a physical-unit stationary recording.

    Read by :func:`calib.nav.reader.for_each_chunk` (slices of about ``chunk`` samples, whole file chunks; the
    next slice read while this one is pre-integrated); ``progress(samples_done)`` after each slice.

    Raises a clear error for a window longer than the recording or a sample rate that is not a multiple of
    the navigation rate.
    """
    h = recording.read_header(path)
    n = int(round(window_h * 3600.0 * h.sample_rate_hz))
    if n > h.n_samples:
        raise ValueError(f"{path}: drift.window_h = {window_h} h needs {n} samples but the recording has "
                         f"{h.n_samples} ({h.duration_s / 3600:.3f} h) -- fix: shorten the window")
    n_sub = h.sample_rate_hz / nav_rate_hz
    if abs(n_sub - round(n_sub)) > 1e-9 or n_sub < 1:
        raise ValueError(f"navigation.nav_rate_hz = {nav_rate_hz} does not divide the sample rate "
                         f"{h.sample_rate_hz} Hz -- fix: choose a divisor")
    n_sub = int(round(n_sub))
    n -= n % n_sub
    carry = None
    Dth, Dv = [], []

    def preintegrate(i0, acc, gyr):  # in a worker thread while the next slice is read (no netCDF here)
        nonlocal carry
        dth = recording.to_si(gyr, h.gyro_units, h.gyro_kind, h.dt, "gyro")
        dv = recording.to_si(acc, h.accel_units, h.accel_kind, h.dt, "accel")
        if carry is None:
            carry = strapdown.new_carry(dth[0], dv[0])
        a, b = strapdown.preintegrate(dth, dv, n_sub, carry)
        Dth.append(a)
        Dv.append(b)

    reader.for_each_chunk(path, preintegrate, h, chunk=chunk, stop=n, progress=progress or None)
    lat0 = math.radians(h.latitude_deg)
    lon0 = math.radians(longitude_deg)
    pitch, roll, yaw = attitude_rad
    init = strapdown.NavInit(lat=lat0, lon=lon0, h=h.height_m, pitch=pitch, roll=roll, yaw=yaw)
    return Window(np.concatenate(Dth), np.concatenate(Dv), n_sub / h.sample_rate_hz, init, lat0, lon0,
                  h.height_m, n, h.sample_rate_hz)


def errors_from_output(out, lat0, lon0):
    """Navigation errors against a stationary truth from ``navigate_multi`` output (S, T, 9).

    Returns dict of (S, T) arrays: pitch, roll, yaw [rad] (as navigated; the truth attitude is subtracted by
    the caller when needed), vE, vN [m/s], lat, lon [rad].
    """
    return {"pitch": out[..., 0], "roll": out[..., 1], "yaw": out[..., 2], "vE": out[..., 3], "vN": out[..., 4],
            "lat": out[..., 6] - lat0, "lon": out[..., 7] - lon0}


def position_scale(unit: str, lat0: float, h0: float = 0.0):
    """Factors turning latitude and longitude errors [rad] into the J unit (He 2019 eq. 18)."""
    if unit == "arcmin":
        return 1.0 / ARCMIN, 1.0 / ARCMIN
    if unit == "rad":
        return 1.0, 1.0
    if unit == "m":
        r_m, r_n = earth.radii(lat0)
        return r_m + h0, (r_n + h0) * math.cos(lat0)
    raise ValueError(f"drift.position_unit = {unit!r}: expected one of {', '.join(POSITION_UNITS)}")


def cost_J(err, weights, unit, lat0, h0=0.0):
    """J of He 2019 eq. (18) per stream from :func:`errors_from_output` dicts."""
    kl, kn = position_scale(unit, lat0, h0)
    r1, r2, r3, r4 = weights
    return (r1 * np.abs(err["vE"]).sum(-1) + r2 * np.abs(err["vN"]).sum(-1)
            + r3 * kl * np.abs(err["lat"]).sum(-1) + r4 * kn * np.abs(err["lon"]).sum(-1))


class NavigationCost:
    """J(eps) for a swarm of drift candidates [deg/h], navigating all particles in one compiled pass."""

    def __init__(self, win: Window, output_interval_s: float, weights, unit: str, threads_parallel=True):
        self.win = win
        self.out_every = max(1, int(round(output_interval_s / win.dt_nav)))
        self.weights = tuple(float(w) for w in weights)
        self.unit = unit
        self.parallel = threads_parallel
        self.n_evaluations = 0
        self.accel_bias = None  # (3,) m/s^2 compensated in every stream (to show what an unmodelled bias does)
        position_scale(unit, win.lat0, win.h0)  # validate early

    def errors(self, eps_deg_h, accel_bias=None):
        X = np.atleast_2d(np.asarray(eps_deg_h, dtype=float)) * DEG_PER_H
        out, _ = strapdown.navigate_multi(self.win.Dtheta, self.win.Dv, self.win.dt_nav, self.win.init, X,
                                          accel_bias, out_every=self.out_every, parallel=self.parallel)
        return errors_from_output(out, self.win.lat0, self.win.lon0)

    def __call__(self, eps_deg_h):
        X = np.atleast_2d(eps_deg_h)
        self.n_evaluations += len(X)
        ab = None if self.accel_bias is None else np.tile(np.asarray(self.accel_bias, float), (len(X), 1))
        return cost_J(self.errors(X, ab), self.weights, self.unit, self.win.lat0, self.win.h0)

    def minimum(self, x0, accel_bias=None):
        """The minimum of J near ``x0`` [deg/h] by Nelder-Mead (J is a sum of absolute values: not smooth), with
        an optional accelerometer-bias compensation [m/s^2]. Separates the optimiser's error from J's own."""
        from scipy.optimize import minimize as nm

        old, self.accel_bias = self.accel_bias, accel_bias
        try:
            r = nm(lambda x: float(self(x[None])[0]), np.asarray(x0, float), method="Nelder-Mead",
                   options={"xatol": 1e-7, "fatol": 1e-9, "maxiter": 3000, "initial_simplex": np.asarray(x0, float)
                            + np.vstack([np.zeros(3), 0.002 * np.eye(3)])})
        finally:
            self.accel_bias = old
        return r.x, float(r.fun)

    @property
    def times_h(self):
        n_out = self.win.Dtheta.shape[0] // self.out_every
        return (np.arange(1, n_out + 1) * self.out_every * self.win.dt_nav) / 3600.0


def table1(estimates, reference):
    """He et al. (2019) Table 1: max, min, mean, std per axis, the reference, and Ac (eq. 19) of the mean."""

    est = np.asarray(estimates, float)
    ref = np.asarray(reference, float)
    mean = est.mean(0)
    return {"max": est.max(0), "min": est.min(0), "mean": mean, "std": est.std(0, ddof=1) if len(est) > 1 else
            np.zeros(3), "reference": ref, "Ac_of_mean_pct": accuracy(mean, ref),
            "Ac_mean_pct": accuracy(est, ref).mean(0), "Ac_min_pct": accuracy(est, ref).min(0)}


# ======================================================================================================
# The Kalman-filter estimator on the linear error model and its covariance
# ======================================================================================================
INITIAL_CONDITIONS = ("true_attitude", "leveled", "self_aligned")


def initial_error_map(condition: str, lat: float, C_bn, g: float):
    """x(0) = L theta: the initial error state (7) as a linear function of theta = [eps_body (3), nabla_body (3)].

    * ``true_attitude`` (He 2019's implicit choice): x(0) = 0.
    * ``leveled``: tilt from the accelerometers, which cancel the level accelerometer biases at the start:
      phi_E = -nabla_N / g, phi_N = nabla_E / g (ENU components); heading true. The east bias stays hidden in
      the tilt; the north one leaks through the Earth-rate coupling (phi_N' = W sin L nabla_N / g), which looks
      like a north drift of that size: within a few hours the two are separated only by the prior on the bias.
    * ``self_aligned``: leveling plus gyrocompassing, the equilibrium of the error model: additionally
      phi_U = (W_U phi_N - eps_E) / W_N, so the east drift hides in the heading error and is unobservable.
    """
    if condition not in INITIAL_CONDITIONS:
        raise ValueError(f"drift.initial_condition = {condition!r}: expected one of {', '.join(INITIAL_CONDITIONS)}")
    C = np.asarray(C_bn, float)
    L = np.zeros((7, 6))
    if condition == "true_attitude":
        return L
    L[0, 3:6] = -C[1, :] / g  # phi_E = -nabla_N / g
    L[1, 3:6] = C[0, :] / g  # phi_N = nabla_E / g
    if condition == "self_aligned":
        wN, wU = earth.OMEGA_IE * math.cos(lat), earth.OMEGA_IE * math.sin(lat)
        L[2, :] = (wU * L[1, :]) / wN
        L[2, 0:3] -= C[0, :] / wN  # - eps_E / W_N
    return L


@dataclass
class KalmanResult:
    estimate: np.ndarray  # (6,) [eps (rad/s), nabla (m/s^2)] body frame
    covariance: np.ndarray  # (6, 6)
    nuisance: tuple  # names of theta components treated as unknown


def kalman_drift(y, dt_out, lat, C_bn, arw_rad_rts, condition="true_attitude", h=0.0, sigma_v=1e-5,
                 sigma_p_rad=1e-9, estimate_accel_bias=True, prior_eps=1e-5, prior_nabla=1e-1, white_rad_s=0.0,
                 dt_sample=0.01):
    """Kalman filter on the linear stationary error model (He 2019 eqs. 4-8) with zero-velocity and
    known-position measurements every ``dt_out`` s; returns the final estimate of the constant errors and
    its covariance.

    y (N, 4): measured [vE, vN, lat, lon] errors [m/s, m/s, rad, rad] at t_k = (k+1) dt_out (the covariance
    does not depend on y: zeros give the filter's covariance alone, :func:`filter_covariance`). Process noise:
    gyro angle random walk
    ``arw_rad_rts`` [rad/sqrt(s)] per body axis (or white rate noise of sigma ``white_rad_s`` per sample of
    ``dt_sample``, PSD white^2 dt_sample). ``sigma_v``, ``sigma_p_rad``: a small measurement noise floor
    (the covariance of the drift does not depend on it once it is well below the process-noise effects).
    The covariance is the filter's own: it comes near the Cramér–Rao bound (:mod:`calib.drift.bound`) only where
    the data determine every constant; where they do not (after levelling or gyrocompassing) it is the prior.
    """

    C = np.asarray(C_bn, float)
    g = float(earth.normal_gravity(lat, h))
    nth = 6 if estimate_accel_bias else 3
    A = np.zeros((13, 13))
    A[:7, :7] = errormodel.f_matrix(lat, h)
    A[:7, 7:] = errormodel.g_matrix(C)
    q = arw_rad_rts**2 + white_rad_s**2 * dt_sample
    Qc = np.zeros((13, 13))
    Qc[:3, :3] = q * (C @ C.T)  # angle random walk enters phi through -C_b^n w
    Phi, Qd = errormodel.discretize(A, Qc, dt_out)
    # initial covariance: x(0) = L theta, theta ~ N(0, P_theta) (diffuse); a fixed nabla when not estimated
    L = initial_error_map(condition, lat, C, g)
    T = np.zeros((13, 6))
    T[:7] = L
    T[7:] = np.eye(6)
    ptheta = np.diag([prior_eps**2] * 3 + [prior_nabla**2 if estimate_accel_bias else 0.0] * 3)
    P = T @ ptheta @ T.T
    z = np.zeros(13)
    H = np.zeros((4, 13))
    H[0, 3] = H[1, 4] = H[2, 5] = H[3, 6] = 1.0
    R = np.diag([sigma_v**2, sigma_v**2, sigma_p_rad**2, sigma_p_rad**2])
    n = len(y) if y is not None else None
    if n is None:
        raise ValueError("y is required (pass zeros of the right shape for the bound only)")
    Ptheta_idx = slice(7, 7 + 6)
    for k in range(n):
        z = Phi @ z
        P = Phi @ P @ Phi.T + Qd
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).T
        z = z + K @ (y[k] - H @ z)
        IKH = np.eye(13) - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T  # Joseph form
    names = ("eps_x", "eps_y", "eps_z", "nabla_x", "nabla_y", "nabla_z")[:nth]
    return KalmanResult(z[Ptheta_idx].copy(), P[Ptheta_idx, Ptheta_idx].copy(), names)


def filter_covariance(window_h, dt_out, lat, C_bn, arw_rad_rts, condition="true_attitude", h=0.0, white_rad_s=0.0,
                      dt_sample=0.01, estimate_accel_bias=True):
    """The Kalman filter's 1-sigma [rad/s] per body axis of the drift after the window, and its covariance of the
    constants, with the accelerometer biases (and, through ``condition``, the initial tilt and heading) as
    nuisance parameters under the filter's priors. Not a bound: see :mod:`calib.drift.bound`."""
    n = int(round(window_h * 3600.0 / dt_out))
    res = kalman_drift(np.zeros((n, 4)), dt_out, lat, C_bn, arw_rad_rts, condition, h, white_rad_s=white_rad_s,
                       dt_sample=dt_sample, estimate_accel_bias=estimate_accel_bias)
    return np.sqrt(np.diag(res.covariance)[:3]), res.covariance


# ======================================================================================================
# Baselines: linear least squares on navigation sensitivities, and the Kalman filter on the error model
# ======================================================================================================
def _stack(err, kl, kn):
    return np.concatenate([err["vE"], err["vN"], kl * err["lat"], kn * err["lon"]], axis=-1)


def linear_lsq(cost: NavigationCost, with_accel_bias: bool, step_deg_h=0.01, step_accel=1e-3):
    """Linear least-squares drift estimate: 3 h navigation errors are linear in the drift.

    A few navigation runs (one at zero compensation, one per unknown with a unit step) give the sensitivity
    matrix H of the stacked errors [vE, vN, lat, lon] (position in the J unit); one solve gives the estimate.
    The fit weights channels like J (rho_1..rho_4 and the position unit) but, unlike J, squares them.
    Returns (estimate deg/h (3,), accel-bias estimate m/s^2 (3,) or None, runs).
    """
    kl, kn = position_scale(cost.unit, cost.win.lat0, cost.win.h0)
    w = np.repeat(np.asarray(cost.weights, float), cost.times_h.size)
    n_u = 6 if with_accel_bias else 3
    X = np.zeros((1 + n_u, 3))
    AB = np.zeros((1 + n_u, 3))
    for i in range(3):
        X[1 + i, i] = step_deg_h
    if with_accel_bias:
        for i in range(3):
            AB[4 + i, i] = step_accel
    err = cost.errors(X, AB)
    Y = _stack(err, kl, kn) * w  # (runs, N)
    y0 = Y[0]
    H = (Y[1:] - y0).T / np.array([step_deg_h] * 3 + [step_accel] * (n_u - 3))
    # compensation c gives errors y0 + H c; the estimate is the c that zeroes them
    c, *_ = np.linalg.lstsq(H, -y0, rcond=None)
    return c[:3], (c[3:] if with_accel_bias else None), 1 + n_u


def kalman_baseline(cost: NavigationCost, arw_rad_rts, condition, estimate_accel_bias=True, white_rad_s=0.0,
                    dt_sample=0.01):
    """Kalman-filter estimate from one uncompensated navigation run (zero velocity and known position as
    measurements). Returns (estimate deg/h (3,), standard errors deg/h (3,), accel bias (3,) or None)."""
    err = cost.errors(np.zeros((1, 3)))
    y = np.stack([err["vE"][0], err["vN"][0], err["lat"][0], err["lon"][0]], axis=1)
    dt_out = cost.out_every * cost.win.dt_nav
    C = cost.win.init.cbn()
    r = kalman_drift(y, dt_out, cost.win.lat0, C, arw_rad_rts, condition, cost.win.h0,
                     estimate_accel_bias=estimate_accel_bias, white_rad_s=white_rad_s, dt_sample=dt_sample)
    # the filter estimates the errors present in the data: the drift to compensate is that estimate
    est = r.estimate[:3] / DEG_PER_H
    se = np.sqrt(np.diag(r.covariance)[:3]) / DEG_PER_H
    return est, se, (r.estimate[3:] if estimate_accel_bias else None)


def longitude_noise_sigma(T_s, lat, C_bn, arw_rad_rts, white_rad_s=0.0, dt_sample=0.01, h=0.0, step_s=60.0):
    """1-sigma longitude error [rad] at time ``T_s`` caused by the gyro noise alone (linear error model).

    The stationary error model is time invariant, so the response to white rate noise of PSD q is
    var = q sum_k int_0^T h_k(t)^2 dt, with h_k = d s_k / dt the impulse response of longitude to a drift on
    body axis k (s_k from :func:`calib.nav.errormodel.sensitivity`).
    """

    t = np.arange(0.0, T_s + step_s, step_s)
    S = errormodel.sensitivity(t, lat, C_bn, h)[:, 6, :3]  # (N, 3) longitude per unit drift
    hk = np.diff(S, axis=0) / step_s
    q = arw_rad_rts**2 + white_rad_s**2 * dt_sample
    return math.sqrt(q * float(np.sum(hk**2)) * step_s)
