"""The sample clock of a recording with time stamps, and its judgement: jitter, dropped samples, gaps.

One fit for every reader: the recording check (:func:`calib.io.recording.check_clock`), the importers
(:func:`calib.ingest.common.time_clock`), the field calibration's step weights and the navigator's time check.

Model
-----
The clock is the least-squares line of stamp against *clock index*,

    t_j = t0_r + T * n_j + e_j,

with one period ``T`` for the whole recording, one offset ``t0_r`` per run (runs are split at gaps) and ``e_j``
the stamping jitter. The clock index ``n_j`` advances by 1 from one sample to the next, by k where k - 1
samples were dropped. The residual ``r_j = e_j / T`` (periods) is how far stamp j lies off the line.

Judgement (the residual, not the single step)
---------------------------------------------
A logger that stamps samples when they arrive (USB or serial bursts) gives steps of 1.024 periods most of
the time, a short step now and then, and now and then a long one that the next short steps pay back: its
stamps wander off the line and come back. That is jitter, whatever the length of a single step: it is
reported (residual standard deviation and largest residual, in periods) and accepted.

What is not jitter is a *level shift*: the residual leaves the line and stays off it. The level on either
side of step j is the median residual over the :data:`LEVEL_WINDOW` samples before and after it (a median,
so a burst shorter than half the window does not move it); a change of at least :data:`SHIFT_MIN` periods is a
shift of size ``delta``:

* ``delta`` within :data:`WHOLE_TOL` of a whole number m >= 1 of periods: m dropped samples, placed at the
  step with the largest excess over its count (where the stamps leave the line), as long as
  m <= :data:`MAX_DROP_RUN`;
* any other shift (not whole, more than :data:`MAX_DROP_RUN` samples lost in a row, or the stamps jumping back
  by a period or more): a **gap**, where the recording is split; each run gets its own offset;
* a lasting change of less than :data:`SHIFT_MIN` periods is a change of the logger's latency: part of
  the jitter.

The steps are counted first by their length (a step of about k periods: k - 1 drops, when it is longer than
1.5 periods by more than twice the steps' own scatter); then, pass by pass, the counts are corrected where
the level changes (a long step that the next ones pay back loses the drops its length suggested) and the
gaps are marked (:func:`_classify`). Bursts of up to :data:`MAX_DROP_RUN` samples held and sent at once are
told from drops and gaps (tested over random patterns); within :data:`LEVEL_WINDOW` samples of a gap a burst's
return can pass for part of it: what the stamps tell is resolved to that window.

When every stamp lies within :data:`SHIFT_MIN` / 2 periods of the line through the plain sample numbers,
no shift of :data:`SHIFT_MIN` or more can be hidden in it (the line is continuous, so at a shift of ``delta``
a stamp on one side or the other lies at least ``delta`` / 2 off it): such a clock is uniform, and the
window search is skipped.

:func:`fit_clock` returns a :class:`ClockFit`: rate and its standard uncertainty (the slope's, from the
residual scatter), jitter, the dropped samples (count and where) and the gaps, with the windows between the
gaps (:meth:`ClockFit.windows`) that import as one uniform clock each.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: samples per side of the robust level (median) on either side of a step
LEVEL_WINDOW = 201
#: samples per side of the shorter level: counts near each other and a drop's fraction (a gap) at its own step
SHORT_WINDOW = 41
#: a lasting change of the residual of at least this many periods is a shift (drops or a gap)
SHIFT_MIN = 0.75
#: a shift within this many periods of a whole number m is m dropped samples
WHOLE_TOL = 0.25
#: more samples than this lost in a row is a hole in the record, a gap: what the sensor measured in it (the
#: motion of a turn, say) cannot be bridged by weighting the next sample; a lost message or a lost buffer of a
#: few samples can
MAX_DROP_RUN = 10
MAX_PASSES = 64
#: fewest samples on either side of a step for its level change to be judged (the ends of a run)
EDGE_WINDOW = 20


class ClockError(ValueError):
    """Time stamps from which no clock can be fitted (fewer than two, not increasing, not finite)."""


@dataclass
class ClockFit:
    """The fitted sample clock. Times in seconds; positions are sample numbers of the recording (0-based).

    ``index``: clock index of each sample (int64; across a gap advanced by the rounded gap length, for
    reference only). ``dropped_after`` / ``dropped_count``: samples missing between sample j and j + 1.
    ``gaps``: ``(j, step_s)`` for each split between sample j and j + 1. ``runs``: ``[start, stop)`` per run.
    ``stamps``: the time stamps fitted (:meth:`windows` gives seconds from the first).
    """

    rate_hz: float
    rate_std_hz: float
    t0_s: float
    index: np.ndarray
    jitter_std_s: float
    max_residual_s: float
    largest_step_s: float
    n_samples: int
    dropped_after: np.ndarray
    dropped_count: np.ndarray
    gaps: list = field(default_factory=list)
    runs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    median_step_rate_hz: float = float("nan")
    stamps: np.ndarray | None = field(default=None, repr=False)

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def n_dropped(self) -> int:
        return int(self.dropped_count.sum())

    @property
    def uniform(self) -> bool:
        """No drops and no gaps: every step is one period."""
        return self.n_dropped == 0 and not self.gaps

    @property
    def jitter_std_periods(self) -> float:
        return self.jitter_std_s * self.rate_hz

    @property
    def max_residual_periods(self) -> float:
        return self.max_residual_s * self.rate_hz

    def steps(self) -> np.ndarray:
        """Clock periods from each sample to the next (n - 1,): 1, or k at a drop, the rounded length at a gap."""
        return np.diff(self.index)

    def windows(self, offset_s: float = 0.0) -> list[tuple[float, float]]:
        """``(start_s, stop_s)`` of each run, in seconds from the first stamp, for an importer's ``start_s`` /
        ``stop_s`` (samples with ``start_s <= t - t_first < stop_s``): each bound halfway between the last stamp
        of a run and the first of the next, the first window starting at 0 and the last ending half a period
        after the last stamp; ``offset_s`` added (the stamps' first sample's own time from an earlier origin)."""
        t = self.stamps
        out = []
        for a, b in self.runs:
            lo = 0.0 if a == 0 else 0.5 * (t[a - 1] + t[a]) - t[0]
            hi = (t[b - 1] - t[0] + 0.5 * self.period_s) if b == len(t) else 0.5 * (t[b - 1] + t[b]) - t[0]
            out.append((float(lo) + offset_s, float(hi) + offset_s))
        return out

    def gap_refusal(self, offset_s: float = 0.0, first: int = 0) -> tuple[str, str]:
        """``(problem, fix)`` of a refusal for a clock with gaps: the first gap by its samples, time and size, and
        the windows either side of the gaps (seconds from the first stamp, plus ``offset_s``; sample numbers plus
        ``first``) that hold one uniform clock each, for the import settings' ``start_s`` / ``stop_s``."""
        t = self.stamps
        j, step = self.gaps[0]
        problem = (f"time gap of {step:.6g} s ({step * self.rate_hz:.3g} sample periods of {self.period_s:.6g} s) "
                   f"between samples {j + first} and {j + first + 1} (t = {t[j]:.6f} s, "
                   f"{t[j] - t[0] + offset_s:.6g} s from the first sample): the stamps leave the fitted clock there "
                   "for good")
        if len(self.gaps) > 1:
            problem += f"; {len(self.gaps)} gaps in all, after samples " + ", ".join(
                str(g + first) for g, _ in self.gaps[:5]) + (", ..." if len(self.gaps) > 5 else "")
        return problem, window_fix(self.windows(offset_s), "the gaps")

    def summary(self) -> str:
        """One line for the import and validate output."""
        s = (f"{self.rate_hz:.6g} Hz fitted (least-squares clock over {self.n_samples} samples), jitter sd "
             f"{self.jitter_std_periods:.2g} periods, largest {self.max_residual_periods:.2g} periods; "
             f"{len(self.gaps)} gap(s), {self.n_dropped} dropped sample(s)")
        if self.n_dropped:
            where = ", ".join(f"{c} after sample {j}" for j, c in zip(self.dropped_after[:3], self.dropped_count[:3]))
            s += f" ({where}{', ...' if len(self.dropped_after) > 3 else ''})"
        return s

    def describe(self) -> str:
        s = (f"{self.rate_hz:.9g} Hz +- {self.rate_std_hz:.2g} Hz (least-squares clock over {self.n_samples} "
             f"samples; median step would give {self.median_step_rate_hz:.6g} Hz); jitter {self.jitter_std_s:.3g} s "
             f"rms, largest residual {self.max_residual_s:.3g} s, largest step {self.largest_step_s:.6g} s; "
             f"{self.n_dropped} dropped sample(s)")
        if self.gaps:
            s += f"; {len(self.gaps)} gap(s): " + ", ".join(f"{d:.4g} s after sample {j}" for j, d in self.gaps[:5])
        return s

    def attrs(self, prefix: str = "clock_") -> dict:
        """Scalar attributes for a recording (netCDF-ready)."""
        a = {"rate_hz": float(self.rate_hz), "rate_std_hz": float(self.rate_std_hz),
             "jitter_std_s": float(self.jitter_std_s), "max_residual_s": float(self.max_residual_s),
             "jitter_std_periods": float(self.jitter_std_periods),
             "max_residual_periods": float(self.max_residual_periods),
             "largest_step_s": float(self.largest_step_s), "dropped_samples": int(self.n_dropped),
             "gaps": len(self.gaps), "median_step_rate_hz": float(self.median_step_rate_hz),
             "summary": self.summary()}
        if self.n_dropped:
            a["dropped_after"] = " ".join(f"{j}x{c}" if c > 1 else str(j)
                                          for j, c in zip(self.dropped_after[:200], self.dropped_count[:200]))
        if self.gaps:
            a["gaps_after"] = " ".join(f"{j}:{d:.6g}s" for j, d in self.gaps[:200])
        return {prefix + k: v for k, v in a.items()}


def seconds(x: float) -> str:
    """Seconds for a settings file: to the microsecond, without trailing zeros."""
    return f"{x:.6f}".rstrip("0").rstrip(".")


def window_fix(windows, between: str) -> str:
    """The fix of a refusal that leaves parts of a record usable: import each window ``(start_s, stop_s)`` (seconds
    from the first sample) as its own recording."""
    show = "; ".join(f"start_s: {seconds(a)}, stop_s: {seconds(b)}" for a, b in windows[:4])
    return (f"import each part between {between} as its own recording, with the import settings' start_s / stop_s "
            f"(seconds from the first sample, stop_s excluded): {show}" + ("; ..." if len(windows) > 4 else ""))


def _pooled_line(t, idx, runs):
    """One slope for all runs, one offset per run (least squares). Returns slope, offsets, residuals, Sxx."""
    sxy = sxx = 0.0
    means = []
    for a, b in runs:
        x = idx[a:b].astype(float)
        y = t[a:b]
        xm, ym = x.mean(), y.mean()
        means.append((xm, ym))
        dx = x - xm
        sxy += float(dx @ (y - ym))
        sxx += float(dx @ dx)
    slope = sxy / sxx if sxx > 0 else float("nan")
    res = np.empty_like(t)
    offsets = []
    for (a, b), (xm, ym) in zip(runs, means):
        off = ym - slope * xm
        offsets.append(off)
        res[a:b] = t[a:b] - (off + slope * idx[a:b])
    return slope, offsets, res, sxx


def _runs(split, n):
    cut = np.flatnonzero(split) + 1
    starts = np.concatenate([[0], cut])
    stops = np.concatenate([cut, [n]])
    return np.column_stack([starts, stops]).astype(np.int64)


def _levels(u, runs, h=LEVEL_WINDOW):
    """The residual's robust level before and after each step ``(before, after)``, each (n - 1,), in periods:
    the median of the ``h`` samples up to the step and of the ``h`` after it, within a run (fewer near its ends;
    no change judged across a gap, or with fewer than :data:`EDGE_WINDOW` samples on a side)."""
    from scipy import ndimage  # heavy import (about 0.3 s), needed only for stamps that leave the line

    before, after = np.zeros(len(u) - 1), np.zeros(len(u) - 1)
    judged = np.zeros(len(u) - 1, dtype=bool)
    for a, b in runs:
        m = b - a
        if m < 4:
            continue
        w = min(h, m // 2)
        w -= 1 - w % 2   # odd: the median of w samples is one of them
        # median of w samples ending at i: a centred median of odd width shifted by half of it
        med = ndimage.median_filter(u[a:b], size=w, mode="mirror", origin=0)
        half = (w - 1) // 2
        j = np.arange(m - 1)
        lo = np.clip(j - half, 0, m - 1)
        hi = np.clip(j + 1 + half, 0, m - 1)
        bf, af = med[lo], med[hi]
        ur = u[a:b]
        for i in range(min(w - 1, m - 1)):   # near the ends of the run: the samples there are fewer than w
            bf[i] = np.median(ur[:i + 1])
        for i in range(max(0, m - w), m - 1):
            af[i] = np.median(ur[i + 1:])
        before[a:b - 1], after[a:b - 1] = bf, af
        # a level of fewer than EDGE_WINDOW samples is not judged (a burst at the start of a run would pass for one)
        judged[a + EDGE_WINDOW - 1:b - EDGE_WINDOW] = True
        after[a:b - 1] = np.where(judged[a:b - 1], after[a:b - 1], before[a:b - 1])
    # drops still miscounted tilt the fitted line (one slope for all runs), and with it every level change by
    # about the same amount (the tilt times the distance between the windows); most steps change nothing: their
    # median change is it
    if judged.any():
        after[judged] -= np.median(after[judged] - before[judged])
    return before, after


def _flattest(u, counted, r0, r1, h):
    """Of the steps ``counted`` (each with a drop counted), the one whose drop, taken back, leaves the residual
    ``u`` over the region ``[r0, r1)`` and ``h`` samples either side flattest (least absolute deviation from
    its median): where the stamps that ran ahead come back, not a drop that is real nearby."""
    lo, hi = max(0, r0 - h), min(len(u), r1 + 1 + h)
    seg = u[lo:hi]
    pos = np.arange(lo, hi)
    cost = [np.abs(x - np.median(x)).sum() for x in (seg + (pos > c) for c in counted)]
    return int(counted[int(np.argmin(cost))])


def _recount(jump, u, ratio, k, gap_mask, h, back):
    """The counts where the level (over ``h`` samples) changes: a region is a stretch of steps where it changes
    by more than half a period, and it counts if the change reaches :data:`SHIFT_MIN` somewhere; its rounded
    largest change is added to the drops there (each where the step is longest over its count) or taken from
    the drops counted there (each where taking it leaves the residual flattest, :func:`_flattest`); a region
    going down with no drop to take is put in ``back``. Returns True if a count changed."""
    wide = (np.abs(jump) > 0.5) & ~gap_mask
    edges = np.flatnonzero(np.diff(np.concatenate([[0], wide.astype(np.int8), [0]])))
    changed = False
    peaks = [float(jump[r0 + np.argmax(np.abs(jump[r0:r1]))]) for r0, r1 in zip(edges[::2], edges[1::2])]
    # drops miscounted tilt the line, and with it the level of the residual: a large miscount can make a
    # small change appear elsewhere, so a pass fixes only changes of at least half the largest one
    least = max([SHIFT_MIN] + [0.5 * abs(p) for p in peaks])
    for r0, r1, peak in zip(edges[::2], edges[1::2], peaks):
        region = np.arange(r0, r1)
        if abs(peak) < least:
            continue
        m = int(round(peak))
        for _ in range(abs(m)):
            over = ratio[region] - k[region]
            if m > 0:
                k[region[np.argmax(over)]] += 1
                changed = True
                continue
            counted = region[k[region] > 1]
            if not counted.size:
                back.append(region)
                break
            k[_flattest(u, counted, r0, r1, h)] -= 1
            changed = True
    return changed


def _classify(u, ratio, k, gap_mask, recount=True):
    """One pass over the places where the residual ``u`` changes its level (:func:`_levels`).

    First the counts (:func:`_recount`), with the long level window, then with the short one (a burst or a
    drop near another is resolved there). Only when no count changes any more are gaps marked: a hole of more
    than :data:`MAX_DROP_RUN` samples that the level keeps; then, one a pass, a counted drop whose step still
    leaves the level changed by more than :data:`WHOLE_TOL` over both windows (a whole number of periods and a
    fraction), or a drop of the level by :data:`SHIFT_MIN` or more where no drop is counted to take (the stamps
    jumping back). ``recount`` False: the counts are kept as they are (they cycle, :func:`fit_clock`) and only
    gaps are marked. Returns True if anything changed."""
    runs = _runs(gap_mask, len(u))
    back = []
    jumps = {}
    for h in (LEVEL_WINDOW, SHORT_WINDOW):
        before, after = _levels(u, runs, h)
        jumps[h] = after - before
        if recount and _recount(jumps[h], u, ratio, k, gap_mask, h, back):
            return True
    jump, jshort = jumps[LEVEL_WINDOW], jumps[SHORT_WINDOW]
    # a hole that the level keeps (no burst pays it back): a gap, split before the gaps below, so that the level
    # windows of what is near it do not reach across it
    hole = ((k - 1) > MAX_DROP_RUN) & (np.abs(jump) < WHOLE_TOL) & ~gap_mask
    if hole.any():
        gap_mask |= hole
        return True
    # one gap a pass, the most certain first (a gap's fraction shows in the levels of its neighbours too, until
    # the split there takes it out of their windows); the smaller of the two windows' changes, so that a burst
    # or a drop within the long window but not at the step does not pass for a fraction of this one
    frac = np.where(np.sign(jshort) == np.sign(jump), np.minimum(np.abs(jump), np.abs(jshort)), 0.0)
    score = np.where((k > 1) & ~gap_mask, frac, 0.0)
    for region in back:
        j = region[np.argmin(ratio[region])]
        score[j] = max(score[j], abs(jump[j]))
    j = int(np.argmax(score))
    if score[j] <= WHOLE_TOL:
        return False
    gap_mask[j] = True
    return True


def fit_clock(t, nominal_rate_hz: float | None = None) -> ClockFit:
    """Fit the sample clock to time stamps ``t`` (s, strictly increasing) and judge it; see the module docstring.

    ``nominal_rate_hz``: optional starting period (1 / rate) for counting steps; default from the steps.
    """
    t = np.asarray(t, dtype=np.float64).ravel()
    n = len(t)
    if n < 2:
        raise ClockError(f"{n} time stamp(s): a clock needs at least two")
    if not np.all(np.isfinite(t)):
        raise ClockError("time stamps contain NaN or Inf")
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0))
        raise ClockError(f"time stamps not strictly increasing at sample {i + 1}")
    med = float(np.median(d))
    gap_mask = np.zeros(n - 1, dtype=bool)
    runs = _runs(gap_mask, n)
    # every step one period: the line through the plain sample numbers, if every stamp stays near it
    k = np.ones(n - 1, dtype=np.int64)
    idx = np.arange(n, dtype=np.int64)
    fit = _pooled_line(t, idx, runs)
    slope, res = fit[0], fit[2]
    if not (slope > 0 and np.max(np.abs(res)) < 0.5 * SHIFT_MIN * slope):
        # a first period that counts the steps right: the mean step over steps shorter than 1.5 median steps
        # (bursty stamps: 1.024 and short steps average to the period; drops are left out)
        if nominal_rate_hz:
            period = 1.0 / nominal_rate_hz
        else:
            short = d[d < 1.5 * med]
            period = float(short.mean()) if short.size else med
        ratio = d / period
        # a step counts drops when longer than 1.5 periods by more than twice the steps' own scatter (a robust
        # sd from the steps shorter than 1.5 periods): jittered stamps are not counted as drops to start with
        normal = ratio[ratio < 1.5]
        spread = 1.4826 * float(np.median(np.abs(normal - np.median(normal)))) if normal.size else 0.0
        k = np.where(ratio > 1.5 + 2.0 * spread, np.maximum(1, np.rint(np.minimum(ratio, 1e9))), 1).astype(np.int64)
        # the counts of a cluster of bursts and drops can flip between two readings pass after pass; a count that
        # comes back is not resolved by more passes: it is kept, and the gaps are marked (each new gap lets the
        # counts change again), so that a cycle in one place does not hide a hole elsewhere
        seen, recount = set(), True
        for _ in range(MAX_PASSES):
            runs = _runs(gap_mask, n)
            k = np.where(gap_mask, 1, k)
            idx = np.concatenate([[0], np.cumsum(k)])
            period, _, res, _ = _pooled_line(t, idx, runs)
            ratio = d / period
            u = res / period
            state = k.tobytes() + gap_mask.tobytes()
            recount = recount and state not in seen
            seen.add(state)
            n_gaps = int(gap_mask.sum())
            if not _classify(u, ratio, k, gap_mask, recount):
                break
            if gap_mask.sum() > n_gaps:
                seen, recount = set(), True
        gap_mask |= (k - 1) > MAX_DROP_RUN   # a hole in the record, even where the stamps keep to the line
        k = np.where(gap_mask, np.maximum(1, np.rint(np.minimum(d / period, 1e9))).astype(np.int64), k)
        idx = np.concatenate([[0], np.cumsum(k)]).astype(np.int64)
        runs = _runs(gap_mask, n)
        fit = _pooled_line(t, idx, runs)
    slope, offsets, res, sxx = fit
    dof = n - 1 - len(runs)
    s2 = float(res @ res) / dof if dof > 0 else 0.0
    slope_std = float(np.sqrt(s2 / sxx)) if sxx > 0 else float("inf")
    drop = (~gap_mask) & (k > 1)
    in_run = d[~gap_mask]
    return ClockFit(
        rate_hz=1.0 / slope, rate_std_hz=slope_std / slope ** 2, t0_s=float(offsets[0]), index=idx,
        jitter_std_s=float(np.sqrt(s2)), max_residual_s=float(np.max(np.abs(res))),
        largest_step_s=float(in_run.max()) if in_run.size else float("nan"), n_samples=n,
        dropped_after=np.flatnonzero(drop).astype(np.int64), dropped_count=(k[drop] - 1).astype(np.int64),
        gaps=[(int(j), float(d[j])) for j in np.flatnonzero(gap_mask)], runs=runs,
        median_step_rate_hz=1.0 / med, stamps=t)
