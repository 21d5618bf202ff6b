"""Static-interval detection on a raw IMU recording (variance in a sliding window).

Method (the idea of IMU-TK, Tedaldi, Pretto & Menegatti, ICRA 2014, written anew here)
------------------------------------------------------------------------------------
For every sample ``t`` the *variance magnitude* of a triad is

    s(t) = sqrt( var_w(x)^2 + var_w(y)^2 + var_w(z)^2 ),

with ``var_w`` the sample variance (ddof = 1) of one axis in a window of ``w`` samples centred on ``t``
(``w`` odd; the first and last ``w // 2`` samples take the value of the nearest full window). Units:
(triad units)^2, e.g. (m s-2)^2 or count^2. A sample is static when ``s_accel(t) < threshold`` (and, with
``use_gyro``, also ``s_gyro(t) < gyro_threshold``); static runs shorter than ``min_interval_s`` are dropped.

Threshold: unless given, ``threshold = k * s0`` where ``s0`` is the variance magnitude of the whole
*initial rest* (per-axis variance over the rest span, then the norm), IMU-TK's rule (its defaults: k up to
10, window 101 samples, initial rest 50 s). The initial rest is ``[0, init_s)`` when ``init_s`` is given;
otherwise it is found on the accelerometer: it ends one window before the first sample whose variance
magnitude reaches ``onset_factor`` (10) times the noise floor (10th percentile of ``s_accel`` over the
recording). The rule actually used is returned in :attr:`StaticDetection.rule`.

Intervals are ``[start, stop)`` sample indices (``stop`` exclusive).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: rows per chunk in :func:`moving_variance_norm` (the mean is removed per chunk to keep the
#: running sums exact enough for counts near 32768 and for very long recordings)
CHUNK = 1 << 16


class StaticDetectionError(ValueError):
    """Too few static intervals (or an unusable recording) for what the caller needs."""


def window_samples(window_s: float, fs: float) -> int:
    """Window length in samples: ``round(window_s * fs)``, made odd, at least 3."""
    w = int(round(window_s * fs))
    if w % 2 == 0:
        w += 1
    return max(w, 3)


def moving_variance_norm(x, w: int) -> np.ndarray:
    """Variance magnitude ``s(t)`` of an (n, 3) triad in a centred window of ``w`` (odd) samples.

    Returns an (n,) float64 array in (units of ``x``)^2. Edges take the nearest full-window value.
    Computed from running sums in chunks of 65,536 rows, each chunk with its own mean removed.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"moving_variance_norm: expected an (n, k) array, got shape {x.shape}")
    n = x.shape[0]
    if w % 2 == 0 or w < 3:
        raise ValueError(f"moving_variance_norm: window {w} must be odd and >= 3")
    if n < w:
        raise StaticDetectionError(f"recording of {n} samples is shorter than one detection window ({w} samples)")
    h = w // 2
    nwin = n - w + 1  # number of full windows; window j covers [j, j + w), centred on j + h
    out = np.empty(n)
    var = np.empty((nwin, x.shape[1]))
    for j0 in range(0, nwin, CHUNK):
        j1 = min(j0 + CHUNK, nwin)
        seg = x[j0:j1 + w - 1]
        seg = seg - seg.mean(axis=0)
        c1 = np.zeros((seg.shape[0] + 1, seg.shape[1]))
        c2 = np.zeros_like(c1)
        np.cumsum(seg, axis=0, out=c1[1:])
        np.cumsum(seg * seg, axis=0, out=c2[1:])
        s1 = c1[w:] - c1[:-w]
        s2 = c2[w:] - c2[:-w]
        v = (s2 - s1 * s1 / w) / (w - 1)
        var[j0:j1] = np.maximum(v, 0.0)  # round-off can make an exactly constant window slightly negative
    out[h:n - h] = np.sqrt((var * var).sum(axis=1))
    out[:h] = out[h]
    out[n - h:] = out[n - h - 1]
    return out


def variance_norm(x) -> float:
    """Variance magnitude of a whole span: norm of the per-axis sample variances (ddof = 1)."""
    x = np.asarray(x, dtype=np.float64)
    return float(np.linalg.norm(x.var(axis=0, ddof=1)))


def runs(mask) -> np.ndarray:
    """``[start, stop)`` pairs of the runs of True in a boolean array, as an (m, 2) int64 array."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]]).astype(np.int8)
    d = np.diff(m)
    return np.column_stack([np.flatnonzero(d == 1), np.flatnonzero(d == -1)]).astype(np.int64)


@dataclass
class StaticDetection:
    """Result of :func:`detect_static`.

    ``intervals``: (m, 2) int64 ``[start, stop)`` sample indices. ``threshold``: accel variance-magnitude
    threshold in (accel units)^2; ``gyro_threshold`` likewise for the gyro (None when unused).
    ``rule``: how the thresholds were chosen, in words. ``stat_accel`` / ``stat_gyro``: the per-sample
    variance magnitudes (kept for plots and threshold suggestions).
    """

    intervals: np.ndarray
    threshold: float
    gyro_threshold: float | None
    rule: str
    fs: float
    window: int
    min_samples: int
    k: float | None
    init_span: tuple[int, int] | None
    init_variance: float | None
    init_variance_gyro: float | None
    stat_accel: np.ndarray = field(repr=False)
    stat_gyro: np.ndarray | None = field(repr=False, default=None)

    @property
    def count(self) -> int:
        return int(len(self.intervals))

    @property
    def durations_s(self) -> np.ndarray:
        return (self.intervals[:, 1] - self.intervals[:, 0]) / self.fs

    def summary(self) -> dict:
        """JSON-ready description (no per-sample arrays)."""
        return {
            "n_intervals": self.count,
            "threshold": self.threshold,
            "gyro_threshold": self.gyro_threshold,
            "rule": self.rule,
            "window_samples": self.window,
            "min_interval_samples": self.min_samples,
            "k": self.k,
            "init_span": list(self.init_span) if self.init_span else None,
            "init_variance": self.init_variance,
            "init_variance_gyro": self.init_variance_gyro,
            "intervals": self.intervals.tolist(),
        }

    def intervals_at(self, threshold: float, gyro_threshold: float | None = None) -> np.ndarray:
        """The intervals a different accel (and gyro) threshold would give, same window and minimum length."""
        mask = self.stat_accel < threshold
        gthr = self.gyro_threshold if gyro_threshold is None else gyro_threshold
        if self.stat_gyro is not None and gthr is not None:
            mask &= self.stat_gyro < gthr
        r = runs(mask)
        return r[(r[:, 1] - r[:, 0]) >= self.min_samples]

    def suggest_threshold(self, needed: int) -> float | None:
        """Smallest accel threshold (gyro threshold scaled by the same factor) giving >= ``needed`` intervals.

        Scans factors 1.25^j of the current thresholds, nearest first (j = 0, 1, -1, 2, -2, ..., +-20: a
        higher threshold can merge intervals, a lower one can split them); None when no factor is enough.
        """
        for j in sorted(range(-20, 21), key=lambda j: (abs(j), -j)):
            f = 1.25 ** j
            g = None if self.gyro_threshold is None else self.gyro_threshold * f
            if len(self.intervals_at(self.threshold * f, g)) >= needed:
                return self.threshold * f
        return None

    def require(self, needed: int, path=None) -> "StaticDetection":
        """Raise :func:`too_few_static_error` when fewer than ``needed`` intervals were found."""
        if self.count < needed:
            raise too_few_static_error(needed, self.count, self.threshold, rule=self.rule,
                                       suggestion=self.suggest_threshold(needed), path=path,
                                       min_interval_s=self.min_samples / self.fs, k=self.k)
        return self


def too_few_static_error(needed: int, found: int, threshold: float, *, rule: str = "", suggestion=None,
                         path=None, min_interval_s=None, k=None) -> StaticDetectionError:
    """The error to raise when a method needs ``needed`` static intervals and only ``found`` were detected.

    The message names the threshold used (and how it was chosen) and suggests a fix: a threshold that
    would give enough intervals when ``suggestion`` is known, else a larger multiplier / shorter minimum.
    """
    where = f"{path}: " if path else ""
    msg = (f"{where}static-interval detection found {found} static interval(s), {needed} needed "
           f"(accel variance threshold {threshold:.4g}")
    msg += f"; {rule})" if rule else ")"
    if suggestion is not None:
        fix = f"pass threshold={suggestion:.4g} to detect_static"
        if k is not None:
            fix += f" (or k={k * suggestion / threshold:.3g} with the same initial rest)"
    else:
        fix = "no threshold gives that many: raise k or lower min_interval_s"
        if min_interval_s is not None:
            fix += f" (now {min_interval_s:g} s)"
        fix += ", or record more static positions"
    return StaticDetectionError(f"{msg} -- fix: {fix}")


def _find_initial_rest(stat: np.ndarray, w: int, onset_factor: float, floor_pct: float):
    floor = float(np.percentile(stat, floor_pct))
    above = stat >= onset_factor * floor
    if not above.any():
        return len(stat), floor
    onset = int(np.argmax(above))
    return max(onset - w, 0), floor


def find_initial_rest(stat, w: int, onset_factor: float = 10.0, floor_percentile: float = 10.0):
    """Length in samples of the initial rest found on a variance magnitude ``stat`` (window ``w``), the rule of
    :func:`detect_static` without ``init_s`` (module docstring), and the noise floor it used:
    ``(n0, floor)``."""
    return _find_initial_rest(np.asarray(stat, dtype=np.float64), int(w), onset_factor, floor_percentile)


def detect_static(accel, gyro, fs: float, min_interval_s: float = 1.0, threshold: float | None = None,
                  window_s: float = 1.0, *, k: float = 10.0, init_s: float | None = None,
                  gyro_threshold: float | None = None, use_gyro: bool = True, onset_factor: float = 10.0,
                  floor_percentile: float = 10.0, stat_accel=None, stat_gyro=None) -> StaticDetection:
    """Find static intervals of an (n, 3) accel and (n, 3) gyro record sampled at ``fs`` Hz.

    ``window_s`` (s): variance window, ``round(window_s * fs)`` samples made odd (IMU-TK: 101 at 100 Hz).
    ``min_interval_s`` (s): shortest static interval kept (IMU-TK: 100 samples).
    ``threshold``: accel variance-magnitude threshold in (accel units)^2; None: ``k`` x the initial rest's.
    ``init_s`` (s): length of the initial rest; None: found automatically (see module docstring).
    ``use_gyro``: also require the gyro variance magnitude below ``gyro_threshold`` (default ``k`` x the
    gyro's over the same initial rest) -- it catches turns about the vertical, which barely move the accel.

    Units: any (raw counts or physical); thresholds are in the squared units of each triad.
    ``stat_accel`` / ``stat_gyro``: the :func:`moving_variance_norm` of accel / gyro with this window, when the
    caller has them already (several thresholds tried on one recording); computed here otherwise.
    """
    accel = np.asarray(accel, dtype=np.float64)
    if accel.ndim != 2 or accel.shape[1] != 3:
        raise ValueError(f"detect_static: accel must be (n, 3), got {accel.shape}")
    if not (fs > 0 and math.isfinite(fs)):
        raise ValueError(f"detect_static: sample rate {fs} Hz is not positive")
    n = accel.shape[0]
    w = window_samples(window_s, fs)
    min_samples = max(1, int(math.ceil(min_interval_s * fs - 1e-9)))
    sa = moving_variance_norm(accel, w) if stat_accel is None else np.asarray(stat_accel, dtype=np.float64)
    sg = None
    if use_gyro:
        gyro = np.asarray(gyro, dtype=np.float64)
        if gyro.shape != accel.shape:
            raise ValueError(f"detect_static: gyro shape {gyro.shape} differs from accel shape {accel.shape}")
        sg = moving_variance_norm(gyro, w) if stat_gyro is None else np.asarray(stat_gyro, dtype=np.float64)

    need_init = threshold is None or (use_gyro and gyro_threshold is None)
    span = None
    v0 = v0g = None
    rule_parts = []
    if need_init:
        if init_s is not None:
            n0 = min(int(round(init_s * fs)), n)
            how = f"initial rest [0, {n0}) samples = first {init_s:g} s (given)"
        else:
            n0, floor = _find_initial_rest(sa, w, onset_factor, floor_percentile)
            how = (f"initial rest [0, {n0}) samples = {n0 / fs:.1f} s, found automatically (ends one window before "
                   f"accel variance first reaches {onset_factor:g} x its {floor_percentile:g}th percentile "
                   f"{floor:.3g})")
        if n0 < w:
            raise StaticDetectionError(
                f"initial rest of {n0} samples is shorter than one window ({w} samples): no automatic threshold "
                "-- fix: pass threshold= (and gyro_threshold=) explicitly, or init_s= for a known rest")
        span = (0, n0)
        rule_parts.append(how)
    if threshold is None:
        v0 = variance_norm(accel[:span[1]])
        if not v0 > 0:
            raise StaticDetectionError("accel variance over the initial rest is zero (constant signal): no "
                                       "automatic threshold -- fix: pass threshold= explicitly")
        threshold = k * v0
        rule_parts.append(f"accel threshold = k={k:g} x initial-rest variance magnitude {v0:.4g}")
    else:
        threshold = float(threshold)
        rule_parts.append(f"accel threshold {threshold:.4g} given")
    if use_gyro:
        if gyro_threshold is None:
            v0g = variance_norm(gyro[:span[1]])
            if v0g > 0:
                gyro_threshold = k * v0g
                rule_parts.append(f"gyro threshold = k={k:g} x initial-rest variance magnitude {v0g:.4g}")
            else:
                sg = None
                rule_parts.append("gyro criterion dropped: gyro constant over the initial rest")
        else:
            gyro_threshold = float(gyro_threshold)
            rule_parts.append(f"gyro threshold {gyro_threshold:.4g} given")
    rule_parts.append(f"window {w} samples, minimum interval {min_samples} samples")

    mask = sa < threshold
    if sg is not None:
        mask &= sg < gyro_threshold
    r = runs(mask)
    r = r[(r[:, 1] - r[:, 0]) >= min_samples]
    return StaticDetection(intervals=r, threshold=float(threshold),
                           gyro_threshold=None if sg is None else float(gyro_threshold),
                           rule="; ".join(rule_parts), fs=float(fs), window=w, min_samples=min_samples,
                           k=k if (v0 is not None or v0g is not None) else None, init_span=span,
                           init_variance=v0, init_variance_gyro=v0g, stat_accel=sa, stat_gyro=sg)


def detect_in_recording(ds, **kwargs) -> StaticDetection:
    """:func:`detect_static` on a ``calib-recording-1`` dataset (its raw accel/gyro and ``sample_rate_hz``)."""
    return detect_static(np.asarray(ds["accel"].values, dtype=np.float64),
                         np.asarray(ds["gyro"].values, dtype=np.float64),
                         float(ds.attrs["sample_rate_hz"]), **kwargs)


def add_segment_table(ds, intervals, *, label_prefix: str = "static"):
    """Return a copy of a recording with a segment table of static intervals.

    ``intervals``: (m, 2) ``[start, stop)`` sample indices, or a :class:`StaticDetection` (its rule and
    thresholds are then stored in the ``segment_index`` attributes). Fills ``segment_index`` (-1 outside the
    intervals), ``segment_kind = 'static'`` and ``segment_label = '<prefix>_NN'``. Refuses a dataset that
    already has a segment table.
    """
    det = intervals if isinstance(intervals, StaticDetection) else None
    iv = np.asarray(det.intervals if det is not None else intervals, dtype=np.int64).reshape(-1, 2)
    if "segment" in ds.dims or "segment_index" in ds:
        raise ValueError(f"{ds.attrs.get('_path', 'dataset')}: variable 'segment_index': the recording already "
                         "has a segment table -- fix: drop it first or keep the imported segments")
    n = ds.sizes["time"]
    if len(iv):
        if (iv[:, 0] < 0).any() or (iv[:, 1] > n).any() or (iv[:, 1] <= iv[:, 0]).any():
            raise ValueError(f"add_segment_table: intervals must satisfy 0 <= start < stop <= {n}")
        if (iv[1:, 0] < iv[:-1, 1]).any():
            raise ValueError("add_segment_table: intervals must be sorted and must not overlap")
    seg = np.full(n, -1, dtype=np.int32)
    for i, (a, b) in enumerate(iv):
        seg[a:b] = i
    attrs = {"long_name": "segment of each sample, -1 for transitions"}
    if det is not None:
        attrs.update({"static_detection_rule": det.rule, "static_detection_threshold": det.threshold})
        if det.gyro_threshold is not None:
            attrs["static_detection_gyro_threshold"] = det.gyro_threshold
    out = ds.copy()
    out["segment_index"] = (("time",), seg, attrs)
    out = out.assign_coords(segment=np.arange(len(iv)))
    out["segment_kind"] = (("segment",), np.asarray(["static"] * len(iv), dtype=str))
    out["segment_label"] = (("segment",), np.asarray([f"{label_prefix}_{i:02d}" for i in range(len(iv))], dtype=str))
    return out
