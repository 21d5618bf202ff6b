"""Covariance of segment means with the slow noise (bias instability) of a long static record.

Why
---
A calibration works on segment means (60 s static positions, whole-revolution rotation windows). The Allan
deviation pooled over the static segments of the session (``segments.noise_from_static``) reaches only
tau <= 30 s, so a bias instability that decorrelates over minutes (the simulated unit: 5 ug with a 300 s
correlation time) is invisible to it -- yet it moves every segment mean, and neighbouring segments move
together. The standard errors of the biases then come out far too small (z-score std 1.6-2.2 over 100 seeds).
This module fits a noise model to the Allan deviation of the static segments *and* of a long static record
of the same unit (tau up to hours), and turns it into the full covariance of the segment means, including the
correlation between segments.

Noise model (per sensor axis, rate reading y(t) in the data's unit, e.g. count s-1)
-----------------------------------------------------------------------------------
    y(t) = mean + q'(t) + w(t) + beta(t)

* q: white *phase* noise (quantisation of a pulse counter) of std Q [unit s]; AVAR_Q = 3 Q^2 / tau^2. For a
  pulse counter with the remainder carried, Q = 1/sqrt(12) count is known (the carry is uniform in [0, 1)).
* w: white rate noise of density N [unit s^1/2] (velocity / angle random walk); AVAR_N = N^2 / tau.
* beta, the slow part, one of
  - first-order Gauss-Markov bias of stationary std sigma [unit] and correlation time Tc [s],
    autocovariance sigma^2 exp(-|s|/Tc), whose Allan variance is (x = tau / Tc)::

        AVAR_GM(tau) = sigma^2 (Tc / tau)^2 (2 x - 3 + 4 e^-x - e^-2x)                          (1)

  - random walk of density K [unit s^-1/2] starting at the recording's t = 0: AVAR_K = K^2 tau / 3;
  - none.

Fit (:func:`fit_mean_noise`): per axis, on the Allan points with tau >= ``tau_min_s`` of every Allan result
given (the session's pooled static segments and the long record; the short taus of a pulse counter carry a
deterministic carry pattern that the white-phase law does not describe, so the 3 Q^2/tau^2 term of the Allan
curve is always fitted freely, while a known Q is used for the segment means), by non-negative least squares
on the Allan variance with weights sqrt(edf/2)/AVAR_model (reweighted to the Gamma maximum likelihood; edf = the equivalent degrees of freedom behind
``allan.py``'s chi-square confidence intervals), Tc profiled on a log grid and refined. The slow part is chosen
between random walk and Gauss-Markov by deviance + ln(n_points) x (number of parameters) (BIC; the Gamma
deviance sum_i edf_i (r_i - 1 - ln r_i), r = AVAR_obs / AVAR_model, is -2 log-likelihood of AVAR_obs ~
AVAR_model chi2(edf)/edf, approximately chi-square, and unbiased at the few-edf long taus); it is always kept (its NNLS
variance is about unbiased even when the record cannot resolve it; dropping it when not significant would bias
the standard errors low) and is 'none' only when that variance comes out zero; whether BIC would keep it over
no slow part at all is reported (``slow_detected_bic``). Reported with a 95 % profile
interval of Tc, a 95 % interval of sigma (Fisher information of the weighted fit) and the fraction of Allan
points whose 95 % chi-square interval (``allan.py``) contains the model.

Covariance of window means (:meth:`MeanNoiseModel.mean_cov`), windows j = [a_j, a_j + T_j] (seconds from the
recording start), disjoint::

    C_jk = delta_jk (N^2 / T_j + 2 Q^2 / T_j^2) + C_slow,jk                                      (2)
    GM:  C_slow,jj = sigma^2 2 Tc^2 / T_j^2 (x_j - 1 + e^-x_j),  x_j = T_j / Tc
         C_slow,jk = sigma^2 Tc^2 (e^-(q0-p1)/Tc - e^-(q0-p0)/Tc - e^-(q1-p1)/Tc + e^-(q1-p0)/Tc) / (T_j T_k)
                     for p = [p0, p1] the earlier, q = [q0, q1] the later window      (the double integral
                     of sigma^2 exp(-|s-t|/Tc) over the two windows, divided by T_j T_k)
    RW:  C_slow,jk = K^2 (a_j + T_j / 2)  for j earlier than k,   C_slow,jj = K^2 (a_j + T_j / 3)

(The mismatch diagnosis takes its window-mean GM covariance from :func:`gm_mean_cov` too:
``calib.diagnosis.noise.gm_part``.) Note that the std of a T-long mean is not
ADEV(T) in general: for white phase noise it is sqrt(2/3) ADEV(T), for a Gauss-Markov bias it is far larger
than ADEV(T) when T << Tc (the mean carries the current bias value, which the Allan difference cancels).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from calib.signal import allan
from calib.signal.segments import SegmentError, rate_reading

#: quantisation phase noise of a pulse counter with the fraction carried [count]: uniform remainder in [0, 1)
PULSE_COUNTER_Q = 1.0 / math.sqrt(12.0)


class NoiseModelError(ValueError):
    """A long static record that cannot give the slow noise (wrong units, too short); the message says why."""


# ----------------------------------------------------------------------------------------------------------
# closed forms
# ----------------------------------------------------------------------------------------------------------
def gm_avar(tau, sigma, tc):
    """Allan variance (1) of a Gauss-Markov process of std ``sigma`` [unit] and correlation time ``tc`` [s] at
    averaging times ``tau`` [s]: sigma^2 (tc/tau)^2 (2x - 3 + 4 e^-x - e^-2x), x = tau/tc [unit^2]."""
    t = np.asarray(tau, dtype=float)
    x = t / tc
    small = x < 1e-3
    # series for small x: 2x - 3 + 4(1 - x + x^2/2 - x^3/6 + x^4/24) - (1 - 2x + 2x^2 - 4x^3/3 + 2x^4/3)
    #                   = 2 x^3 / 3 - x^4 / 2 + ...   => AVAR ~ sigma^2 (2 tau / (3 tc)) (the RW limit, K^2 = 2 s^2/tc)
    xs = np.where(small, 1.0, x)
    full = (2.0 * xs - 3.0 + 4.0 * np.exp(-xs) - np.exp(-2.0 * xs)) / xs**2
    ser = 2.0 * x / 3.0 - x**2 / 2.0
    return sigma**2 * np.where(small, ser, full)


def gm_mean_cov(t0, T, tc):
    """Covariance (M, M) of the means of windows ``[t0_j, t0_j + T_j]`` [s] of a unit-variance Gauss-Markov process
    of correlation time ``tc`` [s], eq. (2). Windows must not overlap (touching is fine)."""
    a0 = np.asarray(t0, dtype=float)
    T = np.asarray(T, dtype=float)
    a1 = a0 + T
    x = T / tc
    C = np.diag(2.0 * tc**2 / T**2 * (x - 1.0 + np.exp(-x)))
    order = np.argsort(a0)
    J, K = np.triu_indices(a0.size, 1)          # every pair, the earlier-starting window j first
    j, k = order[J], order[K]
    p0, p1, q0, q1 = a0[j], a1[j], a0[k], a1[k]
    bad = np.flatnonzero(q0 < p1 - 1e-9 * np.maximum(1.0, np.abs(p1)))
    if bad.size:
        i = bad[0]
        raise ValueError(f"windows overlap: [{p0[i]}, {p1[i]}] and [{q0[i]}, {q1[i]}] s")
    v = tc**2 * (np.exp(-(q0 - p1) / tc) - np.exp(-(q0 - p0) / tc) - np.exp(-(q1 - p1) / tc)
                 + np.exp(-(q1 - p0) / tc)) / (T[j] * T[k])
    C[j, k] = v
    C[k, j] = v
    return C


def rw_mean_cov(t0, T):
    """Covariance (M, M) of window means of a unit-density random walk (K = 1 unit s^-1/2) starting at t = 0:
    (1/(T_j T_k)) int int min(s, t) ds dt = a_j + T_j/2 (j earlier, disjoint), a_j + T_j/3 on the diagonal."""
    a0 = np.asarray(t0, dtype=float)
    T = np.asarray(T, dtype=float)
    if np.any(a0 < 0):
        raise ValueError("random-walk windows must start at t >= 0 (the walk starts at the recording's t = 0)")
    mid = a0 + T / 2.0
    earlier = a0[:, None] <= a0[None, :]
    C = np.where(earlier, mid[:, None], mid[None, :])
    np.fill_diagonal(C, a0 + T / 3.0)
    return C


# ----------------------------------------------------------------------------------------------------------
# model
# ----------------------------------------------------------------------------------------------------------
@dataclass
class MeanNoiseModel:
    """Noise model of one triad's rate reading, per axis (module docstring): ``Q`` [unit s], ``N``
    [unit s^1/2], ``slow`` per axis 'gm' | 'rw' | 'none', ``sigma`` [unit] and ``tc`` [s] (GM), ``K``
    [unit s^-1/2] (RW); fit diagnostics in ``fit`` (per axis dicts); ``source`` says which Allan data."""

    unit: str
    Q: np.ndarray
    N: np.ndarray
    slow: list
    sigma: np.ndarray
    tc: np.ndarray
    K: np.ndarray
    source: str = ""
    fit: list = field(default_factory=list)

    def avar(self, tau):
        """Model Allan variance (len(tau), 3) [unit^2]."""
        t = np.atleast_1d(np.asarray(tau, dtype=float))
        out = np.empty((t.size, 3))
        for a in range(3):
            v = 3.0 * self.Q[a] ** 2 / t**2 + self.N[a] ** 2 / t
            if self.slow[a] == "gm":
                v = v + gm_avar(t, self.sigma[a], self.tc[a])
            elif self.slow[a] == "rw":
                v = v + self.K[a] ** 2 * t / 3.0
            out[:, a] = v
        return out

    def adev(self, tau):
        return np.sqrt(self.avar(tau))

    def mean_cov(self, t0, T, axis: int):
        """Covariance (M, M) [unit^2] of the means of windows starting at ``t0`` [s from the recording start]
        lasting ``T`` [s] on ``axis`` (0, 1, 2), eq. (2)."""
        t0 = np.asarray(t0, dtype=float)
        T = np.asarray(T, dtype=float)
        C = np.diag(self.N[axis] ** 2 / T + 2.0 * self.Q[axis] ** 2 / T**2)
        if self.slow[axis] == "gm" and self.sigma[axis] > 0:
            C = C + self.sigma[axis] ** 2 * gm_mean_cov(t0, T, self.tc[axis])
        elif self.slow[axis] == "rw" and self.K[axis] > 0:
            C = C + self.K[axis] ** 2 * rw_mean_cov(t0, T)
        return C

    def mean_cov_axes(self, t0, T):
        """(3, M, M): :meth:`mean_cov` for the three axes."""
        return np.stack([self.mean_cov(t0, T, a) for a in range(3)])

    def describe(self, axis: int) -> str:
        f = self.fit[axis] if self.fit else {}
        s = f"N = {self.N[axis]:.4g} {self.unit} s^1/2, Q = {self.Q[axis]:.3g} {self.unit} s"
        if self.slow[axis] == "gm":
            ci = f.get("sigma_ci95"), f.get("tc_ci95")
            s += (f", Gauss-Markov bias sigma = {self.sigma[axis]:.4g} {self.unit}"
                  + (f" (95 %: {ci[0][0]:.3g}-{ci[0][1]:.3g})" if ci[0] else "")
                  + f", Tc = {self.tc[axis]:.4g} s" + (f" (95 %: {ci[1][0]:.3g}-{ci[1][1]:.3g})" if ci[1] else ""))
        elif self.slow[axis] == "rw":
            s += f", random walk K = {self.K[axis]:.4g} {self.unit} s^-1/2"
        else:
            s += ", no slow component (fitted variance zero)"
        if self.slow[axis] != "none" and f and not f.get("slow_detected_bic", True):
            s += " [not significant by BIC: kept, about unbiased]"
        if "coverage" in f:
            s += f"; model inside the 95 % Allan interval at {100 * f['coverage']:.0f} % of {f['n_points']} taus"
        return s

    def to_dict(self) -> dict:
        return {"unit": self.unit, "source": self.source,
                "axes": [{"axis": "xyz"[a], "Q_unit_s": float(self.Q[a]), "N_unit_s05": float(self.N[a]),
                          "slow": self.slow[a], "gm_sigma": float(self.sigma[a]), "gm_tc_s": float(self.tc[a]),
                          "rw_K_unit_s-05": float(self.K[a]), "fit": _jsonable(self.fit[a] if self.fit else {}),
                          "description": self.describe(a)} for a in range(3)],
                "equations": "C_jk = delta_jk (N^2/T_j + 2 Q^2/T_j^2) + slow (GM: double integral of "
                             "sigma^2 exp(-|s-t|/Tc) over the windows / (T_j T_k); RW: K^2 min-integral)"}


def _jsonable(d):
    out = {}
    for k, v in d.items():
        if isinstance(v, (tuple, list, np.ndarray)):
            out[k] = [float(x) for x in v]
        elif isinstance(v, (float, np.floating, int, np.integer)):
            out[k] = float(v)
        else:
            out[k] = v
    return out


# ----------------------------------------------------------------------------------------------------------
# fit
# ----------------------------------------------------------------------------------------------------------
def _points(results, axis, tau_min_s):
    tau, av, edf, lo, hi = [], [], [], [], []
    for r in results:
        sel = r.tau >= tau_min_s
        tau.append(r.tau[sel])
        av.append(r.avar[sel, axis])
        edf.append(np.broadcast_to(r.edf, r.tau.shape)[sel])
        lo.append(r.lo[sel, axis])
        hi.append(r.hi[sel, axis])
    return tuple(np.concatenate(v) for v in (tau, av, edf, lo, hi))


def _nnls_fit(A, av, edf, fixed):
    """Iteratively reweighted NNLS of av - fixed = A c with weights sqrt(edf/2)/model (the Gamma maximum-likelihood
    score equations once converged); returns c, deviance (:func:`gamma_deviance`), model."""
    w = np.sqrt(edf / 2.0) / av
    c = np.zeros(A.shape[1])
    for _ in range(8):
        c = allan.nnls(A * w[:, None], (av - fixed) * w)
        model = np.maximum(A @ c + fixed, 1e-300)
        w = np.sqrt(edf / 2.0) / model
    return c, gamma_deviance(av, model, edf), model


def gamma_deviance(av, model, edf):
    """Deviance of Allan variances av ~ model x chi2(edf)/edf (Gamma): sum_i edf_i (av/model - 1 - ln(av/model)).

    -2 log-likelihood up to a constant; approximately chi-square(n) (for large edf it is
    sum (edf/2) ln(av/model)^2). Unlike the squared log ratio it is not biased at the few-edf long taus, where
    E[ln(chi2_nu/nu)] < 0 would pull the model -- and the fitted correlation time -- down."""
    r = av / model
    return float(np.sum(edf * (r - 1.0 - np.log(r))))


def fit_mean_noise(results, *, Q=None, tau_min_s: float = 5.0, unit: str = "", source: str = "",
                   tc_grid=None) -> MeanNoiseModel:
    """Fit the model of the module docstring to one or more :class:`allan.AllanResult` of the same triad.

    ``Q``: known quantisation phase noise per axis [unit s] (e.g. :data:`PULSE_COUNTER_Q` for pulse
    counters), else fitted. ``tau_min_s``: shortest tau used [s]. ``tc_grid``: correlation times tried [s]
    (default 40 log-spaced values from tau_min to 20 x the longest tau). Raises :class:`NoiseModelError` when
    fewer than 4 Allan points remain.
    """
    results = [r for r in results if r is not None]
    if not results:
        raise NoiseModelError("no Allan deviation to fit")
    taus = np.concatenate([r.tau for r in results])
    tmax = float(taus.max())
    if tc_grid is None:
        tc_grid = np.logspace(math.log10(max(tau_min_s, 1e-3)), math.log10(20.0 * tmax), 40)
    tc_grid = np.asarray(tc_grid, dtype=float)
    Qv = np.full(3, np.nan) if Q is None else np.broadcast_to(np.asarray(Q, float), (3,)).copy()
    out_Q, out_N, slow, sig, tcs, Ks, fits = np.zeros(3), np.zeros(3), [], np.zeros(3), np.full(3, np.nan), \
        np.zeros(3), []
    for a in range(3):
        tau, av, edf, lo, hi = _points(results, a, tau_min_s)
        if tau.size < 4:
            raise NoiseModelError(f"axis {'xyz'[a]}: only {tau.size} Allan points with tau >= {tau_min_s} s; "
                                  "a longer static record is needed")
        known_q = np.isfinite(Qv[a])
        # the quantisation term of the *Allan curve* is always fitted: a pulse counter at rest with little noise
        # repeats a carry pattern that is not yet random over seconds to a minute, so its short-tau Allan
        # variance is not 3 Q^2 / tau^2 with the uniform-carry Q; the carry at the ends of a calibration segment
        # is uniform (the moves between positions randomise it), so the means use the known Q
        fixed = np.zeros_like(tau)
        base = [3.0 / tau**2, 1.0 / tau]
        nb = len(base)
        npts = tau.size
        pen = math.log(npts)
        cands = {}
        c, mf, _ = _nnls_fit(np.column_stack(base), av, edf, fixed)
        cands["none"] = (mf + pen * nb, c, None)
        c, mf, _ = _nnls_fit(np.column_stack(base + [tau / 3.0]), av, edf, fixed)
        cands["rw"] = (mf + pen * (nb + 1), c, None)

        def gm_fit(log_tc):
            tc = math.exp(log_tc)
            return _nnls_fit(np.column_stack(base + [gm_avar(tau, 1.0, tc)]), av, edf, fixed)

        prof = np.array([gm_fit(math.log(t))[1] for t in tc_grid])
        j = int(np.argmin(prof))
        lo_t = math.log(tc_grid[max(j - 1, 0)])
        hi_t = math.log(tc_grid[min(j + 1, len(tc_grid) - 1)])
        if hi_t > lo_t:
            r = optimize.minimize_scalar(lambda lt: gm_fit(lt)[1], bounds=(lo_t, hi_t), method="bounded",
                                         options={"xatol": 1e-3})
            ltc = float(r.x) if r.fun <= prof[j] else math.log(tc_grid[j])
        else:
            ltc = math.log(tc_grid[j])
        c, mf, model = gm_fit(ltc)
        cands["gm"] = (mf + pen * (nb + 2), c, math.exp(ltc))
        # the slow part is always fitted (a term the record cannot resolve still has an unbiased, possibly
        # small, variance; dropping it by a significance test would bias the standard errors low): GM or RW
        # by BIC, 'none' only when the fitted slow variance is zero
        best = "gm" if cands["gm"][0] <= cands["rw"][0] else "rw"
        crit, c, tc = cands[best]
        if c[-1] <= 0:
            best = "none"
            crit, c, tc = cands["none"]
        detected = cands[best][0] < cands["none"][0]
        q = Qv[a] if known_q else math.sqrt(c[0])
        q_allan = math.sqrt(c[0])
        n_w = math.sqrt(c[nb - 1])
        info = {"n_points": int(npts), "tau_range_s": (float(tau.min()), float(tau.max())),
                "criterion": {k: float(v[0]) for k, v in cands.items()}, "chosen": best,
                "slow_detected_bic": bool(detected), "Q_allan": q_allan}
        s_a = tc_a = k_a = 0.0
        if best == "gm":
            s_a, tc_a = math.sqrt(c[-1]), tc
            inside = prof <= prof.min() + 3.84
            info["tc_ci95"] = (float(tc_grid[inside].min()), float(tc_grid[inside].max()))
            A = np.column_stack(base + [gm_avar(tau, 1.0, tc)])
            W = np.sqrt(edf / 2.0) / model
            try:
                covc = np.linalg.inv((A * W[:, None]).T @ (A * W[:, None]))
                se = math.sqrt(max(covc[-1, -1], 0.0))
                info["sigma_ci95"] = (math.sqrt(max(c[-1] - 1.96 * se, 0.0)), math.sqrt(c[-1] + 1.96 * se))
            except np.linalg.LinAlgError:
                pass
        elif best == "rw":
            k_a = math.sqrt(c[-1])
        out_Q[a], out_N[a] = q, n_w
        slow.append(best)
        sig[a], tcs[a], Ks[a] = s_a, tc_a, k_a
        fits.append(info)
    m = MeanNoiseModel(unit=unit or results[0].unit, Q=out_Q, N=out_N, slow=slow, sigma=sig, tc=tcs, K=Ks,
                       source=source, fit=fits)
    for a in range(3):
        tau, av, edf, lo, hi = _points(results, a, tau_min_s)
        md = np.sqrt(m.avar(tau)[:, a] + 3.0 * (fits[a]["Q_allan"] ** 2 - m.Q[a] ** 2) / tau**2)
        fits[a]["coverage"] = float(np.mean((md >= lo) & (md <= hi)))
    return m


# ----------------------------------------------------------------------------------------------------------
# recordings
# ----------------------------------------------------------------------------------------------------------
def is_pulse_counter(ds, sensor: str) -> bool:
    """True for integer pulse counts with the remainder carried (quantisation Q = 1/sqrt(12) count known)."""
    v = ds[sensor]
    return (str(ds.attrs.get("quantization", "")).startswith("pulse counter") and v.attrs.get("units") == "count"
            and v.attrs.get("sample_kind") == "increment")


def long_record_allan(ds, sensor: str, *, confidence: float = 0.95) -> allan.AllanResult:
    """Overlapping Allan deviation of the whole of a static recording (tau up to half its length)."""

    y, unit = rate_reading(ds, sensor)
    try:
        return allan.adev(y, float(ds.attrs["sample_rate_hz"]), confidence=confidence, unit=unit)
    except allan.AllanError as exc:
        raise SegmentError(f"{ds.attrs.get('_path', '<long static record>')}: variable '{sensor}': {exc}") from exc


def triad_noise(session_allan: allan.AllanResult, long_ds, sensor: str, *, tau_min_s: float = 5.0,
                pulse_counter: bool | None = None) -> MeanNoiseModel:
    """Noise model of ``sensor`` from the session's pooled static Allan deviation and the long static record
    ``long_ds`` (an xarray recording of the same unit at rest; same output unit required)."""
    la = long_record_allan(long_ds, sensor)
    if session_allan is not None and session_allan.unit != la.unit:
        raise NoiseModelError(f"{long_ds.attrs.get('_path', '<long static record>')}: '{sensor}' rate unit "
                              f"{la.unit!r} differs from the session's {session_allan.unit!r}; the long record "
                              "must come from the same unit with the same output")
    pc = is_pulse_counter(long_ds, sensor) if pulse_counter is None else pulse_counter
    dur = la.n_samples / la.fs
    src = (f"Allan deviation of the session's static segments (tau <= {session_allan.tau[-1]:.3g} s) and of the "
           f"long static record {long_ds.attrs.get('_path', '')} ({dur / 3600.0:.3g} h, tau <= {la.tau[-1]:.4g} s), "
           f"tau >= {tau_min_s} s" + ("; Q = 1/sqrt(12) count (pulse counter)" if pc else ""))
    return fit_mean_noise([session_allan, la], Q=PULSE_COUNTER_Q if pc else None, tau_min_s=tau_min_s,
                          unit=la.unit, source=src)


# ----------------------------------------------------------------------------------------------------------
# covariance of the calibration's observations
# ----------------------------------------------------------------------------------------------------------
def _need_times(obj, what):
    if getattr(obj, "t_start_s", None) is None and getattr(obj, "t_plus", None) is None:
        raise NoiseModelError(f"{what}: the window start times are unknown (closed-form means); the correlation "
                              "between segments needs the times of the recording")


def static_cov(static, model: MeanNoiseModel):
    """(3, M, M) covariance of the static means of ``static`` (``segments.StaticMeans``) [output unit^2]."""
    _need_times(static, "static means")
    return model.mean_cov_axes(static.t_start_s, static.duration_s)


def eq25_cov(pairs, static, model: MeanNoiseModel):
    """(3, n, n) covariance of [plus (J), minus (J), static (M)] means (the order of
    ``calibration._eq25_covariance``) [output unit^2]; ``static`` may be None."""
    if pairs.t_plus is None or pairs.t_minus is None:
        raise NoiseModelError("rotation pairs: the window start times are unknown (closed-form means)")
    t0 = [pairs.t_plus, pairs.t_minus]
    T = [pairs.duration_plus, pairs.duration_minus]
    if static is not None:
        _need_times(static, "static means")
        t0.append(static.t_start_s)
        T.append(static.duration_s)
    return model.mean_cov_axes(np.concatenate(t0), np.concatenate(T))


def observation_covs(inp, models: dict) -> dict:
    """Full covariances for the default calibration of ``segments.CalibrationInputs`` ``inp`` (not modified):
    ``accel_static`` (3, M, M) of the accelerometer static means, ``gyro_eq25`` (3, n, n) of the gyro
    [plus, minus, static] means (None without rotation pairs) [output unit^2]."""
    out = {"accel_static": static_cov(inp.accel_static, models["accel"]), "gyro_eq25": None}
    if inp.gyro_pairs is not None:
        out["gyro_eq25"] = eq25_cov(inp.gyro_pairs, inp.gyro_static, models["gyro"])
    return out
