"""Dropouts and stuck samples: runs of rows in which a sensor's output does not move at all.

A logger that stops (or starts late) writes rows of zeros; a sensor that hangs (a bus that returns its last
value) repeats its last row. Either is a run of rows in which every channel of a triad equals the row before
it *exactly* -- zeros being one case of it. Such rows are no measurement: at the end of a record they halve or
double a white-noise estimate (an AHRS log ending with 239 all-zero rows moved its gyro's N by x2), inside
they stand for motion that was never recorded.

Threshold
---------
:data:`MIN_RUN` = 50 identical rows in a row (49 repeats of the first). A real sensor at rest repeats its
previous row by chance: each axis keeps its code with a probability that grows as its noise shrinks below one
code, and all three at once with the product of the three. The coarsest recording at hand, the ADIS16405's
accelerometer at rest (16-bit output, 18 to 29 distinct codes per axis over 10^6 samples), repeats a whole row
on one sample in forty; the most repetitive triad of the shared recordings (a Bosch-class gyro, imucal) on one
in twenty; the longest run of identical rows in any of them is 5. Even a triad that repeats its row on
every second sample (each axis keeping its code 80 % of the time: noise well below one code) makes a run of 50
with probability 0.5^49 = 1.8e-15 per sample: not once in 10^14 samples, thirty thousand years at 100 Hz. One
axis alone repeating for many rows is normal for a quiet, coarse sensor and is not looked at.

This reasoning takes the rows as independent draws. A sensor whose output is filtered far below its output
rate (a 5 Hz filter read at 1 kHz) holds its codes for tens of rows by design; for it the import setting
``dropout_min_rows`` raises the threshold (0 turns the check off).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.core.clock import window_fix

#: fewest identical rows of a triad in a row that are a dropout or a stuck sensor (see the module docstring)
MIN_RUN = 50


@dataclass(frozen=True)
class Run:
    """Rows ``start .. stop - 1`` of ``sensor`` all equal (``zero``: all channels 0)."""

    sensor: str
    start: int
    stop: int
    zero: bool

    @property
    def rows(self) -> int:
        return self.stop - self.start

    def describe(self) -> str:
        what = "all-zero rows" if self.zero else "identical rows (the sensor's output stuck)"
        return f"{self.sensor}: samples {self.start}..{self.stop - 1}, {self.rows} {what}"


def find_runs(triads: dict, min_run: int = MIN_RUN, offset: int = 0) -> list[Run]:
    """The runs of at least ``min_run`` identical rows in each triad (``{name: (n, 3) array or None}``), sorted
    by their first row; ``offset`` is added to the row numbers. ``min_run`` 0 finds nothing."""
    out = []
    if not min_run:
        return out
    for name, x in triads.items():
        if x is None or len(x) < min_run:
            continue
        tracker = RunTracker(name, min_run)   # the whole array as one chunk: one implementation of a run
        tracker.add(x)
        out += [Run(r.sensor, r.start + offset, r.stop + offset, r.zero) for r in tracker.finish()]
    return sorted(out, key=lambda r: (r.start, r.sensor))


def ends(runs: list[Run], lo: int, hi: int) -> tuple[int, int]:
    """The rows ``[lo, hi)`` left of ``[lo, hi)`` when the runs that touch its first or its last row (and runs
    that touch those, in turn) are cut off."""
    changed = True
    while changed:
        changed = False
        for r in runs:
            if r.start <= lo < r.stop:
                lo, changed = r.stop, True
            if r.start < hi <= r.stop:
                hi, changed = r.start, True
    return lo, max(lo, hi)


def inside(runs: list[Run], lo: int, hi: int) -> list[Run]:
    """The runs that lie within ``[lo, hi)`` (not cut off by :func:`ends`)."""
    return [r for r in runs if r.start >= lo and r.stop <= hi]


def refusal(runs: list[Run], lo: int, hi: int, t_rel, min_run: int) -> tuple[str, str, str]:
    """``(sensor, problem, fix)`` of a refusal for ``runs`` that lie within rows ``[lo, hi)``: the first by its
    rows and times, and the windows of the rows around them (``start_s`` / ``stop_s``, seconds from the first
    sample: ``t_rel`` holds each row's) that import without them."""
    def edge(i):   # seconds of the boundary before row i
        if 0 < i < len(t_rel):
            return float(t_rel[i - 1] + 0.5 * (t_rel[i] - t_rel[i - 1]))
        return 0.0 if i == 0 else float(t_rel[-1] + 0.5 * (t_rel[-1] - t_rel[-2]))

    parts, a = [], lo
    for r in runs:
        if r.start - a >= 2:
            parts.append((edge(a), edge(r.start)))
        a = max(a, r.stop)
    if hi - a >= 2:
        parts.append((edge(a), edge(hi)))
    first = runs[0]
    problem = (f"{first.describe()} (t = {t_rel[first.start]:.6g} to {t_rel[first.stop - 1]:.6g} s from the first "
               f"sample): a dropout or a stuck sensor; {len(runs)} run(s) of {min_run} or more identical rows")
    fix = window_fix(parts, "the runs") if parts else "record again: no part of the file moves"
    return first.sensor, problem, fix + (f"; or, for a sensor filtered far below its output rate, raise the import "
                                         f"setting dropout_min_rows (now {min_run}; 0 turns this check off)")


class RunTracker:
    """:func:`find_runs` for one triad read in consecutive chunks (a long recording checked chunk by chunk)."""

    def __init__(self, name: str, min_run: int = MIN_RUN):
        self.name, self.min_run = name, min_run
        self.last = None     # the last row seen
        self.start = 0       # first row of the run still open at the end of what was seen
        self.value = None    # its value
        self.n = 0
        self.runs: list[Run] = []

    def add(self, x) -> None:
        x = np.asarray(x)
        if not len(x) or not self.min_run:
            return
        prev = x[:1] if self.last is None else self.last[None, :]
        same = np.all(x == np.concatenate([prev, x[:-1]]), axis=1)
        if self.last is None:
            same[0] = False
        starts = np.flatnonzero(~same)   # rows that differ from the row before: each starts a run
        if starts.size:
            self._close(self.n + int(starts[0]))
            bounds = np.append(starts, len(x))
            for i in np.flatnonzero(np.diff(bounds)[:-1] >= self.min_run):
                self.runs.append(Run(self.name, self.n + int(bounds[i]), self.n + int(bounds[i + 1]),
                                     not bool(np.any(x[bounds[i]]))))
            self.start, self.value = self.n + int(starts[-1]), x[starts[-1]].copy()
        self.n += len(x)
        self.last = x[-1].copy()

    def _close(self, stop: int) -> None:
        if self.value is not None and stop - self.start >= self.min_run:
            self.runs.append(Run(self.name, self.start, stop, not bool(np.any(self.value))))

    def finish(self) -> list[Run]:
        """The runs found, the one open at the end included."""
        self._close(self.n)
        self.value = None
        return self.runs
