"""The sample clock of a recording with time stamps: time as the clock ran, not as the samples arrived.

A logger that stamps samples on arrival (USB or serial bursts) gives steps of about 1.024 x the period most of
the time and a short step now and then: the mean step is the period, the median step is not (it is 2.4 % long).
The clock is the least-squares line of time against the *clock index* of each sample,

    t_j = t0_r + T * n_j + e_j,

with one offset ``t0_r`` per contiguous run, one period ``T`` for the whole recording and ``e_j`` the stamping
jitter. The clock index ``n_j`` counts sample periods: it advances by 1 from one sample to the next, by k when
k - 1 samples were dropped (a step near a whole multiple k of the period). Drops are found in two ways: steps
whose length rounds to k >= 2 periods, and -- for bursty stamps where a drop next to a short step leaves a
step of only about one period -- level shifts of one period in the residual of the line (the drop is placed
at the step with the largest excess over its count within the shift). Steps longer than max(1 s, 50 periods)
or far from a whole multiple are gaps: the recording is split there, each run gets its own offset.

:func:`fit_clock` returns a :class:`ClockFit`: rate and its standard uncertainty (the slope's, from the
residual scatter), jitter (residual std, largest residual, largest step), the dropped samples (count and
where) and the gaps.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: a step longer than max(GAP_MIN_S, GAP_PERIODS periods) is a gap (runs are fitted with their own offsets)
GAP_MIN_S = 1.0
GAP_PERIODS = 50
#: a step longer than one period and farther than this (in periods) from a whole multiple is a gap (tested
#: only when the steps scatter less than a quarter of it: with more jitter a whole multiple cannot be told)
WHOLE_MULTIPLE_TOL = 0.35
#: level-shift window (samples) of the drop search in the residual of the line
LEVEL_WINDOW = 400
#: fewest samples on either side of a step for the level-shift test (the record's ends)
EDGE_WINDOW = 20
MAX_PASSES = 8


class ClockError(ValueError):
    """Time stamps from which no clock can be fitted (fewer than two, not increasing, not finite)."""


@dataclass
class ClockFit:
    """The fitted sample clock. Times in seconds; positions are sample numbers of the recording (0-based).

    ``index``: clock index of each sample (int64; across a gap advanced by the rounded gap length, for
    reference only). ``dropped_after`` / ``dropped_count``: samples missing between sample j and j + 1.
    ``gaps``: ``(j, step_s)`` for each split between sample j and j + 1. ``runs``: ``[start, stop)`` per run.
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

    def steps(self) -> np.ndarray:
        """Clock periods from each sample to the next (n - 1,): 1, or k at a drop, the rounded length at a gap."""
        return np.diff(self.index)

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
             "largest_step_s": float(self.largest_step_s), "dropped_samples": int(self.n_dropped),
             "gaps": len(self.gaps), "median_step_rate_hz": float(self.median_step_rate_hz)}
        if self.n_dropped:
            a["dropped_after"] = " ".join(f"{j}x{c}" if c > 1 else str(j)
                                          for j, c in zip(self.dropped_after[:200], self.dropped_count[:200]))
        if self.gaps:
            a["gaps_after"] = " ".join(f"{j}:{d:.6g}s" for j, d in self.gaps[:200])
        return {prefix + k: v for k, v in a.items()}


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


def _level_fix(u, k, excess, runs, window):
    """Add the drops the step lengths miss: level shifts of about one period in the residual ``u`` (periods).

    For each step j the level change = mean(u after j, ``window`` samples) - mean(u up to j); a region where it
    exceeds 1/2 holds round(max) drops, placed at the steps of the largest excess. Returns the number added."""
    added = 0
    for a, b in runs:
        m = b - a
        if m < 2 * EDGE_WINDOW:
            continue
        c = np.concatenate([[0.0], np.cumsum(u[a:b])])
        j = np.arange(EDGE_WINDOW - 1, m - EDGE_WINDOW)  # step j (run-local) with >= EDGE_WINDOW samples each side
        wb = np.minimum(window, j + 1)
        wa = np.minimum(window, m - j - 1)
        before = (c[j + 1] - c[j + 1 - wb]) / wb
        after = (c[j + 1 + wa] - c[j + 1]) / wa
        jump = after - before
        for sign in (1.0, -1.0):
            hot = sign * jump > 0.5
            if not hot.any():
                continue
            edges = np.flatnonzero(np.diff(np.concatenate([[0], hot.astype(np.int8), [0]])))
            for r0, r1 in zip(edges[::2], edges[1::2]):
                steps = j[r0:r1] + a  # global step positions
                count = round(sign * float(jump[r0:r1].max()))
                ex = excess[steps] if sign > 0 else -excess[steps]
                if sign < 0:
                    ok = k[steps] >= 2
                    if not ok.any():
                        continue
                    ex = np.where(ok, ex, -np.inf)
                for s in steps[np.argsort(-ex)[:max(count, 1)]]:
                    k[s] += int(sign)
                    added += 1
    return added


def fit_clock(t, nominal_rate_hz: float | None = None) -> ClockFit:
    """Fit the sample clock to time stamps ``t`` (s, strictly increasing); see the module docstring.

    ``nominal_rate_hz``: optional starting period (1 / rate) for counting steps; default the median step.
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
    period = 1.0 / nominal_rate_hz if nominal_rate_hz else med
    # a first period that counts the steps right: the mean step over steps shorter than 1.5 median steps
    # (bursty stamps: 1.024 and short steps average to the period; drops are left out)
    if nominal_rate_hz is None:
        short = d[d < 1.5 * med]
        period = float(short.mean()) if short.size else med
    k = np.ones(n - 1, dtype=np.int64)
    runs = _runs(np.zeros(n - 1, dtype=bool), n)
    gap_mask = np.zeros(n - 1, dtype=bool)
    for _ in range(MAX_PASSES):
        ratio = d / period
        kk = np.maximum(1, np.rint(ratio)).astype(np.int64)
        normal = ratio[ratio < 1.5]
        spread = 1.4826 * float(np.median(np.abs(normal - np.median(normal)))) if normal.size else 0.0
        gap_now = d > max(GAP_MIN_S, GAP_PERIODS * period)
        if 4.0 * spread < WHOLE_MULTIPLE_TOL:  # steps precise enough to tell a whole multiple from a gap
            gap_now |= (ratio > 1.0 + WHOLE_MULTIPLE_TOL) & (np.abs(ratio - np.rint(ratio)) > WHOLE_MULTIPLE_TOL)
        if not np.array_equal(gap_now, gap_mask):
            gap_mask = gap_now
            runs = _runs(gap_mask, n)
        k = np.where(gap_mask, np.maximum(kk, 1), kk)
        added_total = 0
        for _inner in range(MAX_PASSES):
            idx = np.concatenate([[0], np.cumsum(k)])
            slope, _, res, _ = _pooled_line(t, idx, runs)
            u = res / slope
            excess = np.where(gap_mask, 0.0, ratio - k)
            added = _level_fix(u, k, excess, runs, LEVEL_WINDOW)
            added_total += added
            if not added:
                break
        new_period = slope
        if abs(new_period / period - 1.0) < 1e-12 and not added_total:
            period = new_period
            break
        period = new_period
    idx = np.concatenate([[0], np.cumsum(k)]).astype(np.int64)
    slope, offsets, res, sxx = _pooled_line(t, idx, runs)
    dof = n - 1 - len(runs)
    s2 = float(res @ res) / dof if dof > 0 else 0.0
    slope_std = float(np.sqrt(s2 / sxx)) if sxx > 0 else float("inf")
    rate = 1.0 / slope
    drop = (~gap_mask) & (k > 1)
    in_run = d[~gap_mask]
    return ClockFit(
        rate_hz=rate, rate_std_hz=slope_std / slope ** 2, t0_s=float(offsets[0]), index=idx,
        jitter_std_s=float(np.sqrt(s2)), max_residual_s=float(np.max(np.abs(res))),
        largest_step_s=float(in_run.max()) if in_run.size else float("nan"), n_samples=n,
        dropped_after=np.flatnonzero(drop).astype(np.int64), dropped_count=(k[drop] - 1).astype(np.int64),
        gaps=[(int(j), float(d[j])) for j in np.flatnonzero(gap_mask)], runs=runs,
        median_step_rate_hz=1.0 / med)
