"""The static-interval detection of a field calibration whose settings give none, chosen as a careful user would.

A careful user does not trust one threshold: they try IMU-TK's search over the threshold multiplier ``k``
(Tedaldi, Pretto & Menegatti, ICRA 2014: thresholds ``k`` x the variance of the initial rest, the first
``samples_per_interval`` samples of each interval), and the variance rule of
:func:`calib.signal.detect.detect_static` (accel and gyro) over a few windows, multipliers and minimum interval
lengths; they fit each, set aside what is implausible, and keep the detection whose calibration fits best. Here:

* **candidates** (:func:`candidates`): rule ``imu_tk`` with ``k`` in IMU-TK's 2..10 and 20, 50, 100, its window of
  101 samples (1.01 s at other rates) and 100 samples per interval, the initial rest its own 5000 samples or the
  protocol's / the one found on the signal; rule ``detect`` with windows :data:`WINDOWS_S`, multipliers
  :data:`DETECT_K` and minimum intervals :data:`MIN_INTERVALS_S` (plus half the protocol's shortest wait), the
  initial rest the protocol's or the one found on the signal (its noise floor when none is long enough). Candidates
  giving the same intervals are fitted once.
* **fit** (:func:`quick_fit`): IMU-TK's 9-parameter norm model (|a| = g) fitted to each candidate's interval means
  weighted by their sample counts (cheap, and not pulled by the noise on the norm as a per-sample fit is), its
  **residual** the per-sample norm residual RMS over the samples the candidate uses (what IMU-TK, imucal and
  mikoff/imu-calib report). Consecutive intervals whose calibrated gravity directions differ by less than
  :data:`SAME_POSE_DEG` are one pose.
* **eligible** (:func:`rank`): at least ``min_intervals`` (9) distinct poses; the fit passes the result checks of
  :func:`calib.signal.plausibility.check_fieldcal_result` (and, for an accelerometer in counts with a declared
  ``approx_counts_per_g``, the same scale and bias limits relative to that nominal); the residual at most
  :data:`CONTAMINATION` above the smallest eligible one (intervals that hold motion raise it).
* **odd** candidates: one of their intervals has a mean that misses gravity by far more than the other means and
  its own noise explain (:func:`odd_intervals`), or is held by fewer than :data:`MIN_SUPPORT` of the eligible
  candidates (:func:`unsupported_intervals`) -- a piece of a turn that only permissive detections keep.
* **validated residual** (:func:`validate`): every eligible calibration's norm residual RMS over the same samples,
  those that at least :data:`VALIDATION_VOTE` of the candidates that are not odd and find the most poses fit (the
  static samples they agree on). Judged on the same samples, a calibration cannot look better for fitting fewer
  samples or for leaving out the ends of the intervals, where motion begins.
* **order**: first the candidates (not odd) with at least ``recommended_intervals`` (12; or the protocol's poses
  plus its initial rest, when fewer) distinct poses, then the others by their distinct poses, most first (the
  choice then says how little redundancy is left), the odd ones last. Within each group, validated residuals tied
  with the smallest (within :data:`TIE_TOLERANCE` plus the 9 parameters' over-fit of the smallest one's own N
  samples, 9 / (2 N)) are equally good calibrations: among them the most poses, then whole intervals rather than
  their first samples, then the smallest own residual (the cleanest intervals) comes first; the others follow by
  validated residual.
* the session then runs the full calibration (units check by rotation, the per-sample accel fit started from the
  ranking's, the gyro fit) on the first candidate and checks the result; one that fails (the units check refuses,
  or the result checks) gives way to the next, up to :data:`FULL_ATTEMPTS`
  (:func:`calib.fieldcal.session.fieldcal_recording`), and so does one whose accel fit leaves parameters not
  determined (a pose set on the edge of determining the model) when a later one determines them all. When none
  passes, the first result that the result checks refuse is returned marked as failed
  (``detection_choice['status']``) so that ``calib fieldcal`` writes it for inspection and exits 3 naming the
  settings keys; with nothing to return, a :class:`calib.core.errors.ResultCheckError` (exit 3) names them
  (:func:`no_choice_error`).

The protocol's timing (:class:`Protocol`) comes from the settings' ``protocol:`` section or the recording's
attributes ``protocol_initial_rest_s``, ``protocol_min_wait_s``, ``protocol_n_poses``: the initial rest fixes the
thresholds' reference span, half the shortest wait is one more minimum interval length, and the number of poses
(plus the initial rest) how many distinct poses make a complete detection.

The constants :data:`CONTAMINATION`, :data:`ODD_MEAN_K`, :data:`MIN_SUPPORT`, :data:`VALIDATION_VOTE`,
:data:`TIE_TOLERANCE` and :data:`RANK_MAX_NFEV` were tuned on the static-pose protocols of
``tests/fieldcal/conftest.py::protocol_session`` with seeds 0-199 (and two sessions of 10030-10229, see
``tests/fieldcal/test_default_detection.py``); the acceptance test and its benchmark
(``benchmarks/bench_default_detection.py``) use seeds 10000-10229.
"""
from __future__ import annotations

import contextlib
import logging
import math
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
from scipy.optimize import least_squares

from calib.core import earth
from calib.core.errors import ResultCheckError
from calib.core.triad import NORM_PARAMETERS
from calib.signal import detect, plausibility
from calib.fieldcal.accelerometer import NOMINAL, accel_apply, accel_jacobian, ellipsoid_guess, range_guess
from calib.fieldcal.intervals import imu_tk_intervals
from calib.fieldcal.results import IMU_TK_DEFAULTS, MIN_INTERVALS, PROTOCOL_KEYS, FieldCalError, log

#: windows of the variance rule [s]
WINDOWS_S = (1.0, 0.5, 0.25)
#: threshold multipliers of the variance rule (x the initial rest's variance magnitude)
DETECT_K = (3.0, 10.0, 30.0, 100.0, 300.0)
#: shortest static intervals kept by the variance rule [s]
MIN_INTERVALS_S = (0.5, 1.0, 2.0)
#: IMU-TK's search over k, extended for hand-held poses noisier than a rest on a table
IMU_TK_K = tuple(IMU_TK_DEFAULTS["k"]) + (20, 50, 100)
#: validated residuals (:func:`validate`) within this relative margin of the smallest are equally good calibrations
#: (they differ by less than the parameters' own noise moves them); among those the smallest own residual wins
TIE_TOLERANCE = 0.001
#: a candidate whose residual exceeds the smallest eligible one by more than this (relative) holds motion in its
#: intervals and is not eligible
CONTAMINATION = 0.2
#: the validation samples (:func:`validation_mask`) are those at least this fraction of the eligible candidates fit
VALIDATION_VOTE = 0.9
#: an interval whose calibrated mean misses gravity by more than this many times what the other means and its own
#: samples explain is odd (:func:`odd_intervals`): its candidate comes after those without one
ODD_MEAN_K = 6.0
#: an interval that fewer than this fraction of the eligible candidates hold (on average over its samples) is odd
#: too (:func:`unsupported_intervals`)
MIN_SUPPORT = 0.25
#: consecutive intervals whose calibrated gravity directions differ by less than this are one pose [deg]
SAME_POSE_DEG = 5.0
#: how many candidates get the full calibration before the choice gives up
FULL_ATTEMPTS = 3
#: residual evaluations of each ranking fit (:func:`quick_fit`; from the ellipsoid start it converges in far fewer)
RANK_MAX_NFEV = 200


@dataclass
class Protocol:
    """What is known of the session's timing: initial rest [s], shortest wait at a pose [s], number of poses
    after the rest; ``source`` says where each came from."""

    initial_rest_s: float | None = None
    min_wait_s: float | None = None
    n_poses: int | None = None
    source: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in PROTOCOL_KEYS if getattr(self, k) is not None}

    def describe(self) -> str:
        parts = [f"{k} = {v:g} ({self.source[k]})" for k, v in self.as_dict().items()]
        return "protocol " + ", ".join(parts) if parts else "no protocol timing known"


def protocol_section(settings: dict, src: str = "input") -> dict:
    """The settings' ``protocol:`` section, checked: a mapping of :data:`PROTOCOL_KEYS` (:class:`FieldCalError`
    naming the key otherwise)."""
    sec = settings.get("protocol") or {}
    if not isinstance(sec, dict):
        raise FieldCalError(f"{src}: settings 'protocol' must be a mapping of {', '.join(PROTOCOL_KEYS)}")
    for key in sec:
        if key not in PROTOCOL_KEYS:
            raise FieldCalError(f"{src}: settings 'protocol.{key}' unknown -- fix: one of {', '.join(PROTOCOL_KEYS)}")
    return sec


def protocol_of(ds, settings: dict, src: str = "input") -> Protocol:
    """The protocol timing from the settings' ``protocol:`` section, else the recording's ``protocol_<key>``
    attributes. Non-positive or non-numeric values are an error (:class:`FieldCalError`)."""
    sec = protocol_section(settings, src)
    out = Protocol()
    for key in PROTOCOL_KEYS:
        if key in sec:
            value, where = sec[key], f"settings protocol.{key}"
        elif f"protocol_{key}" in ds.attrs:
            value, where = ds.attrs[f"protocol_{key}"], f"recording attribute protocol_{key}"
        else:
            continue
        try:
            value = float(value)
        except (TypeError, ValueError):
            value = float("nan")
        if not (math.isfinite(value) and value > 0):
            raise FieldCalError(f"{src}: {where} = {value!r} -- fix: a positive number")
        setattr(out, key, int(round(value)) if key == "n_poses" else value)
        out.source[key] = where
    return out


@dataclass
class Candidate:
    """One detection tried: its rule, the ``detection:`` settings that reproduce it, its intervals, the samples per
    interval its fit uses (None: all), and what the ranking found (``residual``: norm RMS [m s-2] of its
    :func:`quick_fit`; ``validated``: the same over the common validation samples; ``problems``: why it is not
    eligible; ``implausible``: the result checks its accel fit fails; ``odd``: its odd intervals; ``values``: the
    fitted parameters, ``start`` the same when they may start the full fit)."""

    rule: str
    detection: dict
    intervals: np.ndarray
    samples_per_interval: int | None
    same_as: list = field(default_factory=list)
    n_poses: int = 0
    n_samples: int = 0
    residual: float | None = None
    problems: list = field(default_factory=list)
    implausible: list = field(default_factory=list)
    odd: list = field(default_factory=list)
    validated: float | None = None
    values: np.ndarray | None = field(default=None, repr=False)
    start: np.ndarray | None = field(default=None, repr=False)

    @property
    def fitted(self) -> bool:
        return self.residual is not None

    @property
    def eligible(self) -> bool:
        return self.residual is not None and not self.problems and not self.implausible

    def label(self) -> str:
        d = self.detection
        if self.rule == "imu_tk":
            return f"imu_tk k={d['k']:g} init_samples={d['init_samples']}"
        init = f"init_s={d['init_s']:g}" if "init_s" in d else ("threshold given" if "threshold" in d else "init auto")
        return (f"detect window_s={d['window_s']:g} k={d['k']:g} min_interval_s={d['min_interval_s']:g} {init}")

    def as_dict(self) -> dict:
        return {"rule": self.rule, "detection": dict(self.detection), "n_intervals": int(len(self.intervals)),
                "n_poses": int(self.n_poses), "n_samples": int(self.n_samples),
                "residual_m_s2": self.residual, "validated_residual_m_s2": self.validated,
                "eligible": self.eligible,
                "odd_intervals": [[int(a), int(b)] for a, b in self.odd],
                "problems": list(self.problems) + list(self.implausible),
                "same_intervals_as": [dict(s) for s in self.same_as]}


def _imu_tk_window(fs: float) -> tuple[int, int]:
    """IMU-TK's window (101 samples) and samples per interval (100) at 100 Hz, the same durations elsewhere."""
    if abs(fs - 100.0) < 1.0:
        return 101, 100
    return detect.window_samples(1.01, fs), max(int(round(fs)), 3)


def candidates(acc, gyr, fs: float, protocol: Protocol, samples_per_interval=None) -> list[Candidate]:
    """The candidate detections (module docstring), those giving identical intervals merged into the first."""
    acc = np.asarray(acc, dtype=np.float64)
    n = len(acc)
    out: dict[bytes, Candidate] = {}

    def add(rule, det, iv, n_per):
        iv = np.asarray(iv, dtype=np.int64).reshape(-1, 2)
        if n_per is not None:
            iv = iv[(iv[:, 1] - iv[:, 0]) >= n_per]
        key = rule.encode() + bytes(str(n_per), "ascii") + iv.tobytes()
        if key in out:
            out[key].same_as.append(det)
        else:
            out[key] = Candidate(rule, det, iv, n_per)

    # IMU-TK: accel only, its window, the first samples of each interval
    win, n_per_tk = _imu_tk_window(fs)
    inits = {int(IMU_TK_DEFAULTS["init_samples"])}
    s_tk = detect.moving_variance_norm(acc, win) if n > win else None
    if protocol.initial_rest_s is not None:
        inits.add(int(round(protocol.initial_rest_s * fs)) - 1)
    elif s_tk is not None:
        n0, _ = detect.find_initial_rest(s_tk, win)
        inits.add(n0 - 1)
    for init in sorted(i for i in inits if win <= i < n):
        for k in IMU_TK_K:
            det = {"rule": "imu_tk", "k": float(k), "init_samples": int(init), "window": int(win),
                   "samples_per_interval": int(n_per_tk)}
            add("imu_tk", det, imu_tk_intervals(acc, fs, k, init_samples=init, window=win,
                                                samples_per_interval=n_per_tk, stat=s_tk), n_per_tk)
    # the variance rule on accel and gyro
    mins = set(MIN_INTERVALS_S)
    if protocol.min_wait_s is not None:
        mins.add(round(0.5 * protocol.min_wait_s, 3))
    for window_s in WINDOWS_S:
        w = detect.window_samples(window_s, fs)
        if n < 2 * w:
            continue
        sa = detect.moving_variance_norm(acc, w)
        sg = None if gyr is None else detect.moving_variance_norm(gyr, w)   # (None: an accelerometer-only record)
        base = {}
        if protocol.initial_rest_s is not None and protocol.initial_rest_s * fs >= w:
            base = {"init_s": float(protocol.initial_rest_s)}
        else:
            n0, _ = detect.find_initial_rest(sa, w)
            if n0 < w:   # no rest long enough for this window: thresholds on the noise floor
                base = {"floor": (float(np.percentile(sa, 10.0)),
                                  float(np.percentile(sg, 10.0)) if sg is not None else None)}
        for k in DETECT_K:
            for m in sorted(mins):
                if m < window_s / 2:
                    continue
                det = {"rule": "detect", "window_s": float(window_s), "k": float(k), "min_interval_s": float(m)}
                if "floor" in base:
                    fa, fg = base["floor"]
                    if not (fa > 0 and (fg is None or fg > 0)):
                        continue
                    det.update(threshold=k * fa)
                    if fg is not None:
                        det.update(gyro_threshold=k * fg)
                else:   # the initial rest's length (none: the rest detect_static finds)
                    det.update(base)
                if gyr is None:
                    det.update(use_gyro=False)
                try:
                    d = detect.detect_static(acc, gyr, fs, **{kk: v for kk, v in det.items() if kk != "rule"},
                                             stat_accel=sa, stat_gyro=sg)
                except detect.StaticDetectionError:
                    continue
                add("detect", det, d.intervals, samples_per_interval)
    return list(out.values())


def distinct_poses(cal_means, same_deg: float = SAME_POSE_DEG) -> int:
    """Number of poses among intervals whose calibrated mean specific forces are ``cal_means``: a new pose starts
    where the gravity direction moved by ``same_deg`` or more since the previous interval."""
    u = np.asarray(cal_means, dtype=float)
    if len(u) == 0:
        return 0
    u = u / np.linalg.norm(u, axis=1)[:, None]
    ang = np.degrees(np.arccos(np.clip(np.sum(u[1:] * u[:-1], axis=1), -1.0, 1.0)))
    return 1 + int(np.sum(ang >= same_deg))


class _Hold(logging.Filter):
    """Keeps the records of the ``calib.fieldcal`` logger instead of letting them through (below ERROR)."""

    def __init__(self):
        super().__init__()
        self.records = []

    def filter(self, record):
        if record.levelno >= logging.ERROR:
            return True
        self.records.append(record)
        return False


@contextlib.contextmanager
def held_messages():
    """The messages of the fits inside the block are kept, not shown (they are about candidates, not the result);
    yields the list they are kept in. :func:`replay` shows those of the candidate chosen."""
    f = _Hold()
    log.addFilter(f)
    try:
        yield f.records
    finally:
        log.removeFilter(f)


def replay(records) -> None:
    """Show the messages kept by :func:`held_messages` (the chosen candidate's)."""
    for r in records:
        log.handle(r)


def nominal_problems(fit, counts_per_g: float | None, zero_count: float | None) -> list[str]:
    """For an accelerometer in counts with a declared ``approx_counts_per_g`` (and ``approx_zero_count``): the
    result checks of physical units on the scale factors relative to that nominal and on the bias."""
    if counts_per_g is None:
        return []
    nominal = counts_per_g / earth.STANDARD_GRAVITY  # counts per m s-2
    bias = None if zero_count is None else (np.asarray(fit.bias) - zero_count) / nominal
    probs = plausibility.check_triad_result("accel", np.asarray(fit.scale_factors) / nominal, bias, counts=False)
    return [f"{p} (relative to the declared approx_counts_per_g {counts_per_g:g})" for p in probs]


@dataclass
class Ranking:
    """What :func:`rank` found: ``order`` the eligible candidates best first, ``fallback`` the candidates with enough
    poses whose accel fit fails the result checks (by residual: the best one is calibrated for inspection when no
    eligible one is left), ``need`` the distinct poses of a complete detection, ``most_poses`` the most any eligible
    candidate has, ``best_residual`` the smallest eligible residual."""

    order: list
    fallback: list
    need: int
    min_poses: int
    most_poses: int = 0
    best_residual: float | None = None
    n_validation: int = 0

    @property
    def complete(self) -> bool:
        """Whether the first candidate has the distinct poses of a complete detection."""
        return bool(self.order) and self.order[0].n_poses >= self.need


def _banded(group) -> list:
    """``group`` ordered: those whose validated residual is within the tie band of its smallest (equally good
    calibrations: :data:`TIE_TOLERANCE` plus what fitting its own samples gains the smallest one, ``p / (2 N)`` for
    the 9 parameters over its N samples) by their distinct poses (most first: the full fit is the better
    determined), those fitting whole intervals before those fitting their first samples (more samples: the full
    per-sample fit is the steadier), then their own residual (the cleanest intervals first); then the others by
    validated residual."""
    if not group:
        return []
    top = min(group, key=lambda c: c.validated)
    band = top.validated * (1 + TIE_TOLERANCE + NORM_PARAMETERS / (2.0 * max(top.n_samples, 1)))
    tied = [c for c in group if c.validated <= band]
    rest = [c for c in group if c.validated > band]
    return (sorted(tied, key=lambda c: (-c.n_poses, c.samples_per_interval is not None, c.residual))
            + sorted(rest, key=lambda c: c.validated))


def _fit_spans(c) -> np.ndarray:
    """The sample ranges a candidate's fit uses: its intervals, or their first ``samples_per_interval`` samples."""
    iv = np.asarray(c.intervals, dtype=np.int64).reshape(-1, 2)
    if c.samples_per_interval is None:
        return iv
    return np.column_stack([iv[:, 0], iv[:, 0] + int(c.samples_per_interval)])


def validation_mask(group, n: int) -> np.ndarray:
    """The samples that at least :data:`VALIDATION_VOTE` of the candidates ``group`` fitting whole intervals (all of
    them when none does) fit: the static samples they agree on, without the ends of intervals that only the more
    permissive detections keep. :func:`rank` gives the candidates that find the most distinct poses, so that every
    pose is in it."""
    voters = [c for c in group if c.samples_per_interval is None] or list(group)
    votes = np.zeros(n + 1, dtype=np.int64)
    for c in voters:
        sp = _fit_spans(c)
        np.add.at(votes, sp[:, 0], 1)
        np.add.at(votes, sp[:, 1], -1)
    return np.cumsum(votes)[:n] >= VALIDATION_VOTE * max(len(voters), 1) - 1e-9


def validate(voters, cands, acc, gravity: float) -> int:
    """Each candidate's ``validated`` residual: the per-sample norm residual RMS of its ranking fit over the common
    :func:`validation_mask` of ``voters`` (every calibration judged on the same samples, so that neither fitting
    fewer samples nor leaving out the ends of the intervals makes a residual look smaller). Returns the number of
    validation samples."""
    mask = validation_mask(voters, len(acc))
    x = acc[mask]
    for c in cands:
        with np.errstate(all="ignore"):
            r = np.linalg.norm(accel_apply(c.values, x), axis=1) - gravity
            v = float(np.sqrt(np.mean(r * r))) if len(r) else float("nan")
        c.validated = v if math.isfinite(v) else c.residual
    return int(mask.sum())


def _prefix_sums(acc) -> np.ndarray:
    """Cumulative sums of the samples (their overall mean removed, for counts near 32768), a leading zero row."""
    x = acc - acc.mean(axis=0) if len(acc) else acc
    out = np.zeros((len(acc) + 1, 3))
    np.cumsum(x, axis=0, out=out[1:])
    return out


def quick_fit(acc, csum, intervals, n_per, gravity: float, *, counts: bool):
    """The 9-parameter norm model fitted to the interval means weighted by their sample counts (Levenberg-Marquardt
    from the ellipsoid start, at most :data:`RANK_MAX_NFEV` evaluations), and its per-sample norm residual RMS over
    the samples the candidate uses (all, or the first ``n_per`` of each interval): the ranking's fit. Cheap (the
    means come from the prefix sums ``csum``) and, unlike the per-sample fit, not pulled by the noise on the norm
    (whose spread shrinks with the gains); the chosen candidate then gets the full fit. None when it fails."""
    iv = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    stop = iv[:, 1] if n_per is None else iv[:, 0] + int(n_per)
    lens = (stop - iv[:, 0]).astype(float)
    mu0 = acc.mean(axis=0) if len(acc) else np.zeros(3)
    means = (csum[stop] - csum[iv[:, 0]]) / lens[:, None] + mu0
    w = np.sqrt(lens)
    x0 = ellipsoid_guess(means, gravity)
    spans = x0 is not None   # the means span every direction (else the full fit holds what they cannot see first)
    if x0 is None:
        x0 = range_guess(means, gravity) if counts else np.array(NOMINAL)

    def fun(p):
        return w * (np.linalg.norm(accel_apply(p, means), axis=1) - gravity)

    def jac(p):
        return accel_jacobian(p, means, gravity) * w[:, None]

    try:
        with np.errstate(all="ignore"):
            sol = least_squares(fun, x0, jac=jac, method="lm", x_scale="jac", max_nfev=RANK_MAX_NFEV)
    except (ValueError, np.linalg.LinAlgError):
        return None
    p = sol.x.copy()
    flip = np.where(p[3:6] < 0, -1.0, 1.0)   # the norm does not see an axis' sign: gains positive
    p[3:6] *= flip
    p[0] *= flip[0] * flip[1]
    p[1] *= flip[0] * flip[2]
    p[2] *= flip[1] * flip[2]
    samples = np.concatenate([acc[a:b] for a, b in zip(iv[:, 0], stop)])
    with np.errstate(all="ignore"):
        r = np.linalg.norm(accel_apply(p, samples), axis=1) - gravity
        rms = float(np.sqrt(np.mean(r * r)))
        first = np.concatenate([[0], np.cumsum(lens[:-1])]).astype(np.int64)
        interval_rms = np.sqrt(np.add.reduceat(r * r, first) / lens)
        mean_res = np.linalg.norm(accel_apply(p, means), axis=1) - gravity
    if not (math.isfinite(rms) and np.all(np.isfinite(p))):
        return None
    return SimpleNamespace(values=p, spans=spans, means=means, residual_rms=rms, n_residuals=int(len(r)),
                           scale_factors=1.0 / p[3:6], bias=p[6:9].copy(), lens=lens, interval_rms=interval_rms,
                           mean_residuals=mean_res)


def odd_intervals(fit) -> np.ndarray:
    """Indices of the intervals whose calibrated mean misses gravity by more than :data:`ODD_MEAN_K` times what the
    others' means (their median absolute miss, as a standard deviation) and its own samples' scatter (its residual
    RMS over the square root of its length) explain: an interval in the middle of a motion."""
    e = np.abs(fit.mean_residuals)
    noise = fit.interval_rms / np.sqrt(fit.lens)
    spread = 1.4826 * float(np.median(e))
    return np.flatnonzero(e > ODD_MEAN_K * np.maximum(spread, noise))


def coverage(group, n: int) -> np.ndarray:
    """Per sample, the fraction of the candidates ``group`` whose intervals hold it."""
    votes = np.zeros(n + 1, dtype=np.int64)
    for c in group:
        iv = np.asarray(c.intervals, dtype=np.int64).reshape(-1, 2)
        np.add.at(votes, iv[:, 0], 1)
        np.add.at(votes, iv[:, 1], -1)
    return np.cumsum(votes)[:n] / max(len(group), 1)


def unsupported_intervals(c, cover_sum) -> list:
    """The intervals of candidate ``c`` that, on average over their samples, fewer than :data:`MIN_SUPPORT` of the
    candidates hold (``cover_sum``: prefix sums of :func:`coverage`): a piece of motion only the most permissive
    detections take for a pose."""
    iv = np.asarray(c.intervals, dtype=np.int64).reshape(-1, 2)
    support = (cover_sum[iv[:, 1]] - cover_sum[iv[:, 0]]) / np.maximum(iv[:, 1] - iv[:, 0], 1)
    return [tuple(int(v) for v in iv[i]) for i in np.flatnonzero(support < MIN_SUPPORT)]


def rank(cands, acc, gravity: float, *, need: int, accel_counts: bool, min_poses: int = MIN_INTERVALS,
         counts_per_g=None, zero_count=None) -> Ranking:
    """Fit every candidate, mark the ineligible ones, order the eligible ones (module docstring). ``need``: the
    distinct poses of a complete detection; ``min_poses``: the fewest a calibration may use."""
    acc = np.asarray(acc, dtype=np.float64)
    csum = _prefix_sums(acc)
    for c in cands:
        if len(c.intervals) == 0:
            c.problems.append("no static interval")
            continue
        if len(c.intervals) < min_poses:
            c.problems.append(f"{len(c.intervals)} static intervals, at least {min_poses} needed")
            continue
        fit = quick_fit(acc, csum, c.intervals, c.samples_per_interval, gravity, counts=accel_counts)
        if fit is None:
            c.problems.append("accel fit failed or not finite")
            continue
        c.residual = float(fit.residual_rms)
        c.values = fit.values
        c.start = fit.values if fit.spans else None
        c.n_samples = int(fit.n_residuals)
        c.n_poses = distinct_poses(accel_apply(fit.values, fit.means))
        c.odd = [tuple(c.intervals[i]) for i in odd_intervals(fit)]
        if c.n_poses < min_poses:
            c.problems.append(f"{c.n_poses} distinct poses in {len(c.intervals)} intervals, at least {min_poses} "
                              "needed")
        try:
            plausibility.check_fieldcal_result(_AccelOnly(fit), accel_counts, False, "candidate")
        except ResultCheckError as exc:
            c.implausible.append(exc.message)
        if accel_counts:
            c.implausible += nominal_problems(fit, counts_per_g, zero_count)
    ok = [c for c in cands if c.eligible]
    fallback = sorted([c for c in cands if c.fitted and not c.problems and c.implausible], key=lambda c: c.residual)
    out = Ranking([], fallback, need, min_poses)
    if not ok:
        return out
    r0 = min(c.residual for c in ok)
    out.best_residual = r0
    for c in ok:
        if c.residual > r0 * (1 + CONTAMINATION):
            c.problems.append(f"residual {c.residual:.4g} m s-2 more than {100 * CONTAMINATION:g} % above the "
                              f"smallest, {r0:.4g}: its intervals hold motion")
    ok = [c for c in ok if c.eligible]
    out.most_poses = max(c.n_poses for c in ok)
    cover_sum = np.concatenate([[0.0], np.cumsum(coverage(ok, len(acc)))])
    for c in ok:
        for a, b in unsupported_intervals(c, cover_sum):
            if (a, b) not in c.odd:
                c.odd.append((a, b))
    voters = [c for c in ok if not c.odd] or ok
    most = max(c.n_poses for c in voters)
    out.n_validation = validate([c for c in voters if c.n_poses == most], ok, acc, gravity)
    clean = [c for c in ok if not c.odd]
    full = [c for c in clean if c.n_poses >= need]
    out.order = _banded(full)
    for p in sorted({c.n_poses for c in clean if c.n_poses < need}, reverse=True):
        out.order += _banded([c for c in clean if c.n_poses == p])
    out.order += sorted([c for c in ok if c.odd], key=lambda c: c.validated)
    return out


@dataclass
class _AccelOnly:
    accel: object
    gyro: object = None


def choice(chosen: Candidate, cands: list, ranking: Ranking, attempts: list, protocol: Protocol,
           status: str = "passed", problems: str = "") -> dict:
    """The ``detection_choice`` of the result: one line, the chosen and runner-up candidates, every candidate.
    ``status``: ``passed`` (its result passed the checks) or ``failed`` (no candidate did; ``problems`` says why
    this one fails)."""
    order = ranking.order
    runner = next((c for c in order if c is not chosen and (len(c.intervals) != len(chosen.intervals)
                                                             or c.residual != chosen.residual)), None)
    ok = [c for c in cands if c.eligible]
    why = f"{len(ok)} of {len(cands)} distinct candidates eligible"
    if status == "failed":
        why = (f"no candidate's calibration passed the result checks; this one, the best ranked, returned for "
               f"inspection: {problems}")
    elif chosen.odd:
        why += (f"; every eligible candidate has an interval whose mean misses gravity (e.g. samples "
                f"{list(chosen.odd[0])}): smallest validated residual")
    else:
        if chosen.n_poses < ranking.need:
            why += (f"; none has {ranking.need} distinct poses (recommended_intervals"
                    f"{' or the protocol poses + rest' if protocol.n_poses is not None else ''}): the one with the "
                    f"most ({chosen.n_poses}) chosen, {chosen.n_poses - 9 if chosen.n_poses > 9 else 'no'} pose(s) "
                    "of redundancy for the 9 accel parameters")
            peers = [c for c in ok if c.n_poses == chosen.n_poses and not c.odd]
        else:
            peers = [c for c in ok if c.n_poses >= ranking.need and not c.odd]
        top = min(peers, key=lambda c: c.validated)
        if top is chosen:
            why += ", smallest validated residual"
        else:
            why += (f", the most poses, whole intervals and the smallest own residual among validated residuals tied "
                    f"with the smallest ({top.validated:.5g} m s-2, {top.label()})")
    validated = ("" if chosen.validated is None else f", validated {chosen.validated:.5g} m s-2 over the "
                 f"{ranking.n_validation} samples most candidates find static")
    line = (f"detection chosen: {chosen.label()}: {len(chosen.intervals)} intervals ({chosen.n_poses} poses, "
            f"{chosen.n_samples} samples), accel residual {chosen.residual:.5g} m s-2{validated}; {why}")
    if runner is not None and status == "passed":
        line += (f"; runner-up {runner.label()}: {len(runner.intervals)} intervals ({runner.n_poses} poses), "
                 f"residual {runner.residual:.5g}, validated {runner.validated:.5g} m s-2")
    for c, reason in attempts:
        if c is not chosen:
            line += f"; {c.label()} set aside: {reason}"
    line += f"; {protocol.describe()}"
    out = {"status": status, "line": line, "chosen": chosen.as_dict(),
           "runner_up": None if runner is None else runner.as_dict(),
           "set_aside": [{"candidate": c.label(), "reason": r} for c, r in attempts if c is not chosen],
           "n_candidates": len(cands), "n_eligible": len(ok), "need_poses": ranking.need,
           "n_validation_samples": ranking.n_validation, "candidates": [c.as_dict() for c in cands]}
    if protocol.as_dict():
        out["protocol"] = {**protocol.as_dict(), "source": dict(protocol.source)}
    return out


FIX = ("give the detection in the settings: fieldcal.detection.k (threshold multiplier), "
       "fieldcal.detection.min_interval_s, fieldcal.detection.window_s or fieldcal.detection.threshold "
       "(rule detect), or fieldcal.detection.rule: imu_tk with fieldcal.detection.k; the protocol's timing "
       "in fieldcal.protocol.initial_rest_s / min_wait_s / n_poses")


def no_choice_error(cands: list, src: str, ranking: Ranking, protocol: Protocol, attempts=()) -> ResultCheckError:
    """The exit-3 refusal when no candidate detection gives a calibration to return: what was tried, the nearest
    miss, the settings keys (the recording itself first when no candidate finds enough distinct poses)."""
    fitted = [c for c in cands if c.residual is not None]
    most = max(fitted or cands, key=lambda c: (c.n_poses, len(c.intervals)), default=None)
    tried = (f"{len(cands)} distinct candidate detections (rules imu_tk and detect, k 2..300, windows 0.25-1 s; "
             f"{protocol.describe()})")
    few = most is None or most.n_poses < ranking.min_poses
    if few:
        # the gravity norm gives one equation per distinct pose: the 9 parameters need at least 9 of them
        need = ("the fewest the 9-parameter accelerometer model needs (one gravity-norm equation per pose)"
                if ranking.min_poses >= NORM_PARAMETERS else
                f"as fieldcal.min_intervals asks (the 9-parameter accelerometer model needs {NORM_PARAMETERS}, one "
                "gravity-norm equation per pose; with fewer, what the poses leave undetermined is held at nominal)")
        msg = f"no default static-interval detection finds {ranking.min_poses} distinct static poses, {need}: {tried}"
    else:
        msg = f"no default static-interval detection gives a plausible accelerometer calibration: {tried}"
    if most is not None:
        # distinct poses are counted on a candidate's accel fit, which runs only with enough intervals
        poses = (f"{most.n_poses} distinct poses" if most.fitted else
                 "distinct poses not counted (too few intervals for the accel fit that counts them)")
        msg += (f"; the most poses: {most.label()} with {len(most.intervals)} intervals, {poses} (at least "
                f"{ranking.min_poses} needed)")
        probs = [p for p in most.problems + most.implausible
                 if "distinct poses" not in p and not (not most.fitted and "static intervals, at least" in p)]
        if probs:
            msg += f", {probs[0]}"
    for c, reason in attempts:
        msg += f"; {c.label()}: {reason}"
    if protocol.n_poses is not None:
        msg += f"; the protocol declares {protocol.n_poses} poses after the initial rest"
    record = f"record at least {ranking.need} distinct static poses (IMU-TK's protocol: 12 or more)"
    if few:
        fix = (f"a multi-position session is needed: {record}; if the recording holds them, {FIX}; "
               f"fieldcal.min_intervals (now {ranking.min_poses}) only if fewer poses are meant")
    else:
        fix = f"{FIX}; fieldcal.min_intervals (now {ranking.min_poses}) only if fewer poses are meant; or {record}"
    return ResultCheckError(msg, file=src, field="fieldcal.detection", fix=fix)
