"""Overlapping Allan deviation, its confidence intervals, a noise-model fit, and the sigma of a segment mean.

Why this module exists
----------------------
Every chi-square and every standard error of a calibration needs the standard deviation of a *segment
mean* (one static position, one whole-revolution rotation window). The scatter of the samples inside
one 60 s window only measures the fast (white) noise: the mean of such a window also wanders with
bias instability and rate random walk, which the within-window scatter cannot see. The Allan deviation
at tau = segment duration is the conventional measure of how much consecutive T-long means differ:
for white rate noise it equals the standard deviation of a T-long mean exactly, and for the slower
noises it is the usual proxy (IEEE Std 952 / 1554 practice). So:

    sigma(mean of a T-long segment) = ADEV(tau = T)                                         (1)

Units: whatever the rate samples are in (count s-1 for the synthetic unit, m s-2, rad s-1, ...);
tau in seconds. Rate samples ``y_k`` at sample rate ``fs``; the "phase" is the integral
``theta_k = sum_{j<k} y_j / fs`` (``N = n + 1`` phase points).

Overlapping Allan variance at cluster size ``m`` (tau = m / fs)::

    AVAR(tau) = sum_{k=0}^{N-2m-1} (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2 / (2 tau^2 (N - 2m))     (2)

Confidence intervals: chi-square with the equivalent degrees of freedom of the overlapping estimator for
white rate noise (Lesage & Audoin's approximation, as tabulated in Riley, NIST SP 1065 §5.3)::

    edf = (3 (N - 1) / (2 m) - 2 (N - 2) / N) * 4 m^2 / (4 m^2 + 5)                          (3)

It is exact only for white rate noise; for flicker and random-walk noise the true edf is smaller, so the
intervals are somewhat too narrow at the longest taus. This is the "standard simple approximation".

Noise model (IEEE Std 952 Annex C), fitted by non-negative least squares to the AVAR curve::

    AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2   (4)

Q quantisation, N angle/velocity random walk, B bias instability, K rate random walk, R rate ramp.
(4) is used to evaluate (1). Inside the measured tau range the full model is used. A segment mean of
duration T needs ADEV(T), but T-long segments only support tau <= T/2 (static segments are pooled for the
estimate); beyond the longest measured tau a term fitted to one noisy long-tau point would blow up the
extrapolation, so there the model is refitted with the terms the data clearly support (penalised choice
among Q, N, B, K; the ramp R is never extrapolated). A long static recording (tau_max >= T) removes the
extrapolation; :attr:`AllanResult.tau` shows what the data support.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy import optimize

from calib.core.distributions import chi2_ppf


class AllanError(ValueError):
    """Input that gives no usable Allan deviation (too short, flat, non-finite)."""


def octave_clusters(n: int, max_fraction: float = 0.5) -> np.ndarray:
    """Octave-spaced cluster sizes m = 1, 2, 4, ... with 2 m <= max_fraction * 2 * n (i.e. tau <= T/2 by default)."""
    if n < 3:
        raise AllanError(f"{n} samples: at least 3 are needed for one Allan variance term")
    m_max = max(1, int(math.floor(max_fraction * n)))
    m_max = min(m_max, (n) // 2)
    out = []
    m = 1
    while m <= m_max:
        out.append(m)
        m *= 2
    if out[-1] < m_max and m_max >= 1.25 * out[-1]:
        out.append(m_max)  # the longest cluster the record supports (tau = T / 2 by default)
    return np.array(out, dtype=np.int64)


def edf_white(n_phase, m):
    """Equivalent degrees of freedom of the overlapping AVAR, eq. (3) of the module docstring (>= 1)."""
    N = np.asarray(n_phase, dtype=float)
    m = np.asarray(m, dtype=float)
    e = (3.0 * (N - 1.0) / (2.0 * m) - 2.0 * (N - 2.0) / N) * 4.0 * m * m / (4.0 * m * m + 5.0)
    return np.maximum(e, 1.0)


@numba.njit(cache=True)
def _second_difference_sums(theta, ms, sumsq, nterms):  # pragma: no cover - compiled
    """sumsq[i, c] = sum_k (theta[k+2m, c] - 2 theta[k+m, c] + theta[k, c])^2, k = 0..N-2m-1, m = ms[i], summed in
    k order per column (the order of ``np.einsum('ij,ij->j', d, d)`` on an (N-2m, ncols >= 2) array). Three
    columns at a time in local accumulators (independent sums: the same order per column)."""
    n_phase, k = theta.shape
    for i in range(ms.shape[0]):
        m = ms[i]
        nt = n_phase - 2 * m
        if nt < 1:
            continue
        a = theta[2 * m:2 * m + nt]  # views: the loops index from 0 (no negative-index handling)
        b = theta[m:m + nt]
        e = theta[:nt]
        c0 = 0
        while c0 < k:
            w = min(3, k - c0)
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            if w == 3:
                for t in range(nt):
                    d0 = a[t, c0] - 2.0 * b[t, c0] + e[t, c0]
                    d1 = a[t, c0 + 1] - 2.0 * b[t, c0 + 1] + e[t, c0 + 1]
                    d2 = a[t, c0 + 2] - 2.0 * b[t, c0 + 2] + e[t, c0 + 2]
                    s0 += d0 * d0
                    s1 += d1 * d1
                    s2 += d2 * d2
            elif w == 2:
                for t in range(nt):
                    d0 = a[t, c0] - 2.0 * b[t, c0] + e[t, c0]
                    d1 = a[t, c0 + 1] - 2.0 * b[t, c0 + 1] + e[t, c0 + 1]
                    s0 += d0 * d0
                    s1 += d1 * d1
            else:
                for t in range(nt):
                    d0 = a[t, c0] - 2.0 * b[t, c0] + e[t, c0]
                    s0 += d0 * d0
            sumsq[i, c0] = s0
            if w > 1:
                sumsq[i, c0 + 1] = s1
            if w > 2:
                sumsq[i, c0 + 2] = s2
            c0 += w
        nterms[i] = nt


@numba.njit(cache=True)
def _column_means(y):  # pragma: no cover - compiled
    """Column means of a C-ordered (n, k) array summed row by row (numpy's ``y.mean(axis=0)`` for k >= 2)."""
    n, k = y.shape
    s = np.zeros(k)
    for i in range(n):
        for j in range(k):
            s[j] += y[i, j]
    return s / n


@numba.njit(cache=True)
def _phase(y, mu, fs):  # pragma: no cover - compiled
    """theta[0] = 0, theta[i + 1] = theta[i] + (y[i] - mu) / fs: ``np.cumsum((y - mu) / fs, axis=0)``."""
    n, k = y.shape
    theta = np.zeros((n + 1, k))
    for j in range(k):
        theta[1, j] = (y[0, j] - mu[j]) / fs
    for i in range(1, n):
        for j in range(k):
            theta[i + 1, j] = theta[i, j] + (y[i, j] - mu[j]) / fs
    return theta


def avar_sums(y, fs: float, ms):
    """Raw ingredients of eq. (2) for one contiguous record, for pooling over several records.

    ``y`` (n,) or (n, k) rate samples. Returns ``(sumsq (len(ms), k), nterms (len(ms),))`` where
    ``sumsq`` is the sum of squared second differences of the phase [unit^2 s^2] and ``nterms`` = N - 2m
    (0 where the record is too short for that m).

    Several columns (k >= 2): compiled loops without temporaries that do numpy's operations in numpy's order
    (``y.mean(axis=0)`` of a C-ordered array and ``einsum('ij,ij->j')`` sum row by row for k >= 2), so the
    numbers are the same to the last bit (tests/signal/test_allan.py). One column: numpy (its contiguous sums
    are pairwise / vectorised, in another order).
    """
    y = np.asarray(y, dtype=np.float64)
    if y.ndim == 1:
        y = y[:, None]
    if not np.all(np.isfinite(y)):
        raise AllanError("rate samples contain NaN or Inf")
    n = y.shape[0]
    ms = np.asarray(ms, dtype=np.int64)
    sumsq = np.zeros((len(ms), y.shape[1]))
    nterms = np.zeros(len(ms), dtype=np.int64)
    if y.shape[1] >= 2 and n >= 1:
        # remove the mean: AVAR is blind to a constant and the cumulative sum stays small (no cancellation)
        mu = _column_means(y) if y.flags.c_contiguous else y.mean(axis=0)
        theta = _phase(y, np.ascontiguousarray(mu, dtype=np.float64), float(fs))
        _second_difference_sums(theta, ms, sumsq, nterms)
        return sumsq, nterms
    # remove the mean: AVAR is blind to a constant and the cumulative sum stays small (no cancellation)
    yc = y - y.mean(axis=0)
    theta = np.zeros((n + 1, y.shape[1]))
    np.cumsum(yc / fs, axis=0, out=theta[1:])
    N = n + 1
    for i, m in enumerate(ms):
        k = N - 2 * m
        if k < 1:
            continue
        d = theta[2 * m:] - 2.0 * theta[m:N - m] + theta[:k]
        sumsq[i] = np.einsum("ij,ij->j", d, d)
        nterms[i] = k
    return sumsq, nterms


@dataclass
class NoiseModel:
    """Coefficients of eq. (4) per axis, in the rate unit of the data (Q in unit*s, N in unit*s^0.5, ...)."""

    Q: np.ndarray
    N: np.ndarray
    B: np.ndarray
    K: np.ndarray
    R: np.ndarray

    def avar(self, tau):
        """Model Allan variance (len(tau), naxes) of eq. (4)."""
        t = np.atleast_1d(np.asarray(tau, dtype=float))[:, None]
        return (3.0 * self.Q**2 / t**2 + self.N**2 / t + 2.0 * math.log(2.0) / math.pi * self.B**2
                + self.K**2 * t / 3.0 + self.R**2 * t**2 / 2.0)

    def adev(self, tau):
        return np.sqrt(self.avar(tau))


#: iteration limit of :func:`nnls` per unknown (scipy's default is 3 per unknown)
NNLS_ITERATIONS = 100


def nnls(M, v) -> np.ndarray:
    """``argmin ||M c - v||`` subject to ``c >= 0`` (Lawson-Hanson, ``scipy.optimize.nnls``), allowed
    :data:`NNLS_ITERATIONS` iterations per unknown. scipy's default of 3 stops short on ill-conditioned AVAR fits
    (all five terms of eq. (4) on a curve that climbs six decades, condition ~3e7: 16 iterations for 5 unknowns
    reach the optimum, the default allows 15); a problem that still does not converge is an :class:`AllanError`,
    not a crash. Where the default limit sufficed, the same iterations and the same numbers."""
    M = np.asarray(M, dtype=float)
    try:
        return optimize.nnls(M, v, maxiter=NNLS_ITERATIONS * M.shape[1])[0]
    except RuntimeError as exc:
        raise AllanError(f"the noise-model fit (non-negative least squares, {M.shape[1]} terms on {M.shape[0]} taus) "
                         f"did not converge: {exc}") from None


def _basis(tau):
    t = np.asarray(tau, dtype=float)
    return np.stack([3.0 / t**2, 1.0 / t, np.full_like(t, 2.0 * math.log(2.0) / math.pi), t / 3.0, t**2 / 2.0],
                    axis=1)


@dataclass
class AllanResult:
    """Overlapping Allan deviation on octave-spaced taus.

    ``tau`` (k,) s; ``adev``, ``lo``, ``hi`` (k, naxes) in the rate unit of the data; ``edf`` (k,);
    ``nterms`` (k,) number of squared differences summed; ``confidence`` of the [lo, hi] interval.
    """

    tau: np.ndarray
    adev: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    edf: np.ndarray
    nterms: np.ndarray
    fs: float
    confidence: float
    unit: str = ""
    n_records: int = 1
    n_samples: int = 0
    _models: dict = field(default_factory=dict, repr=False)

    @property
    def avar(self):
        return self.adev**2

    def noise_model(self, terms=("Q", "N", "B", "K", "R")) -> NoiseModel:
        """Fit eq. (4) per axis with the given ``terms`` by NNLS, relative weights sqrt(edf/2)/AVAR (reweighted
        twice with the model); terms left out are zero."""
        key = tuple(terms)
        if key in self._models:
            return self._models[key]
        names = ("Q", "N", "B", "K", "R")
        use = [names.index(t) for t in terms]
        A = _basis(self.tau)[:, use]
        coef = np.zeros((5, self.adev.shape[1]))
        for ax in range(self.adev.shape[1]):
            av = self.avar[:, ax]
            w = np.sqrt(self.edf / 2.0) / av
            c = None
            for _ in range(3):
                c = nnls(A * w[:, None], av * w)
                model = A @ c
                w = np.sqrt(self.edf / 2.0) / np.maximum(model, 1e-300)
            coef[use, ax] = c
        c = np.sqrt(coef)
        self._models[key] = NoiseModel(Q=c[0], N=c[1], B=c[2], K=c[3], R=c[4])
        return self._models[key]

    def misfit(self, model: NoiseModel) -> np.ndarray:
        """Per-axis sum over taus of (edf/2) ln(AVAR_obs / AVAR_model)^2 (approximate -2 log-likelihood)."""
        mod = model.avar(self.tau)
        return np.sum(self.edf[:, None] / 2.0 * np.log(self.avar / mod) ** 2, axis=0)

    def extrapolation_model(self, penalty: float = 16.0) -> NoiseModel:
        """Model for taus beyond the data: terms chosen per axis among the subsets of {Q, N, B, K} that contain
        N, by misfit + ``penalty`` x (number of terms); a term must clearly improve the fit to be kept (a floor
        or random walk fitted to one noisy long-tau point would otherwise inflate every extrapolated sigma).
        The rate ramp R is never extrapolated. The default penalty keeps white-noise data at the white law
        (checked over 40 seeds: ratio 1.000 +- 0.003) and picks up a random walk that dominates the longest
        measured taus; a random walk that only matters beyond them cannot be seen (record a long static
        segment)."""
        if ("extrap", penalty) in self._models:
            return self._models[("extrap", penalty)]
        cands = [("N",), ("Q", "N"), ("N", "B"), ("Q", "N", "B"), ("N", "K"), ("Q", "N", "K"), ("N", "B", "K"),
                 ("Q", "N", "B", "K")]
        fits = [self.noise_model(c) for c in cands]
        crit = np.array([self.misfit(f) + penalty * len(c) for f, c in zip(fits, cands)])  # (4, naxes)
        best = np.argmin(crit, axis=0)
        pick = {k: np.array([getattr(fits[best[a]], k)[a] for a in range(self.adev.shape[1])])
                for k in ("Q", "N", "B", "K", "R")}
        m = NoiseModel(**pick)
        self._models[("extrap", penalty)] = m
        return m

    def sigma_of_mean(self, duration_s, method: str = "model"):
        """Standard deviation of the mean of a segment lasting ``duration_s`` seconds, per axis.

        Eq. (1): ADEV at tau = duration. ``method='model'``: the fitted noise model (4) with all terms inside
        the measured tau range, and with the non-rising terms (:meth:`extrapolation_model`) beyond it;
        ``'interp'``: log-log interpolation of the measured ADEV inside the range, the model outside.
        Returns an array (..., naxes) for scalar or array ``duration_s``.
        """
        d = np.asarray(duration_s, dtype=float)
        if np.any(~np.isfinite(d)) or np.any(d <= 0):
            raise AllanError(f"segment duration must be positive, got {duration_s}")
        flat = np.atleast_1d(d).ravel()
        inside = flat <= self.tau[-1] * (1.0 + 1e-9)
        out = np.empty((flat.size, self.adev.shape[1]))
        if inside.any():
            out[inside] = self.noise_model().adev(flat[inside])
        if (~inside).any():
            out[~inside] = self.extrapolation_model().adev(flat[~inside])
        if method == "interp":
            lt = np.log(self.tau)
            sel = inside & (flat >= self.tau[0])
            for ax in range(self.adev.shape[1]):
                if sel.any():
                    out[sel, ax] = np.exp(np.interp(np.log(flat[sel]), lt, np.log(self.adev[:, ax])))
        elif method != "model":
            raise ValueError(f"method must be 'model' or 'interp', got {method!r}")
        return out.reshape(d.shape + (self.adev.shape[1],))


def _finish(sumsq, nterms, edf, ms, fs, confidence, unit, n_records, n_samples) -> AllanResult:
    ok = nterms > 0
    if not ok.any():
        raise AllanError("records too short for any Allan variance term")
    ms, sumsq, nterms, edf = ms[ok], sumsq[ok], nterms[ok], edf[ok]
    tau = ms / fs
    av = sumsq / (2.0 * tau[:, None] ** 2 * nterms[:, None])
    if np.any(av <= 0):
        ax = int(np.argmax((av <= 0).any(axis=0)))
        raise AllanError(f"axis {'xyz'[ax] if av.shape[1] == 3 else ax}: Allan variance is zero - the samples are "
                         "constant (flat data). A flat channel gives no noise estimate; check that the channel "
                         "is connected and the units are right, or give sigma explicitly")
    alpha = 1.0 - confidence
    lo = av * edf[:, None] / chi2_ppf(1.0 - alpha / 2.0, edf)[:, None]
    hi = av * edf[:, None] / chi2_ppf(alpha / 2.0, edf)[:, None]
    return AllanResult(tau=tau, adev=np.sqrt(av), lo=np.sqrt(lo), hi=np.sqrt(hi), edf=edf, nterms=nterms, fs=fs,
                       confidence=confidence, unit=unit, n_records=n_records, n_samples=n_samples)


def adev(y, fs: float, *, ms=None, confidence: float = 0.95, unit: str = "") -> AllanResult:
    """Overlapping Allan deviation of rate samples ``y`` (n,) or (n, naxes) at ``fs`` Hz.

    ``ms``: cluster sizes (default octave-spaced, tau up to half the record). Raises :class:`AllanError`
    for records shorter than 3 samples or flat (constant) data.
    """
    y = np.asarray(y, dtype=np.float64)
    if y.ndim == 1:
        y = y[:, None]
    if not (fs > 0 and math.isfinite(fs)):
        raise AllanError(f"sample rate must be positive, got {fs}")
    n = y.shape[0]
    ms = octave_clusters(n) if ms is None else np.asarray(ms, dtype=np.int64)
    sumsq, nterms = avar_sums(y, fs, ms)
    edf = edf_white(n + 1, ms)
    return _finish(sumsq, nterms, edf, ms, fs, confidence, unit, 1, n)


def adev_pooled(records, fs: float, *, confidence: float = 0.95, unit: str = "", max_fraction: float = 0.5):
    """Allan deviation pooled over several independent contiguous records (e.g. all static segments).

    The squared second differences and their counts are summed over the records, so each record only
    contributes the taus it can support (tau <= max_fraction x its length); degrees of freedom add.
    A constant offset per record (a different attitude per static position) does not matter.
    """
    recs = [np.asarray(r, dtype=np.float64).reshape(len(r), -1) for r in records if len(r) >= 3]
    if not recs:
        raise AllanError("no record with at least 3 samples to pool")
    nmax = max(len(r) for r in recs)
    ms_all = octave_clusters(nmax, max_fraction)
    k = recs[0].shape[1]
    sumsq = np.zeros((len(ms_all), k))
    nterms = np.zeros(len(ms_all), dtype=np.int64)
    edf = np.zeros(len(ms_all))
    for r in recs:
        if r.shape[1] != k:
            raise AllanError("records differ in number of axes")
        ms = ms_all[ms_all <= max(1, int(max_fraction * len(r)))]
        s, c = avar_sums(r, fs, ms)
        sumsq[: len(ms)] += s
        nterms[: len(ms)] += c
        edf[: len(ms)] += np.where(c > 0, edf_white(len(r) + 1, ms), 0.0)
    return _finish(sumsq, nterms, np.maximum(edf, 1.0), ms_all, fs, confidence, unit, len(recs),
                   sum(len(r) for r in recs))
