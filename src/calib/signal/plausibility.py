"""Physical plausibility of a recording before any fit, and of a result before it is reported as a success.

The recording format (:mod:`calib.io.recording`) checks structure: units declared, time increasing without
gaps and consistent with ``sample_rate_hz``, no NaN or masked sample. What it cannot check is whether the
numbers are what the declared units say. Here, one pass over the samples:

* **single absurd samples**: a specific force above :data:`ABSURD_ACCEL_G` g or a rate above
  :data:`ABSURD_GYRO_DEG_S` deg/s in the declared units, named by sample index; for accelerometer counts (no
  physical scale) a sample above :data:`ABSURD_ACCEL_G` times the recording's own static norm (1 g in counts);
* **static magnitudes**, on the quiet blocks of :data:`BLOCK_S` seconds (accel and gyro scatter both at most
  twice their median over the recording): the accelerometer norm against local gravity (ratio within
  :data:`ACCEL_NORM_RATIO`) and the gyro magnitude against the Earth's rate (at most
  :data:`GYRO_STATIC_MAX_DEG_S` deg/s; and not far below 15.04 deg/h when the sensor is quiet enough to see
  it). A failure names the likely mistake: m s-2 declared as g or the reverse, rad/s declared as deg/s or
  the reverse, rates declared as increments or the reverse, raw counts declared as a physical unit, or
  physical data declared as counts.

A recorded triad whose every sample is the same value is refused first as what it is, a placeholder and not a
measurement (a partial record leaves the absent triad out instead: ``absent_sensors``); the triad a partial record
does not hold is not judged. Count recordings carry no physical scale, so only the last mistake is looked for
there. The result checks
(:func:`check_triad_result`, :func:`check_finite_result`) apply the same idea to calibrations and navigation
solutions: scale factors within :data:`SCALE_RANGE` for physical units (a count triad: its three scale
factors within a factor :data:`SCALE_SPREAD_MAX` of each other), accelerometer bias at most
:data:`ACCEL_BIAS_MAX_M_S2` m s-2 (0.2 g), gyro bias at most :data:`GYRO_BIAS_MAX_DEG_S` deg/s (consumer
MEMS gyros, e.g. the MPU-9150 recordings of ``config/import``, show up to 1.3 deg/s), every value finite.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import netCDF4
import numpy as np

from calib.core import earth
from calib.core.errors import InputError, ResultCheckError
from calib.io import recording
from calib.io.netcdf import conventions, float_values, index_values, string_values

ABSURD_ACCEL_G = 1000.0
ABSURD_GYRO_DEG_S = 1.0e4
BLOCK_S = 1.0
ACCEL_NORM_RATIO = (0.5, 2.0)
GYRO_STATIC_MAX_DEG_S = 10.0
EARTH_RATE_DEG_H = earth.OMEGA_IE / earth.DEG_PER_H   # 15.041 deg/h, the magnitude any static gyro triad sees
#: a static gyro magnitude below this fraction of the Earth's rate is refused when the sensor resolves it
EARTH_RATE_FLOOR = 0.05
#: ... i.e. when the noise of a block mean is below this fraction of the Earth's rate
EARTH_RATE_RESOLVED = 0.1
#: count data whose static norm matches local gravity in m s-2 or in g within this are physical data
PHYSICAL_MATCH = 0.03
SCALE_RANGE = (0.5, 2.0)
SCALE_SPREAD_MAX = 2.0
ACCEL_BIAS_MAX_M_S2 = 2.0
GYRO_BIAS_MAX_DEG_S = 10.0


@dataclass
class Plausibility:
    """What :func:`check_recording` measured (declared units) and any refusals turned into warnings."""

    path: str
    n_quiet_blocks: int = 0
    accel_static_norm: float | None = None
    accel_expected: float | None = None
    accel_units: str = ""
    gyro_static_deg_h: float | None = None
    table_angle_ratio: float | None = None      # gyro rotation / table angle over the rotation segments
    warnings: list = field(default_factory=list)

    def describe(self) -> str:
        parts = []
        if self.accel_static_norm is not None:
            parts.append(f"static accel norm {self.accel_static_norm:.6g} {self.accel_units} (local gravity "
                         f"{self.accel_expected:.6g})")
        if self.gyro_static_deg_h is not None:
            parts.append(f"static gyro magnitude {self.gyro_static_deg_h:.4g} deg/h (Earth rate "
                         f"{EARTH_RATE_DEG_H:.2f} deg/h)")
        if not parts:
            return "no physical magnitude check (count units or no quiet blocks)"
        return "; ".join(parts) + f" over {self.n_quiet_blocks} quiet {BLOCK_S:g} s blocks"


def _per_sample_factor(h, sensor):
    """Factor from a raw sample to an SI rate (m s-2 or rad s-1); None for counts."""
    units = h.accel_units if sensor == "accel" else h.gyro_units
    kind = h.accel_kind if sensor == "accel" else h.gyro_kind
    f = recording.unit_factor(units)
    if f is None:
        return None
    return f * (h.sample_rate_hz if kind == "increment" else 1.0)


def _raw_rate_factor(h, sensor):
    """Factor from a raw sample to a raw rate (per second): the sample rate for increments, else 1."""
    kind = h.accel_kind if sensor == "accel" else h.gyro_kind
    return h.sample_rate_hz if kind == "increment" else 1.0


class _Blocks:
    """Means and scatter of the consecutive blocks of ``w`` samples of the whole record (samples ``[0, w)``,
    ``[w, 2w)``, ...), accumulated chunk by chunk whatever the chunks' lengths: a chunk's samples after its last
    whole block start the next chunk's first block; the record's last incomplete block is left out."""

    def __init__(self, w):
        self.w = w
        self.mean, self.sd = [], []
        self.rest = None   # (3, r < w): the samples carried to the next chunk

    def add(self, t):
        """``t``: one chunk, axes first (3, n), contiguous; its samples inside the blocks completed here are
        overwritten (the block means are subtracted), those after them (``t[:, end:]``) are not. Returns ``(ss,
        end)``: the largest sum of squared magnitudes ``sum |x|^2`` over any block completed here (-inf: none; NaN
        when a block holds a NaN), and the index from which this chunk's samples are in no block completed here
        (carried to the next chunk, or the record's tail)."""
        w, off, ss = self.w, 0, -np.inf
        if self.rest is not None:   # the block begun in the previous chunk
            need = w - self.rest.shape[1]
            if t.shape[1] < need:
                self.rest = np.concatenate([self.rest, t], axis=1)
                return ss, 0
            first = np.concatenate([self.rest, t[:, :need]], axis=1)
            self.rest, off = None, need
            ss = self._blocks([first[a].reshape(1, w) for a in range(3)])
        nb = (t.shape[1] - off) // w
        end = off + nb * w
        if end < t.shape[1]:
            self.rest = t[:, end:].copy()
        if nb:   # per axis, a view (nb, w) of the chunk's row: no copy, sums along memory
            ss = float(np.maximum(ss, self._blocks([t[a, off:end].reshape(nb, w) for a in range(3)])))   # NaN stays
        return ss, end

    def _blocks(self, rows):
        m = np.stack([r.sum(axis=1) for r in rows]) / self.w          # (3, nb)
        var = np.empty_like(m)
        for a, r in enumerate(rows):
            r -= m[a][:, None]
            var[a] = np.einsum("ij,ij->i", r, r) / self.w
        self.mean.append(m.T)
        v = var.sum(axis=0)
        self.sd.append(np.sqrt(v))   # the block's scatter: the norm of its per-axis std
        # sum over the block of |x|^2 = w (|mean|^2 + scatter^2): bounds every sample's squared magnitude
        return float(np.max(self.w * (np.einsum("ij,ij->j", m, m) + v)))

    def arrays(self):
        if not self.mean:
            return np.zeros((0, 3)), np.zeros(0)
        return np.concatenate(self.mean), np.concatenate(self.sd)


def _axes_first(x, factor) -> np.ndarray:
    """``x * factor`` of one chunk (n, 3), axes first: (3, n), contiguous (the sums over samples then run along
    memory: ~8x faster than over a strided axis of three)."""
    t = np.empty((3, len(x)))
    np.multiply(x.T, factor, out=t)
    return t


def _squared_magnitude(t) -> np.ndarray:
    """Per sample, the squared norm of an axes-first chunk (3, n)."""
    return np.einsum("ij,ij->j", t, t)


class RecordingCheck:
    """The plausibility check of one recording, fed its samples chunk by chunk (:meth:`add`, in order, each sample
    once) and judged at the end (:meth:`finish`): so that the pass that validates the samples
    (:func:`calib.io.recording.validate`) can feed it, and the file is read once. :func:`check_recording` reads it
    itself."""

    def __init__(self, path, header, *, force: bool = False):
        h = self.h = header
        self.path, self.force = path, force
        self.fa, self.fg = _per_sample_factor(h, "accel"), _per_sample_factor(h, "gyro")
        self.ra = _raw_rate_factor(h, "accel")
        self.w = max(8, int(round(h.sample_rate_hz * BLOCK_S)))
        self.blocks_a, self.blocks_g = _Blocks(self.w), _Blocks(self.w)
        self.absurd = {"accel": _Absurd(ABSURD_ACCEL_G, "g", h.accel_units),
                       "gyro": _Absurd(ABSURD_GYRO_DEG_S, "deg/s", h.gyro_units)}
        self.integer_accel = True
        #: accelerometer counts: a bound of every sample's squared magnitude (raw rate), judged against the static norm
        self.count_bound = -np.inf
        self.n_seen = 0
        #: per triad held, its first sample and whether every sample so far equals it (a constant placeholder)
        self.first = {s: None for s in h.sensors}
        self.constant = {s: True for s in h.sensors}

    def add(self, i0, acc, gyr) -> None:
        """Samples ``i0 ..`` of the raw accel and gyro (n, 3) in the declared units (None: a triad the partial
        record does not hold)."""
        with np.errstate(over="ignore", invalid="ignore"):   # overflowing samples are absurd samples, judged later
            for sensor, x in (("accel", acc), ("gyro", gyr)):
                if x is not None and len(x):
                    if self.first[sensor] is None:
                        self.first[sensor] = np.array(x[0], dtype=float)
                    self.constant[sensor] = self.constant[sensor] and bool(np.all(x == self.first[sensor]))
            a = None if acc is None else _axes_first(acc, self.fa if self.fa is not None else self.ra)
            g = None if gyr is None else _axes_first(gyr, self.fg if self.fg is not None else 1.0)
            self.integer_accel = self.integer_accel and (acc is None or bool(np.all(acc == np.round(acc))))
            for x, t, blocks, factor, sensor, per_unit in ((acc, a, self.blocks_a, self.fa, "accel",
                                                             earth.STANDARD_GRAVITY),
                                                            (gyr, g, self.blocks_g, self.fg, "gyro", earth.DEG)):
                if x is None:
                    continue
                ss, end = blocks.add(t)   # (t's samples in the blocks completed now are overwritten)
                if factor is None and sensor == "accel":   # the samples of blocks completed later bound it then
                    self.count_bound = max(self.count_bound, ss)
                if factor is not None:
                    self.absurd[sensor].add_bounded(ss, t[:, end:], per_unit, i0, end,
                                                    lambda x=x, factor=factor: _axes_first(x, factor))
        self.n_seen += len(acc if acc is not None else gyr)

    def finish(self) -> Plausibility:
        """The judgement on every sample added (:func:`check_recording`)."""
        return _judge(self)


def check_recording(path, header=None, *, force: bool = False) -> Plausibility:
    """Refuse (:class:`calib.core.errors.InputError`, exit 2) a recording whose samples are implausible for
    its declared units; ``force``: record the refusals in ``warnings`` instead. One pass over the samples; the
    static magnitudes are judged first, so that a unit mistake is named as such rather than as spikes."""
    h = header or recording.read_header(path)
    check = RecordingCheck(path, h, force=force)
    for i0, acc, gyr in recording.iter_raw_chunks(path, h):
        check.add(i0, acc, gyr)
    return check.finish()


def _judge(c: RecordingCheck) -> Plausibility:
    path, h, fa, fg, ra, w, absurd = c.path, c.h, c.fa, c.fg, c.ra, c.w, c.absurd
    res = Plausibility(str(path), accel_units=h.accel_units)

    def refuse(field_, message, fix):
        if not c.force:
            raise InputError(message, file=path, field=field_, fix=fix)
        res.warnings.append(f"{path}: {field_}: {message}")

    blocks_a, blocks_g, integer_accel = c.blocks_a, c.blocks_g, c.integer_accel
    # a recorded triad whose samples are all equal is a placeholder (a sensor's noise or quantization always moves
    # them; a noise-free synthetic session may be constant): named before any unit diagnosis
    recorded = str(h.attrs.get("source", "")) == "recorded"
    placeholder = set()
    for sensor, first in c.first.items():
        if recorded and first is not None and c.constant[sensor] and c.n_seen > 1:
            placeholder.add(sensor)
            refuse(sensor, f"every one of the {c.n_seen} samples is ({', '.join(f'{v:g}' for v in first)}): a constant "
                   "placeholder, not a measurement", f"if the logger recorded no {sensor}, leave '{sensor}' out of the "
                   "import settings (a partial record, declared absent: calib validate, noise and, with the "
                   "accelerometer, fieldcal work on it); else check the logger's channel")
            fa = None if sensor == "accel" else fa   # nothing physical to judge in it
            fg = None if sensor == "gyro" else fg
    am, asd = blocks_a.arrays()
    gm, gsd = blocks_g.arrays()
    # a partial record: the absent triad's blocks stand in as quiet (it adds nothing to the choice of blocks)
    if "accel" not in h.sensors:
        am, asd = np.zeros_like(gm), np.zeros_like(gsd)
    if "gyro" not in h.sensors:
        gm, gsd = np.zeros_like(am), np.zeros_like(asd)
    quiet = np.zeros(len(am), dtype=bool)
    if len(am):
        ok = np.isfinite(asd) & np.isfinite(gsd) & np.all(np.isfinite(am), axis=1) & np.all(np.isfinite(gm), axis=1)
        if ok.any():
            quiet = (ok & (asd <= max(2.0 * float(np.median(asd[ok])), 1e-300))
                     & (gsd <= max(2.0 * float(np.median(gsd[ok])), 1e-300)))
    else:
        res.warnings.append(f"{path}: shorter than one {BLOCK_S:g} s block: magnitudes not checked")
    res.n_quiet_blocks = int(quiet.sum())
    if quiet.any():
        a_norm = float(np.median(np.linalg.norm(am[quiet], axis=1)))
        if fa is not None:
            _accel_physical(refuse, res, h, a_norm, fa)
        elif not integer_accel and "accel" in h.sensors and "accel" not in placeholder:
            _accel_counts(refuse, h, a_norm, ra)
        if fg is not None:
            mags = np.linalg.norm(gm[quiet], axis=1)
            g_static = float(np.percentile(mags, 10))
            noise = float(np.median(gsd[quiet])) / math.sqrt(w)
            res.gyro_static_deg_h = g_static / earth.DEG_PER_H
            _gyro_physical(refuse, h, g_static, noise)
    for sensor, ab in absurd.items():
        if sensor in h.sensors:
            ab.judge(refuse, sensor)
    if fa is None and "accel" in h.sensors and quiet.any():
        _count_spikes(refuse, c, a_norm)   # the static norm judged above
    if fg is not None:
        _table_rotation_check(refuse, res, path, h, fg)
    return res


#: a gyro's integrated rotation over a rotation segment within this factor of the table's recorded angle passes
TABLE_ANGLE_RATIO = (0.8, 1.25)


def _table_rotation_check(refuse, res, path, h, fg):
    """Where the recording has a turntable record (rotation segments with ``table_angle``): the gyro's integrated
    rotation over each rotation segment (magnitude of the integral of the rate vector, in the declared units and
    clock) against the angle the table turned. A common ratio near 180/pi, pi/180, 3600, 2 or 1/2 names the
    likely mistake (exit 2 before any fit)."""
    try:
        with netCDF4.Dataset(path, "r") as nc:   # read as xarray decodes them, without importing it
            var = nc.variables
            if not {"table_angle", "segment_index", "segment_kind"} <= set(var):
                return
            kinds = string_values(var["segment_kind"])
            if "rotation" not in kinds:
                return
            seg = index_values(var["segment_index"])
            ang = float_values(var["table_angle"])
            gyr = float_values(var["gyro"])
    except (OSError, KeyError, ValueError):
        return
    dt = 1.0 / h.sample_rate_hz
    ratios = []
    for s, kind in enumerate(kinds):
        if kind != "rotation":
            continue
        idx = np.flatnonzero(seg == s)
        if idx.size < 10:
            continue
        a = np.unwrap(np.radians(ang[idx]))
        turned = abs(a[-1] - a[0])
        if turned < math.radians(30.0):
            continue
        turned += turned / (idx.size - 1)                       # the last sample's own interval
        rot = float(np.linalg.norm(np.sum(gyr[idx] * fg, axis=0) * dt))   # rad
        ratios.append(rot / turned)
    if not ratios:
        return
    r = float(np.median(ratios))
    res.table_angle_ratio = r
    if TABLE_ANGLE_RATIO[0] <= r <= TABLE_ANGLE_RATIO[1]:
        return
    likely = _likely(r, [(math.degrees(1.0), "data in degrees declared as radians (gyro.units)"),
                         (math.radians(1.0), "data in radians declared as degrees (gyro.units)"),
                         (3600.0, "data in deg/s declared as 'deg h-1' (gyro.units)"),
                         (1.0 / 3600.0, "data in deg/h declared as 'deg s-1' (gyro.units)"),
                         (2.0, "a declared sample_rate_hz half the true one"),
                         (0.5, "a declared sample_rate_hz twice the true one")])
    refuse("gyro", f"the gyro's integrated rotation is {r:.4g} times the angle the table turned (median over "
           f"{len(ratios)} rotation segments, declared {h.gyro_units!r} at {h.sample_rate_hz:g} Hz)"
           + (f": likely {likely}" if likely else ""),
           "declare the gyro's real units and the sample rate in the import settings (gyro.units, "
           "sample_rate_hz), or pass --force")


class _Absurd:
    """First and number of samples whose magnitude exceeds ``limit`` (in ``unit``)."""

    def __init__(self, limit, unit, declared):
        self.limit, self.unit, self.declared = limit, unit, declared
        self.first, self.value, self.count = None, None, 0

    def add(self, m2, per_unit, i0):
        """Samples ``i0 ..`` of squared magnitude ``m2``: magnitude ``sqrt(m2) / per_unit`` in ``unit``."""
        if m2.size == 0 or m2.max() <= (self.limit * per_unit) ** 2 * (1.0 - 1e-9):
            return   # every sample well inside the limit (a NaN fails the test: judged sample by sample below)
        mag = np.sqrt(m2) / per_unit
        bad = ~(mag <= self.limit)
        if bad.any():
            if self.first is None:
                i = int(np.argmax(bad))
                self.first, self.value = i0 + i, float(mag[i])
            self.count += int(bad.sum())

    def add_bounded(self, ss, tail, per_unit, i0, end, chunk):
        """:meth:`add` for one chunk of samples ``i0 ..`` from the block sums of :meth:`_Blocks.add`: ``ss``, the
        largest sum of squared magnitudes over the blocks completed with the chunk, bounds the squared magnitude
        of every sample in them (each is one of the sum's non-negative terms); the samples after them (``tail``,
        axes first, from index ``end`` of the chunk) are tested one by one. Only when the bound is above the limit
        (or NaN) are the chunk's samples tested one by one (``chunk()``: the chunk axes first again, scaled): a
        clean chunk costs no pass over its samples. (The samples of a completed block that came from the previous
        chunk were tested there, as that chunk's tail.)"""
        if not ss <= (self.limit * per_unit) ** 2 * (1.0 - 1e-9):
            self.add(_squared_magnitude(chunk()), per_unit, i0)   # the samples one by one, named by index
            return
        self.add(_squared_magnitude(tail), per_unit, i0 + end)

    def judge(self, refuse, sensor):
        if self.first is not None:
            refuse(sensor, f"sample {self.first}: magnitude {self.value:.4g} {self.unit} exceeds {self.limit:g} "
                   f"{self.unit} ({self.count} such sample(s)): a spike, or not {self.declared!r}",
                   f"remove the spike at the source, or declare the right units for {sensor}")


def _count_spikes(refuse, c: RecordingCheck, a_norm: float) -> None:
    """Accelerometer counts carry no physical scale, but their static norm is 1 g in counts: a sample above
    :data:`ABSURD_ACCEL_G` times it is a spike, not a reading, refused by index before any fit. The block sums
    bound every sample (the record's last incomplete block is looked at here); only when the bound is above the
    limit is the file read again to name the first such sample."""
    h, limit = c.h, ABSURD_ACCEL_G * a_norm
    rest = c.blocks_a.rest
    bound = max(c.count_bound, float(_squared_magnitude(rest).max()) if rest is not None and rest.size else -np.inf)
    if not (limit > 0 and bound > limit ** 2):
        return
    first, value, count = None, None, 0
    for i0, acc, _ in recording.iter_raw_chunks(c.path, h):
        with np.errstate(over="ignore", invalid="ignore"):
            mag = np.sqrt(_squared_magnitude(_axes_first(acc, c.ra)))
        bad = ~(mag <= limit)
        if bad.any():
            if first is None:
                i = int(np.argmax(bad))
                first, value = i0 + i, float(mag[i])
            count += int(bad.sum())
    if first is not None:
        unit = "count s-1" if h.accel_kind == "increment" else "count"
        refuse("accel", f"sample {first}: magnitude {value:.4g} {unit} is more than {ABSURD_ACCEL_G:g} times the static "
               f"norm of the recording ({a_norm:.4g} {unit}, 1 g) ({count} such sample(s)): a spike, not a reading",
               "remove or repair the sample at the source and import the recording again")


def _likely(ratio, candidates):
    """The candidate mistake whose factor is nearest ``ratio`` (within 30 %), or None."""
    best = min(candidates, key=lambda c: abs(math.log(ratio / c[0])), default=None)
    if best is not None and abs(math.log(ratio / best[0])) < math.log(1.3):
        return best[1]
    return None


def _accel_physical(refuse, res, h, a_norm_si, fa):
    g = h.gravity_m_s2
    ratio = a_norm_si / g
    units, kind, fs = h.accel_units, h.accel_kind, h.sample_rate_hz
    res.accel_static_norm = a_norm_si / fa   # in the declared units (per sample for increments)
    res.accel_expected = g / fa
    lo, hi = ACCEL_NORM_RATIO
    if lo <= ratio <= hi:
        return
    cands = []
    if units == "g":
        cands.append((earth.STANDARD_GRAVITY, "data in m s-2 declared as 'g'"))
    if units in ("m s-2",):
        cands.append((1.0 / earth.STANDARD_GRAVITY, "data in g declared as 'm s-2'"))
    if kind == "increment":
        cands.append((fs, "rates (m s-2) declared as sample_kind 'increment'"))
    else:
        cands.append((1.0 / fs, "increments (m s-1 per sample) declared as sample_kind 'rate'"))
    mistake = _likely(ratio, cands) or ("raw counts declared as a physical unit" if ratio > hi else
                                        "a scale or unit mistake")
    refuse("accel", f"static accelerometer norm {res.accel_static_norm:.5g} {units} but local gravity is "
           f"{res.accel_expected:.5g} {units} (ratio {ratio:.4g}, allowed {lo:g}..{hi:g}): likely {mistake}",
           "declare the accelerometer's real units and sample_kind in the import settings (accel.units, "
           "accel.sample_kind; 'count' for raw counts)")


def _accel_counts(refuse, h, a_norm_raw_rate, ra):
    g = h.gravity_m_s2
    per_sample = a_norm_raw_rate / ra
    for value, what in ((a_norm_raw_rate, "rate"), (per_sample, "per sample")):
        for ref, unit in ((g, "m s-2"), (g / earth.STANDARD_GRAVITY, "g")):
            if abs(value / ref - 1.0) < PHYSICAL_MATCH:
                refuse("accel", f"declared 'count' but the static norm ({what}) is {value:.5g}, local gravity in "
                       f"{unit}, and the samples are not integers: likely physical data ({unit}) declared as "
                       "counts", f"declare accel.units: {unit} in the import settings")
                return


def _gyro_physical(refuse, h, g_static, noise):
    deg_s = g_static / earth.DEG
    units, kind = h.gyro_units, h.gyro_kind
    if deg_s > GYRO_STATIC_MAX_DEG_S:
        possible = []
        if units in ("rad s-1", "rad"):
            possible.append("data in degrees declared as radians")
        if units == "deg s-1":
            possible.append("data in deg/h declared as 'deg s-1'")
        if kind == "increment":
            possible.append("rates declared as sample_kind 'increment'")
        possible.append("raw counts declared as a physical unit")
        refuse("gyro", f"static gyro magnitude {deg_s:.4g} deg/s (declared {units!r}) on the quietest blocks; no "
               f"gyro at rest reads more than {GYRO_STATIC_MAX_DEG_S:g} deg/s: likely {' or '.join(possible)}",
               "declare the gyro's real units and sample_kind in the import settings (gyro.units, "
               "gyro.sample_kind; 'count' for raw counts), or pass --force for a recording without rests")
        return
    earth_rate = earth.OMEGA_IE
    if g_static < EARTH_RATE_FLOOR * earth_rate and noise < EARTH_RATE_RESOLVED * earth_rate:
        mistake = ("data in rad/s declared as degrees" if units in ("deg s-1", "deg") else
                   "data in rad/s declared as 'deg h-1'" if units == "deg h-1" else
                   "increments declared as sample_kind 'rate'" if kind == "rate" else "a dead or clipped gyro")
        refuse("gyro", f"static gyro magnitude {g_static / earth.DEG_PER_H:.3g} deg/h is far below the Earth's rate "
               f"({EARTH_RATE_DEG_H:.2f} deg/h) that a gyro this quiet (block noise "
               f"{noise / earth.DEG_PER_H:.3g} deg/h) sees at rest: likely {mistake}",
               "declare the gyro's real units and sample_kind in the import settings (gyro.units, gyro.sample_kind)")


# =========================================================================== results


def check_triad_result(sensor: str, scale, bias_si, *, counts: bool, scale_names=None) -> list[str]:
    """Problems of one calibrated triad: ``scale`` (3) input per output unit for physical units, any positive
    scale for counts; ``bias_si`` (3) in m s-2 or rad s-1 (None: not checked, e.g. an ADC offset in counts).
    Returns the problems as sentences (empty: plausible)."""
    scale = np.asarray(scale, dtype=float)
    names = scale_names or ("x", "y", "z")
    out = []
    if not np.all(np.isfinite(scale)):
        out.append(f"{sensor} scale factors not finite ({scale.tolist()})")
    elif counts:
        a = np.abs(scale)
        if a.min() <= 0 or a.max() / a.min() > SCALE_SPREAD_MAX:
            out.append(f"{sensor} scale factors {', '.join(f'{v:.5g}' for v in scale)} differ by more than a factor "
                       f"{SCALE_SPREAD_MAX:g} between axes")
    else:
        lo, hi = SCALE_RANGE
        for n, v in zip(names, scale):
            if not lo <= abs(v) <= hi:
                out.append(f"{sensor} scale factor {n} = {v:.5g} outside [{lo:g}, {hi:g}] for physical units")
    if bias_si is not None:
        b = np.asarray(bias_si, dtype=float)
        if sensor == "accel":
            limit, unit, conv = ACCEL_BIAS_MAX_M_S2, "m s-2", 1.0
        else:
            limit, unit, conv = GYRO_BIAS_MAX_DEG_S, "deg/s", 1.0 / earth.DEG
        if not np.all(np.isfinite(b)):
            out.append(f"{sensor} biases not finite ({b.tolist()})")
        elif np.abs(b * conv).max() > limit:
            out.append(f"{sensor} bias {np.abs(b * conv).max():.4g} {unit} above {limit:g} {unit}")
    return out


def raise_result_problems(problems, file, fix, what="result"):
    """:class:`calib.core.errors.ResultCheckError` (exit 3) listing ``problems``, if any."""
    if problems:
        raise ResultCheckError(f"{what} implausible: " + "; ".join(problems), file=file, fix=fix)


def check_finite_result(ds, file, fix, time_name="time"):
    """:class:`calib.core.errors.ResultCheckError` (exit 3) when a data variable of ``ds`` holds NaN or Inf,
    naming the first variable and the time of its first bad value."""
    for name, var in ds.data_vars.items():
        v = np.asarray(var.values)
        if v.dtype.kind not in "fc" or np.all(np.isfinite(v)):
            continue
        where = ""
        if time_name in var.dims:
            bad = ~np.isfinite(v)
            ax = var.dims.index(time_name)
            idx = int(np.argmax(np.moveaxis(bad, ax, 0).reshape(bad.shape[ax], -1).any(axis=1)))
            where = f" from {time_name} = {float(ds[time_name].values[idx]):.6g}"
        raise ResultCheckError(f"non-finite values in '{name}'{where}", file=file, fix=fix)


def check_calibration_file(path) -> dict:
    """A ``default_calibration.nc`` of the calibrate stage as input (``calib navigate --calibration``): the
    paper vectors ``accel`` and ``gyro`` (12 finite parameters each on ``parameter``). A recording, a field
    calibration or any other file is refused (:class:`calib.core.errors.InputError`). Returns the vectors."""
    fix = "give the default_calibration.nc written by 'calib calibrate --out DIR'"
    import xarray as xr

    try:
        with xr.open_dataset(path, engine="netcdf4") as d:
            kind = ("a recording" if conventions(d.attrs) == recording.CONVENTIONS else
                    "a field calibration ('calib fieldcal --out')" if "value" in d and "static_intervals" in d else
                    None)
            vecs = {s: np.asarray(d[s].values) for s in ("accel", "gyro") if s in d and d[s].dims == ("parameter",)}
    except Exception as exc:  # noqa: BLE001 - whatever the netCDF library raises, it is not a calibration file
        raise InputError(f"not a netCDF calibration file ({type(exc).__name__})", file=path, fix=fix) from None
    if kind or set(vecs) != {"accel", "gyro"}:
        raise InputError(f"is {kind or 'not a calibration of the calibrate stage'} (needs accel(parameter) and "
                         "gyro(parameter))", file=path, fix=fix)
    for s, v in vecs.items():
        if v.shape != (12,) or not np.all(np.isfinite(v)):
            raise InputError(f"'{s}' needs 12 finite parameters (K, E, b), has shape {v.shape}"
                             f"{'' if np.all(np.isfinite(v)) else ' with NaN/Inf'}", file=path, field=s, fix=fix)
    return vecs


def check_calibration_result(nc_path, json_path=None) -> None:
    """The default calibration of the calibrate stage (``K E b`` per triad, inputs in g and deg/h): the biases
    ``b / K`` against the limits, the scale factors' spread between axes (their unit is output per g or per
    deg/h, whatever the recording's units), and no parameter pinned on its search bound (``on_bound`` of
    ``default_calibration.json``: the optimum lies outside Liu 2021's Tables 1/3).
    :class:`calib.core.errors.ResultCheckError` (exit 3) if implausible."""
    import xarray as xr

    with xr.open_dataset(nc_path, engine="netcdf4") as d:
        vecs = {s: np.asarray(d[s].values, dtype=float) for s in ("accel", "gyro") if s in d}
    problems = []
    for sensor, v in vecs.items():
        K, b = v[0:3], v[9:12]
        with np.errstate(divide="ignore", invalid="ignore"):
            bias = b / K * (earth.STANDARD_GRAVITY if sensor == "accel" else earth.DEG_PER_H)
        problems += check_triad_result(sensor, K, bias, counts=True)
    json_path = Path(nc_path).with_suffix(".json") if json_path is None else Path(json_path)
    if json_path.exists():
        summary = json.loads(json_path.read_text())
        for sensor in ("accel", "gyro"):
            hits = (summary.get(sensor) or {}).get("on_bound") or []
            if hits:
                problems.append(f"{sensor} parameter(s) {', '.join(hits)} on the search bounds of Liu 2021 Tables 1/3 "
                                "(the optimum lies outside them)")
    raise_result_problems(problems, nc_path, "check the recording's units and segment table (the bounds fit the Liu "
                          "2021 unit); the fit is set by calibration.default_method, calibration.NP and "
                          "calibration.EG in --config", "calibration")


def check_fieldcal_result(res, accel_counts: bool, gyro_counts: bool, where) -> None:
    """A field calibration (:class:`calib.fieldcal.FieldCalResult`: ``accel`` / ``gyro`` fits with
    ``scale_factors`` and ``bias`` in SI for physical units) against the limits; biases of count triads are ADC
    offsets and not checked. :class:`calib.core.errors.ResultCheckError` (exit 3) if implausible."""
    problems = []
    for sensor, fit, counts in (("accel", res.accel, accel_counts), ("gyro", res.gyro, gyro_counts)):
        if fit is not None:
            problems += check_triad_result(sensor, fit.scale_factors, None if counts else fit.bias, counts=counts)
    raise_result_problems(problems, where, "check the recording's declared units; the static intervals are chosen "
                          "by the settings keys detection.rule / detection.threshold, gravity by gravity_m_s2, the "
                          "gyro offset by gyro.bias", "field calibration")
