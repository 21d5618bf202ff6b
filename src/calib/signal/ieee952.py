"""The IEEE Std 952-1997 noise terms of a static record, with confidence intervals, and Kalibr's noise parameters.

What allan_variance_ros / imu_utils do, with intervals that mean what they say. The Allan deviation itself is
:mod:`calib.signal.allan` (overlapping estimator, octave-spaced taus, chi-square intervals); the term model and
its weighted non-negative least-squares fit are :meth:`calib.signal.allan.AllanResult.noise_model`. This module
adds which terms the record supports, intervals for every term, the confidence band of the measured deviation
with the degrees of freedom of the noise type that dominates at each tau, the report and the data of its figure
(drawn by :mod:`calib.figures.allan_plots`).

Terms (IEEE Std 952-1997 Annex C; per sensor axis, rate unit ``u`` = rad s-1 for a gyro, m s-2 for an
accelerometer, whatever the record's rate unit otherwise)::

    AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3                        (1)

=====  ==========================================  ===========  =================================================
term   name (gyro / accelerometer)                 unit         reading on the log-log ADEV plot
=====  ==========================================  ===========  =================================================
``Q``  angle / velocity quantization noise          u s          slope -1 line, ADEV(tau = sqrt(3) s) = Q
``N``  angle / velocity random walk (white noise)   u s^1/2      slope -1/2 line, ADEV(tau = 1 s) = N
``B``  bias instability (flicker floor)             u            flat floor, ADEV_min = sqrt(2 ln 2 / pi) B = 0.664 B
``K``  rate / acceleration random walk              u s^-1/2     slope +1/2 line, ADEV(tau = 3 s) = K
=====  ==========================================  ===========  =================================================

``N`` is the density of the white rate noise: u s^1/2 = u / sqrt(Hz) (rad s-1 / sqrt(Hz) = rad s^-1/2; m s-2 /
sqrt(Hz) = m s^-3/2); the standard deviation of one sample at ``fs`` is N sqrt(fs). ``K`` is the density of the
white noise driving a random-walk bias: u s^-1/2 = u sqrt(Hz) / s (rad s^-2 / sqrt(Hz), m s^-3 / sqrt(Hz)); the
bias wanders by K sqrt(t) after t seconds. These are Kalibr's continuous-time ``*_noise_density`` (= N) and
``*_random_walk`` (= K) (:func:`kalibr_parameters`).

Which terms: ``N`` and ``K`` are always fitted; ``Q`` and ``B`` only where they clearly improve the fit (per axis,
among the four term sets, by the misfit of :meth:`~calib.signal.allan.AllanResult.misfit` + :data:`PENALTY` x the
number of terms, the rule of :meth:`~calib.signal.allan.AllanResult.extrapolation_model`). A fitted term that is
not there biases the others (a quantization term fitted to white noise takes about 0.7 % off N, 0.7 of its
standard error); a term left out reads 0 and is given an upper bound (below).

Intervals: parametric bootstrap. The fitted model is simulated ``n_boot`` times at the record's length and rate
(white rate noise, random walk, white phase noise, and flicker rate noise by spectral shaping), each replicate
goes through the same overlapping Allan deviation (the same taus), term selection and fit, and the interval is the
*basic bootstrap interval on the log scale*, [theta^2 / q_hi, theta^2 / q_lo] with q the replicates' quantiles,
whose centre, theta^2 / q_50, is the reported (bias-corrected) estimate of a resolved term: the interval
carries the estimator's multiplicative bias and skew (the fitted random walk of a short record is skewed and
biased low; on simulated white noise + random walk the plain percentile interval covered the truth at 92 % for N
and 89 % for K with this term selection, 77 % and 73 % with all four terms always fitted). The Allan deviations at different taus of one record are strongly correlated,
so intervals from the fit's own weights (independent taus) would be about 1.4 times too narrow for N; the
bootstrap has the correlation built in. A term the record does not resolve (fitted 0, or a lower quantile of 0)
gets the upper bound the confidence band allows: the largest coefficient whose own line stays below the band's
upper edge at every tau. The values over the axes (``combined``: the root mean square of the three axes, the
single number a filter with one parameter per sensor takes) get intervals from the same replicates.

Confidence band of the measured deviation: chi-square with the equivalent degrees of freedom of the noise type
the fitted model says dominates at each tau (white PM, white FM, flicker FM, random-walk FM: Riley, NIST SP 1065
Table 5, "simple" formulas, :func:`edf_simple`); :mod:`calib.signal.allan`'s white-FM edf is too large where the
random walk dominates.

Units follow the data (SI for the ``calib noise`` command: rad s-1 and m s-2 rates); tau in seconds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.stats import binom

from calib.core.distributions import chi2_ppf
from calib.signal import allan

TERMS = ("Q", "N", "B", "K")
#: the term sets tried per axis (N and K always, Q and B when they clearly improve the fit)
CANDIDATES = (("N", "K"), ("Q", "N", "K"), ("N", "B", "K"), ("Q", "N", "B", "K"))
#: misfit penalty per fitted term (as :meth:`calib.signal.allan.AllanResult.extrapolation_model`)
PENALTY = 16.0
#: default number of bootstrap replicates
N_BOOT = 200
#: power-law exponent alpha of the rate PSD (S_y ~ f^alpha) of each term, for the degrees of freedom
ALPHA = {"Q": 2, "N": 0, "B": -1, "K": -2}
#: sqrt(2 ln 2 / pi): ADEV of the flicker floor per unit bias instability B
FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
#: largest number of simulated phase values held at once in the bootstrap (memory: 8 bytes each)
BATCH_VALUES = 8_000_000
#: tail probability below which the points of the fitted model outside the band say the model misfits the record
MISFIT_P = 0.01
#: record lengths over which the bootstrap synthesises flicker noise before cutting one record out
FLICKER_SPAN = 4

DEFINITIONS = {
    "Q": "quantization noise (angle / velocity quantization): AVAR term 3 Q^2 / tau^2, slope -1 on the log-log "
         "ADEV plot, ADEV(sqrt(3) s) = Q; unit: rate unit x s",
    "N": "white-noise random walk (angle / velocity random walk), the white rate-noise density: AVAR term "
         "N^2 / tau, slope -1/2, ADEV(1 s) = N; unit: rate unit x s^1/2 = rate unit / sqrt(Hz)",
    "B": "bias instability (flicker floor): AVAR term (2 ln 2 / pi) B^2, flat, ADEV minimum = 0.664 B; unit: "
         "rate unit",
    "K": "rate / acceleration random walk, the density of the white noise driving a random-walk bias: AVAR term "
         "K^2 tau / 3, slope +1/2, ADEV(3 s) = K; unit: rate unit x s^-1/2 = rate unit x sqrt(Hz) / s",
}


class NoiseTermsError(ValueError):
    """A record that gives no noise terms (too short, flat, non-finite); the message says why, ``fix`` what to
    do."""

    def __init__(self, message, fix="record a longer static period"):
        super().__init__(message)
        self.fix = fix


#: the fix of a flat (constant) channel: a placeholder for a triad the logger did not record
FLAT_FIX = ("a constant channel holds no measurement: if the logger recorded no such triad, leave it out of the "
            "import settings (a partial record, declared absent); else check the channel")


# --------------------------------------------------------------------------- degrees of freedom


def edf_simple(n_phase, m, alpha: int):
    """Equivalent degrees of freedom of the overlapping Allan variance at cluster size ``m`` for ``n_phase`` phase
    points and power-law noise ``alpha`` (rate PSD ~ f^alpha: 2 white PM, 1 flicker PM, 0 white FM, -1 flicker
    FM, -2 random-walk FM): the simple approximations of Riley, NIST SP 1065 (2008), Table 5; at least 1."""
    N = np.asarray(n_phase, dtype=float)
    m = np.asarray(m, dtype=float)
    if alpha == 2:
        e = (N + 1.0) * (N - 2.0 * m) / (2.0 * (N - m))
    elif alpha == 1:
        e = np.exp(np.sqrt(np.log((N - 1.0) / (2.0 * m)) * np.log((2.0 * m + 1.0) * (N - 1.0) / 4.0)))
    elif alpha == 0:
        e = allan.edf_white(N, m)
    elif alpha == -1:
        e = np.where(m == 1, 2.0 * (N - 2.0) / (2.3 * N - 4.9), 5.0 * N**2 / (4.0 * m * (N + 3.0 * m)))
    elif alpha == -2:
        e = (N - 2.0) / m * ((N - 1.0) ** 2 - 3.0 * m * (N - 1.0) + 4.0 * m**2) / (N - 3.0) ** 2
    else:
        raise ValueError(f"alpha must be one of 2, 1, 0, -1, -2, got {alpha!r}")
    return np.maximum(e, 1.0)


def chi2_band(adev, edf, confidence: float):
    """Lower and upper ends of the chi-square interval of an Allan deviation with ``edf`` degrees of freedom."""
    a = 1.0 - confidence
    av = np.asarray(adev, dtype=float) ** 2
    lo = av * edf / chi2_ppf(1.0 - a / 2.0, edf)
    hi = av * edf / chi2_ppf(a / 2.0, edf)
    return np.sqrt(lo), np.sqrt(hi)


# --------------------------------------------------------------------------- fit


def term_avar(values: dict, tau) -> dict:
    """Each term's Allan variance (len(tau), naxes) of eq. (1) for coefficients ``values`` {term: (naxes,)}."""
    t = np.atleast_1d(np.asarray(tau, dtype=float))[:, None]
    return {"Q": 3.0 * values["Q"] ** 2 / t**2, "N": values["N"] ** 2 / t, "B": FLOOR**2 * values["B"] ** 2 + 0.0 * t,
            "K": values["K"] ** 2 * t / 3.0}


def select_fit(res: allan.AllanResult, penalty: float = PENALTY):
    """Per axis, the term set of :data:`CANDIDATES` with the least misfit + ``penalty`` x terms, fitted by
    :meth:`~calib.signal.allan.AllanResult.noise_model`. Returns ``(values (4, naxes) in TERMS order,
    chosen (naxes,) index into CANDIDATES)``."""
    fits = [res.noise_model(c) for c in CANDIDATES]
    crit = np.array([res.misfit(f) + penalty * len(c) for f, c in zip(fits, CANDIDATES)])
    best = np.argmin(crit, axis=0)
    k = res.adev.shape[1]
    values = np.array([[getattr(fits[best[a]], t)[a] for a in range(k)] for t in TERMS])
    return values, best


# --------------------------------------------------------------------------- bootstrap


@numba.njit(cache=True)
def _second_difference_sums(theta, ms):  # pragma: no cover - compiled
    n_phase, k = theta.shape
    out = np.zeros((ms.shape[0], k))
    for i in range(ms.shape[0]):
        m = ms[i]
        for t in range(n_phase - 2 * m):
            for c in range(k):
                d = theta[t + 2 * m, c] - 2.0 * theta[t + m, c] + theta[t, c]
                out[i, c] += d * d
    return out


def second_difference_sums(theta, ms) -> np.ndarray:
    """Sum over k of (theta[k+2m] - 2 theta[k+m] + theta[k])^2 for each m in ``ms``, per column of ``theta``
    (n_phase, ncols) [unit^2 s^2]: the numerator of eq. (2) of :mod:`calib.signal.allan` (its
    :func:`~calib.signal.allan.avar_sums`, compiled for the many columns of the bootstrap)."""
    return _second_difference_sums(np.ascontiguousarray(theta, dtype=np.float64), np.asarray(ms, dtype=np.int64))


@numba.njit(cache=True)
def _integrate(theta, zw, zk, a, b, dt):  # pragma: no cover - compiled
    n, k = zw.shape
    walk = np.zeros(k)
    for t in range(n):
        for c in range(k):
            walk[c] += b[c] * zk[t, c]
            theta[t + 1, c] = theta[t, c] + dt * (a[c] * zw[t, c] + walk[c])


def simulate_phase(values: dict, n: int, fs: float, reps: int, rng) -> np.ndarray:
    """Phase (integrated rate, theta_0 = 0) of ``reps`` independent records of ``n`` rate samples at ``fs`` Hz of
    the noise model ``values`` {term: (naxes,)} of eq. (1): shape (n + 1, reps x naxes), column r x naxes + a is
    replicate r of axis a. White rate noise of std N sqrt(fs) per sample; a random walk of K / sqrt(fs) per step;
    white phase noise of std Q on theta; flicker rate noise of two-sided PSD B^2 / (2 pi |f|) (IEEE 952's; one-sided
    B^2 / (pi f)) by spectral shaping (its Allan deviation is 0.664 B between a few samples and a tenth of the
    record). The standard normal draws are single precision (the sums are double)."""
    naxes = len(values["N"])
    cols = reps * naxes
    dt = 1.0 / fs
    coef = {t: np.tile(np.asarray(values[t], dtype=float), reps) for t in TERMS}
    theta = np.zeros((n + 1, cols))
    zw = rng.standard_normal((n, cols), dtype=np.float32)
    has_k = bool(np.any(coef["K"] > 0))
    zk = rng.standard_normal((n, cols), dtype=np.float32) if has_k else np.zeros((1, cols), np.float32)
    _integrate(theta, zw, zk if has_k else np.zeros_like(zw), coef["N"] * math.sqrt(fs),
               coef["K"] * math.sqrt(dt) if has_k else np.zeros(cols), dt)
    if np.any(coef["B"] > 0):
        # synthesised over FLICKER_SPAN record lengths and cut to one: a record of flicker noise also holds the
        # frequencies below 1 / T (a synthesis of one record length leaves them out, and its Allan deviation at
        # tau = T / 2 was 0.78 of the law, which biased every replicate's fit against the model it was drawn from)
        n_syn = FLICKER_SPAN * n
        f = np.fft.rfftfreq(n_syn, dt)
        amp = np.zeros_like(f)
        amp[1:] = np.sqrt(1.0 / (math.pi * f[1:]) * n_syn * fs / 4.0)   # one-sided PSD B^2 / (pi f)
        z = rng.standard_normal((len(f), cols)) + 1j * rng.standard_normal((len(f), cols))
        y = np.fft.irfft(z * amp[:, None], n_syn, axis=0)[:n] * coef["B"]
        theta[1:] += np.cumsum(y * dt, axis=0)
    if np.any(coef["Q"] > 0):
        theta += rng.standard_normal((n + 1, cols)) * coef["Q"]
    return theta


def _replicate_fits(values, res: allan.AllanResult, n_boot: int, seed: int, penalty: float, progress=None):
    """Term values of ``n_boot`` bootstrap replicates: (n_boot, 4, naxes)."""
    ms = np.rint(res.tau * res.fs).astype(np.int64)
    n = res.n_samples
    naxes = res.adev.shape[1]
    rng = np.random.default_rng(seed)
    span = FLICKER_SPAN if np.any(np.asarray(values)[TERMS.index("B")] > 0) else 1   # (the flicker synthesis' size)
    per = max(1, min(n_boot, BATCH_VALUES // ((n + 1) * naxes * span)))
    out = []
    done = 0
    vals = dict(zip(TERMS, values))
    while done < n_boot:
        reps = min(per, n_boot - done)
        theta = simulate_phase(vals, n, res.fs, reps, rng)
        sumsq = second_difference_sums(theta, ms)
        nterms = (n + 1) - 2 * ms
        av = sumsq / (2.0 * res.tau[:, None] ** 2 * nterms[:, None])
        ad = np.sqrt(np.maximum(av, 1e-300))
        r = allan.AllanResult(tau=res.tau, adev=ad, lo=ad, hi=ad, edf=res.edf, nterms=res.nterms, fs=res.fs,
                              confidence=res.confidence, unit=res.unit, n_records=1, n_samples=n)
        v, _ = select_fit(r, penalty)
        out.append(v.reshape(4, reps, naxes).transpose(1, 0, 2))
        done += reps
        if progress is not None:
            progress(done, n_boot)
    return np.concatenate(out, axis=0)


def band_upper_bounds(tau, hi) -> np.ndarray:
    """Largest coefficient of each term whose own ADEV line stays at or below the band's upper edge ``hi``
    (ntau, naxes) at every tau: (4, naxes) in :data:`TERMS` order (the bound of a term the record does not
    resolve)."""
    t = np.asarray(tau, dtype=float)[:, None]
    return np.array([np.min(hi * t / math.sqrt(3.0), axis=0), np.min(hi * np.sqrt(t), axis=0),
                     np.min(hi / FLOOR, axis=0), np.min(hi * np.sqrt(3.0 / t), axis=0)])


def log_basic_interval(value, reps, confidence: float, upper_cap):
    """Basic bootstrap interval on the log scale, [value^2 / q_hi, value^2 / q_lo], q the replicates' (axis 0)
    quantiles, and its point estimate, the bias-corrected value^2 / q_50 (the replicates' median): the interval
    corrects the fit's bias under the fitted model (term selection, a skewed random walk), so where that bias
    exceeds the replicates' spread the interval leaves the raw fit outside; the bias-corrected estimate lies
    inside it. Where ``value`` is 0 or the lower quantile is 0 (the term is not distinguished from zero): [0,
    max(``upper_cap``, 2 value)] -- the band's bound, or, when the fit itself reaches above it (a model that
    does not follow the measured deviation), the basic interval's upper end on the linear scale, 2 value - q_lo
    with q_lo = 0 -- and the estimate stays the raw fit. Returns (estimate, lo, hi, resolved)."""
    a = 1.0 - confidence
    q_lo, q_50, q_hi = np.quantile(reps, [a / 2.0, 0.5, 1.0 - a / 2.0], axis=0)
    value = np.asarray(value, dtype=float)
    ok = (value > 0) & (q_lo > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        lo = np.where(ok, value**2 / np.where(q_hi > 0, q_hi, 1.0), 0.0)
        hi = np.where(ok, value**2 / np.where(q_lo > 0, q_lo, 1.0), np.maximum(upper_cap, 2.0 * value))
        est = np.where(ok, value**2 / np.where(q_50 > 0, q_50, 1.0), value)
    return est, lo, hi, ok


# --------------------------------------------------------------------------- result


@dataclass
class NoiseTerms:
    """The terms of one triad (or any set of axes) of a static record.

    ``values``, ``lo``, ``hi``: {term: (naxes,)} the coefficient and its ``confidence`` interval (units in the
    module docstring): for a resolved term the bias-corrected estimate at the centre of its interval
    (:func:`log_basic_interval`), for an unresolved one the raw fit; ``fitted``: the raw fit of the record;
    ``model_outside`` (ntau, naxes): where the fitted model leaves the band of the measured deviation; ``resolved``: {term: (naxes,) bool} whether the record tells the term from zero (False:
    fitted 0, or the bootstrap's lower quantile is 0; the interval is then [0, upper bound]); ``combined``:
    {term: (value, lo, hi, resolved)} the root mean square over the axes; ``band_lo``/``band_hi`` (ntau, naxes):
    confidence band of the measured ADEV with the edf of the dominant noise type (``band_edf``, ``dominant`` its
    term); ``allan``: the :class:`~calib.signal.allan.AllanResult`."""

    allan: allan.AllanResult
    values: dict
    lo: dict
    hi: dict
    resolved: dict
    combined: dict
    band_lo: np.ndarray
    band_hi: np.ndarray
    band_edf: np.ndarray
    dominant: np.ndarray
    confidence: float
    n_boot: int
    seed: int
    penalty: float
    unit: str
    axes: tuple = ("x", "y", "z")
    replicates: np.ndarray | None = field(default=None, repr=False)
    fitted: dict | None = None
    model_outside: np.ndarray | None = None

    def model_adev(self, tau=None) -> np.ndarray:
        """ADEV (len(tau), naxes) of the fitted model (default: at the measured taus)."""
        tau = self.allan.tau if tau is None else tau
        return np.sqrt(sum(term_avar(self.fitted or self.values, tau).values()))

    def term_adev(self, term: str, tau=None) -> np.ndarray:
        tau = self.allan.tau if tau is None else tau
        return np.sqrt(term_avar(self.fitted or self.values, tau)[term])

    def model_misfit(self, p: float = MISFIT_P) -> bool:
        """Whether the fitted model leaves the band of the measured deviation at more (tau, axis) points than
        chance allows: the count outside has a binomial tail probability below ``p`` when each point lies outside
        its ``confidence`` band with probability 1 - ``confidence`` (a well fitted model of stationary noise)."""
        if self.model_outside is None:
            return False
        k, m = int(np.sum(self.model_outside)), self.model_outside.size
        return k > 0 and float(binom.sf(k - 1, m, 1.0 - self.confidence)) < p

    def tau_range(self) -> tuple:
        """The shortest and longest tau [s] of the measured Allan deviation (the longest is half the record)."""
        return float(self.allan.tau[0]), float(self.allan.tau[-1])

    def not_estimated(self) -> list:
        """The terms the record does not tell from zero on any axis (upper bounds only)."""
        return [t for t in TERMS if not np.any(self.resolved[t])]

    def short_record_notes(self) -> list:
        """What the record's length supports, in words: the tau range, the terms it cannot estimate (and why a
        longer record would), and where the fitted model leaves the band of the measured deviation."""
        r = self.allan
        t0, t1 = self.tau_range()
        dur = r.n_samples / r.fs
        out = [f"record of {dur:.4g} s: Allan deviation at tau = {t0:.3g} .. {t1:.4g} s (the longest tau is half the "
               f"record)"]
        names = {"Q": "quantization noise Q", "N": "white noise N", "B": "bias instability B",
                 "K": "rate random walk K"}
        why = {"Q": "it shows only at the shortest taus, below the white noise",
               "N": "the white noise does not stand out of the other terms",
               "B": f"its flat floor is not seen at tau <= {t1:.4g} s (a floor shows at taus of tens of seconds to "
                    "hours: record a longer static period)",
               "K": f"its +1/2 slope is not seen at tau <= {t1:.4g} s (a random walk shows beyond the white noise, "
                    "typically at taus of minutes to hours: record a longer static period)"}
        for t in self.not_estimated():
            out.append(f"{names[t]} not estimated: the record does not tell it from zero ({why[t]}); only its upper "
                       f"bound is given (RMS of axes < {self.combined[t][2]:.4g} {term_unit(t, self.unit)})")
        if self.model_misfit():
            bad = np.flatnonzero(np.any(self.model_outside, axis=1))
            out.append(f"the fitted model leaves the {100 * self.confidence:g} % band of the measured deviation at "
                       f"{len(bad)} of {len(r.tau)} taus ({', '.join(f'{x:.3g}' for x in r.tau[bad][:6])} s): the "
                       "terms assume stationary noise; a step, a dropout or motion in the record breaks that, and "
                       "the terms and intervals are then not to be trusted")
        return out

    def to_dict(self) -> dict:
        """JSON-ready: per term and axis the value and interval, the combined values, the measured ADEV."""
        r = self.allan
        return {
            "unit": self.unit, "sample_rate_hz": float(r.fs), "n_samples": int(r.n_samples),
            "duration_s": r.n_samples / r.fs, "confidence": self.confidence,
            "interval_method": f"parametric bootstrap ({self.n_boot} replicates, seed {self.seed}), basic interval "
                               "on the log scale; unresolved terms: [0, upper bound from the ADEV band]",
            "term_selection": f"N and K always; Q and B where misfit + {self.penalty:g} x terms is lower",
            "value": "resolved terms: bias-corrected estimate fit^2 / median of the replicates (inside its interval); "
                     "unresolved terms: the fit ('fit' is the raw fit of the record throughout)",
            "tau_range_s": list(self.tau_range()), "not_estimated": self.not_estimated(),
            "notes": self.short_record_notes(),
            "terms": {t: {"definition": DEFINITIONS[t], "unit": term_unit(t, self.unit),
                          "axes": {ax: {"value": float(self.values[t][i]), "lo": float(self.lo[t][i]),
                                        "hi": float(self.hi[t][i]), "resolved": bool(self.resolved[t][i]),
                                        "fit": float((self.fitted or self.values)[t][i])}
                                   for i, ax in enumerate(self.axes)},
                          "combined_rms": dict(zip(("value", "lo", "hi", "resolved"),
                                                   (*map(float, self.combined[t][:3]), bool(self.combined[t][3]))))}
                      for t in TERMS},
            "allan": {"tau_s": r.tau.tolist(), "adev": r.adev.T.tolist(), "band_lo": self.band_lo.T.tolist(),
                      "band_hi": self.band_hi.T.tolist(), "edf": self.band_edf.T.tolist(),
                      "dominant_term": [[str(d) for d in row] for row in self.dominant.T],
                      "model_adev": self.model_adev().T.tolist()},
        }


def term_unit(term: str, unit: str) -> str:
    """Unit of a coefficient for a rate unit ``unit`` (u s, u s^1/2, u, u s^-1/2)."""
    return {"Q": f"{unit} s", "N": f"{unit} s^1/2", "B": unit, "K": f"{unit} s^-1/2"}[term]


def noise_terms(y, fs: float, *, confidence: float = 0.95, n_boot: int = N_BOOT, seed: int = 0,
                penalty: float = PENALTY, unit: str = "", axes=("x", "y", "z"), progress=None,
                keep_replicates: bool = False) -> NoiseTerms:
    """IEEE-952 terms with intervals of rate samples ``y`` (n, naxes) at ``fs`` Hz (module docstring).

    ``progress(done, total)``: called after each batch of bootstrap replicates. Deterministic for a given
    ``seed``. Raises :class:`NoiseTermsError` for records too short (fewer than 64 samples) or flat."""
    y = np.asarray(y, dtype=np.float64)
    if y.ndim == 1:
        y = y[:, None]
    if len(y) < 64:
        raise NoiseTermsError(f"{len(y)} samples: the noise terms need a long static record (at least 64 samples; "
                              "an hour or more to see the random walk)")
    if n_boot < 20:
        raise NoiseTermsError(f"n_boot = {n_boot}: at least 20 bootstrap replicates are needed for an interval")
    try:
        res = allan.adev(y, fs, confidence=confidence, unit=unit)
    except allan.AllanError as exc:
        raise NoiseTermsError(str(exc), FLAT_FIX if "constant" in str(exc) else "record a longer static period") \
            from None
    if len(res.tau) < 4:
        raise NoiseTermsError(f"only {len(res.tau)} Allan points: record a longer static period")
    values, _ = select_fit(res, penalty)
    reps = _replicate_fits(values, res, n_boot, seed, penalty, progress)
    # the band: chi-square with the edf of the noise type the fitted model says dominates at each tau
    parts = term_avar(dict(zip(TERMS, values)), res.tau)
    dom_idx = np.argmax(np.stack([parts[t] for t in TERMS]), axis=0)  # (ntau, naxes)
    dominant = np.asarray(TERMS)[dom_idx]
    ms = np.rint(res.tau * fs).astype(np.int64)
    n_phase = res.n_samples + 1
    edf = np.empty_like(res.adev)
    for j, t in enumerate(TERMS):
        e = edf_simple(n_phase, ms, ALPHA[t])
        edf = np.where(dom_idx == j, e[:, None], edf)
    band_lo, band_hi = chi2_band(res.adev, edf, confidence)
    caps = band_upper_bounds(res.tau, band_hi)
    out = {"values": {}, "lo": {}, "hi": {}, "resolved": {}, "combined": {}, "fitted": {}}
    for i, t in enumerate(TERMS):
        est, lo, hi, ok = log_basic_interval(values[i], reps[:, i, :], confidence, caps[i])
        out["values"][t], out["lo"][t], out["hi"][t], out["resolved"][t] = est, lo, hi, ok
        out["fitted"][t] = values[i]
        comb = np.sqrt(np.mean(values[i] ** 2))
        comb_reps = np.sqrt(np.mean(reps[:, i, :] ** 2, axis=1))
        cest, clo, chi, cok = log_basic_interval(comb, comb_reps, confidence, float(np.sqrt(np.mean(caps[i] ** 2))))
        out["combined"][t] = (float(cest), float(clo), float(chi), bool(cok))
    # where the fitted model leaves the band of the measured deviation: the terms assume stationary noise
    model = np.sqrt(sum(term_avar(dict(zip(TERMS, values)), res.tau).values()))
    outside = (model > band_hi * (1.0 + 1e-9)) | (model < band_lo * (1.0 - 1e-9))
    return NoiseTerms(allan=res, band_lo=band_lo, band_hi=band_hi, band_edf=edf, dominant=dominant,
                      model_outside=outside,
                      confidence=confidence, n_boot=n_boot, seed=seed, penalty=penalty, unit=unit, axes=tuple(axes),
                      replicates=reps if keep_replicates else None, **out)


# --------------------------------------------------------------------------- Kalibr


def kalibr_parameters(gyro: NoiseTerms, accel: NoiseTerms) -> dict:
    """Kalibr's IMU noise parameters (continuous time) from the terms of SI records (gyro rad s-1, accel m s-2):
    ``*_noise_density`` = N [rad s-1 / sqrt(Hz), m s-2 / sqrt(Hz)], ``*_random_walk`` = K [rad s-2 / sqrt(Hz),
    m s-3 / sqrt(Hz)], the root mean square over the three axes. A random walk the record does not resolve gives
    its upper bound (flagged). Returns {key: {value, lo, hi, unit, resolved}}."""
    out = {}
    for sensor, terms, (un, uk) in (("accelerometer", accel, ("m/s^2/sqrt(Hz)", "m/s^3/sqrt(Hz)")),
                                    ("gyroscope", gyro, ("rad/s/sqrt(Hz)", "rad/s^2/sqrt(Hz)"))):
        for key, t, u in (("noise_density", "N", un), ("random_walk", "K", uk)):
            v, lo, hi, resolved = terms.combined[t]
            out[f"{sensor}_{key}"] = {"value": v if resolved else hi, "lo": lo, "hi": hi, "unit": u,
                                      "resolved": resolved}
    return out


# --------------------------------------------------------------------------- report and figure data


def _fmt(v) -> str:
    return f"{v:.4g}"


def customary(term: str, sensor: str, value: float):
    """The value in the unit data sheets use (gyro: deg h^-1/2, deg h-1, deg h^-3/2, arcsec; accel: ug/sqrt(Hz),
    ug, ug sqrt(Hz)/s, mm s-1) as (number, unit), or None; ``value`` in SI (rad s-1 / m s-2 based)."""
    if sensor == "gyro":
        d = 180.0 / math.pi
        return {"N": (value * d * 60.0, "deg h^-1/2"), "B": (value * d * 3600.0, "deg h-1"),
                "K": (value * d * 3600.0 * 60.0, "deg h^-3/2"), "Q": (value * d * 3600.0, "arcsec")}[term]
    if sensor == "accel":
        ug = 1e6 / 9.80665
        return {"N": (value * ug, "ug / sqrt(Hz)"), "B": (value * ug, "ug"), "K": (value * ug, "ug sqrt(Hz) / s"),
                "Q": (value * 1e3, "mm s-1")}[term]
    return None


def report_markdown(results: dict, source: str, kalibr: dict | None = None, notes=()) -> str:
    """Markdown report of {sensor: NoiseTerms} (sensor 'gyro' / 'accel')."""
    lines = [f"# IEEE Std 952-1997 noise terms of {source}", ""]
    any_r = next(iter(results.values()))
    r = any_r.allan
    lines += [f"Static record: {r.n_samples} samples at {r.fs:.9g} Hz ({r.n_samples / r.fs / 3600.0:.3f} h); "
              f"overlapping Allan deviation at {len(r.tau)} octave-spaced taus {r.tau[0]:.3g}..{r.tau[-1]:.4g} s; "
              f"{100 * any_r.confidence:g} % intervals by parametric bootstrap ({any_r.n_boot} replicates, seed "
              f"{any_r.seed}; basic interval on the log scale; a resolved term's value is the bias-corrected estimate "
              "at its centre). Model (per axis):", "",
              "    AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3", "", "Terms:", ""]
    lines += [f"* **{t}**: {DEFINITIONS[t]}" for t in TERMS]
    lines += ["", "N and K are always fitted; Q and B only where they clearly improve the fit. A term marked "
              "'< value' was not resolved by the record (fitted 0, or not told from 0 by the bootstrap): the value is "
              "the upper bound its ADEV line allows under the upper edge of the confidence band.", ""]
    for sensor, nt in results.items():
        lines += [f"## {sensor} [{nt.unit}]", "", "| term | unit | " + " | ".join(nt.axes) + " | RMS of axes | "
                  "customary unit (RMS) |", "|---|---|" + "---|" * (len(nt.axes) + 2)]
        for t in TERMS:
            cells = []
            for i in range(len(nt.axes)):
                if nt.resolved[t][i]:
                    cells.append(f"{_fmt(nt.values[t][i])} [{_fmt(nt.lo[t][i])}, {_fmt(nt.hi[t][i])}]")
                else:
                    cells.append(f"< {_fmt(nt.hi[t][i])}")
            v, lo, hi, ok = nt.combined[t]
            comb = f"{_fmt(v)} [{_fmt(lo)}, {_fmt(hi)}]" if ok else f"< {_fmt(hi)}"
            si = {"gyro": "rad s-1", "accel": "m s-2"}.get(sensor) == nt.unit
            cu = customary(t, sensor, v if ok else hi) if si else None
            cus = f"{'' if ok else '< '}{_fmt(cu[0])} {cu[1]}" if cu else ""
            lines.append(f"| {t} | {term_unit(t, nt.unit)} | " + " | ".join(cells) + f" | {comb} | {cus} |")
        lines.append("")
    if kalibr:
        lines += ["## Kalibr (imu.yaml, continuous time)", "", "| key | value | interval | unit |", "|---|---|---|---|"]
        for k, v in kalibr.items():
            val = _fmt(v["value"]) + ("" if v["resolved"] else " (upper bound: not resolved)")
            lines.append(f"| {k} | {val} | [{_fmt(v['lo'])}, {_fmt(v['hi'])}] | {v['unit']} |")
        lines += ["", "noise density = N, random walk = K (RMS over the axes). Kalibr users usually inflate these "
                  "static-record values (often x2-x10) for the motion, vibration and temperature of a real "
                  "calibration session.", ""]
    for n in notes:
        lines.append(f"* note: {n}")
    return "\n".join(lines).rstrip() + "\n"


def figure_data(results: dict) -> list:
    """What :func:`calib.figures.allan_plots.noise_terms` draws, as plain data: one dict per sensor of ``results``
    {sensor: NoiseTerms}, with the measured ADEV (``tau``, ``adev``) and its confidence band (``band_lo``,
    ``band_hi``), the fitted model (``model``) and each term's line (``terms[t]["adev"]``, drawn where
    ``terms[t]["drawn"]``: the fit holds the term on that axis) on 200 log-spaced taus (``tau_model``), and each
    term's value, interval and whether the record resolves it."""
    out = []
    for sensor, nt in results.items():
        r = nt.allan
        tt = np.geomspace(r.tau[0], r.tau[-1], 200)
        fit = nt.fitted or nt.values
        out.append({"sensor": sensor, "axes": tuple(nt.axes), "unit": nt.unit, "confidence": nt.confidence,
                    "tau": r.tau, "adev": r.adev, "band_lo": nt.band_lo, "band_hi": nt.band_hi, "tau_model": tt,
                    "model": nt.model_adev(tt),
                    "terms": {t: {"adev": nt.term_adev(t, tt), "drawn": np.asarray(fit[t]) > 0, "value": nt.values[t],
                                  "lo": nt.lo[t], "hi": nt.hi[t], "resolved": nt.resolved[t]} for t in TERMS}})
    return out
