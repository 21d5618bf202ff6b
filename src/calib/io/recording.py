"""The recording format ``calib-recording-1``: one netCDF file per session, read and written here only.

Layout (docs/recording-format.md)
---------------------------------
dims ``time`` and ``axis`` (= x, y, z); optional ``segment``, ``row``, ``col``.

* ``time(time)`` seconds from the start, **or** (long files) no ``time`` variable and the global
  attributes ``t0_s`` and ``sample_rate_hz`` alone.
* ``accel(time, axis)``, ``gyro(time, axis)``: raw output per sample. Attributes ``sample_kind``
  (``rate`` | ``increment``) and ``units``. A partial record (accelerometers only, or gyroscopes only) leaves
  the absent triad's variable out and names it in the global attribute ``absent_sensors`` (``"gyro"`` or
  ``"accel"``): declared, never zero-filled. A variable missing without that declaration is refused.
* optional ``temperature(time)`` [degC], ``segment_index(time)`` (int, -1 for transitions),
  ``table_angle(time)`` [deg about the current rotation axis].
* optional segment table on ``segment``: ``segment_kind`` (static | rotation), ``segment_label``,
  ``rotation_axis(segment, axis)`` (unit vector, body frame), ``rotation_rate(segment)`` [deg/s, right-hand
  rule], ``nominal_attitude(segment, row, col)`` (C_b^n, body to ENU).
* global attributes: ``latitude_deg`` (required), ``height_m``, ``gravity_m_s2``, ``sample_rate_hz``,
  ``source`` (synthetic | recorded), ``sensor``, ``Conventions = "CF-1.8 calib-recording-1"`` (files of
  earlier versions: ``conventions = "calib-recording-1"``, still read).
* ``sample_time_convention`` (global attribute, optional): which interval the output of sample ``k`` stamped
  ``t_k`` covers -- ``interval_start`` (the default, and the simulator's: ``[t_k, t_k + dt)``),
  ``interval_centre`` (``[t_k - dt/2, t_k + dt/2)``) or ``interval_end`` (``[t_k - dt, t_k)``, a logger that
  stamps a sample when it arrives). The table angle is read at the stamps; the diagnosis places each sample's
  motion by this convention, so a half-sample offset of the stamps is not reported as a clock offset.
* units are written in their CF (UDUNITS-2) spelling (``degree s-1``) and read back as the short names of
  :data:`UNITS` (``deg s-1``); both spellings are accepted on input.

Body frame: whatever the sensor's case marks; for the synthetic unit, Liu 2021's right-front-up.
Navigation frame: ENU. Rates are signed by the right-hand rule.
"""
from __future__ import annotations

import contextlib
import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import netCDF4
import numpy as np

from calib.core import clock, dropouts, earth
from calib.core.errors import InputError
from calib.io.atomic import atomic_path, utf8_name
from calib.io.netcdf import (CF_UNITS, CF_VERSION, AtomicNetCDF, conventions, float_values, index_values,
                             internal_units, string_values, write_netcdf)

if TYPE_CHECKING:   # imported where a dataset is made: checking a file (validate) needs neither xarray nor pandas
    import xarray as xr

CONVENTIONS = "calib-recording-1"
AXES = ("x", "y", "z")
#: the two triads of a recording; a partial record holds one of them (global attribute ``absent_sensors``)
SENSORS = ("accel", "gyro")

#: allowed units per (sensor, sample_kind)
UNITS = {
    ("accel", "rate"): ("count", "count s-1", "m s-2", "g"),
    ("accel", "increment"): ("count", "m s-1"),
    ("gyro", "rate"): ("count", "count s-1", "rad s-1", "deg s-1", "deg h-1"),
    ("gyro", "increment"): ("count", "rad", "deg"),
}
#: factor to SI (m/s^2, m/s, rad/s, rad) for physical units; counts have none
TO_SI = {
    "m s-2": 1.0,
    "g": None,  # depends on the standard gravity used by the sensor maker: 9.80665 m/s^2
    "m s-1": 1.0,
    "rad s-1": 1.0,
    "deg s-1": math.pi / 180.0,
    "deg h-1": math.pi / 180.0 / 3600.0,
    "rad": 1.0,
    "deg": math.pi / 180.0,
}
LONG_FILE_SAMPLES = 2_000_000  # above this, writers omit the explicit time coordinate


#: which interval the output of a sample covers relative to its time stamp (module docstring); the first is the
#: default and the simulator's
SAMPLE_TIME_CONVENTIONS = ("interval_start", "interval_centre", "interval_end")
#: the start of a sample's interval relative to its stamp, in sample periods
SAMPLE_INTERVAL_START = {"interval_start": 0.0, "interval_centre": -0.5, "interval_end": -1.0}


class RecordingError(InputError):
    """A recording that breaks ``calib-recording-1``; the message names the file, the variable and the fix.

    An :class:`calib.core.errors.InputError` (exit 2 of the command line) and so a ``ValueError``.
    """

    def __init__(self, path, variable, problem, fix=""):
        # variable "-": a problem of the file as a whole (missing, unreadable, truncated), named without a variable
        self.path, self.variable, self.problem = str(path), variable, problem
        super().__init__(problem, file=str(path), field=None if variable == "-" else f"variable '{variable}'",
                         fix=fix or None)

    def text(self) -> str:
        msg = ": ".join([self.path] + ([self.field] if self.field else []) + [self.problem])
        return msg + (f" -- fix: {self.fix}" if self.fix else "")


@dataclass(frozen=True)
class Header:
    """What a reader needs to know about a recording without loading its samples."""

    path: str
    n_samples: int
    sample_rate_hz: float
    t0_s: float
    has_time: bool
    latitude_deg: float
    height_m: float
    gravity_m_s2: float
    accel_kind: str
    accel_units: str
    gyro_kind: str
    gyro_units: str
    attrs: dict
    #: the time coordinate's fitted clock in one line (rate, jitter, gaps, dropped samples); None without one
    clock_summary: str | None = None

    @property
    def dt(self) -> float:
        return 1.0 / self.sample_rate_hz

    @property
    def sensors(self) -> tuple:
        """The triads the recording holds: ``("accel", "gyro")``, or one of them for a partial record (the other's
        kind and units are then None)."""
        return tuple(s for s, k in (("accel", self.accel_kind), ("gyro", self.gyro_kind)) if k is not None)

    @property
    def absent(self) -> tuple:
        """The triads a partial record declares absent (``absent_sensors``)."""
        return tuple(s for s in SENSORS if s not in self.sensors)

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.sample_rate_hz


def unit_factor(units: str) -> float | None:
    """Multiplier taking a physical unit to SI; ``g`` uses standard gravity; ``None`` for counts."""
    if units == "g":
        return earth.STANDARD_GRAVITY
    return TO_SI.get(units)


#: the declared ``sample_rate_hz`` must agree with the least-squares clock of the time coordinate to this
CLOCK_REL_TOL = 0.01
#: local gravity outside this range [m s-2] is not a value in m s-2 for a site on the Earth
GRAVITY_RANGE_M_S2 = (9.0, 10.5)
UNREADABLE_FIX = "re-export or re-import the recording"


def _attr(nc, name, default=None):
    return nc.getncattr(name) if name in nc.ncattrs() else default


def _number(path, nc, name, default=None):
    """A numeric global attribute as a float (``default`` when absent); a RecordingError when not a number."""
    v = _attr(nc, name, default)
    if v is None:
        return None
    try:
        arr = np.asarray(v, dtype=float)
        if arr.size != 1:
            raise ValueError("not a scalar")
        return float(arr.reshape(-1)[0])
    except (TypeError, ValueError):
        raise RecordingError(path, name, f"global attribute is {v!r}, not a number") from None


def _unreadable(path, exc) -> RecordingError:
    """What a reader raises for a file the netCDF library cannot read (truncated, corrupted, not netCDF; or a
    name it cannot open: the library takes UTF-8 paths only, and Python keeps the bytes of a name that is not
    valid UTF-8 as lone surrogates, which shows in the message as their escapes, e.g. ``\\udcff``)."""
    if isinstance(exc, PermissionError):
        return RecordingError(path, "-", "permission denied", "make the file readable")
    if isinstance(exc, UnicodeError):
        return RecordingError(path, "-", "the file name (or a folder on its path) is not valid UTF-8, and the netCDF "
                              "library opens UTF-8 paths only", "rename it to valid UTF-8 (e.g. letters, digits, "
                              "'-' and '_' only)")
    return RecordingError(path, "-", f"not a readable netCDF file ({type(exc).__name__}: {exc}); truncated or not "
                          "netCDF", UNREADABLE_FIX)


def _open(path):
    path = Path(path)
    if not path.exists():
        raise RecordingError(path, "-", "file not found")
    if path.is_dir():
        raise RecordingError(path, "-", "is a folder, not a recording file", "give the path of a .nc recording")
    try:
        return netCDF4.Dataset(path, "r")
    except Exception as exc:  # noqa: BLE001 - whatever the netCDF library raises, the file is unreadable
        raise _unreadable(path, exc) from exc


def check_clock(path, t, fs: float) -> clock.ClockFit:
    """The time coordinate ``t`` judged by its fitted clock (:func:`calib.core.clock.fit_clock`, the one fit of
    the importers too): jitter (stamps that leave the line and come back) is accepted and dropped samples
    (whole periods) are counted; a gap (the stamps leave the line for good) is refused, naming it and the
    windows either side that hold one clock each; the fitted rate must be within :data:`CLOCK_REL_TOL` of the
    declared ``fs``. Returns the fit."""
    try:
        clk = clock.fit_clock(t)
    except clock.ClockError as exc:
        raise RecordingError(path, "time", str(exc)) from None
    if clk.gaps:
        problem, fix = clk.gap_refusal()
        raise RecordingError(path, "time", problem, fix)
    if abs(clk.rate_hz / fs - 1.0) > CLOCK_REL_TOL:
        raise RecordingError(path, "sample_rate_hz", f"declared {fs:.6g} Hz but the time coordinate gives "
                             f"{clk.rate_hz:.6g} Hz (least-squares clock over {len(t)} samples; tolerance "
                             f"{100 * CLOCK_REL_TOL:g} %)",
                             "correct sample_rate_hz or the units of the time coordinate")
    return clk


def read_header(path) -> Header:
    """Open ``path`` and check everything that can be checked without reading the samples (the time
    coordinate included: monotonic, no gaps, consistent with ``sample_rate_hz``).

    Raises :class:`RecordingError` naming the file, the variable and what is wrong.
    """
    path = Path(path)
    nc = _open(path)
    try:
        return _header(path, nc)
    except RecordingError:
        raise
    except Exception as exc:  # noqa: BLE001 - a corrupted file fails anywhere inside the library
        raise _unreadable(path, exc) from exc
    finally:
        nc.close()


def _header(path, nc) -> Header:
    conv = conventions({k: nc.getncattr(k) for k in nc.ncattrs()})
    if conv != CONVENTIONS:
        raise RecordingError(path, "Conventions", f"global attribute names {conv or 'no format'!r}, expected "
                             f"'{CF_VERSION} {CONVENTIONS}'", "write recordings with calib import or calib simulate")
    for dim in ("time", "axis"):
        if dim not in nc.dimensions:
            raise RecordingError(path, dim, "dimension missing")
    if len(nc.dimensions["axis"]) != 3:
        raise RecordingError(path, "axis", f"length {len(nc.dimensions['axis'])}, expected 3 (x, y, z)")
    n = len(nc.dimensions["time"])
    if n < 2:
        raise RecordingError(path, "time", f"only {n} samples", "record at least two samples")
    lat = _number(path, nc, "latitude_deg")
    if lat is None:
        raise RecordingError(path, "latitude_deg", "required global attribute missing",
                             "set the site latitude (degrees) in the import settings")
    if not (-90.0 <= lat <= 90.0) or not math.isfinite(lat):
        raise RecordingError(path, "latitude_deg", f"value {lat} outside [-90, 90] degrees")
    height = _number(path, nc, "height_m", 0.0)
    if not math.isfinite(height):
        raise RecordingError(path, "height_m", f"value {height} is not finite")
    conv_t = str(nc.getncattr("sample_time_convention")) if "sample_time_convention" in nc.ncattrs() else \
        SAMPLE_TIME_CONVENTIONS[0]
    if conv_t not in SAMPLE_TIME_CONVENTIONS:
        raise RecordingError(path, "sample_time_convention", f"value {conv_t!r} unknown",
                             f"one of {', '.join(SAMPLE_TIME_CONVENTIONS)} (default {SAMPLE_TIME_CONVENTIONS[0]})")
    kinds = {}
    absent = declared_absent(path, _attr(nc, "absent_sensors", ""))
    for var in SENSORS:
        if var in absent:
            if var in nc.variables:
                raise RecordingError(path, var, "variable present but declared absent (absent_sensors)",
                                     f"remove '{var}' from the global attribute absent_sensors or the variable")
            kinds[var] = (None, None)
            continue
        if var not in nc.variables:
            raise RecordingError(path, var, "variable missing",
                                 f"import it, or declare a partial record: absent_sensors = \"{var}\" (calib import "
                                 f"does so when the settings leave '{var}' out)")
        v = nc.variables[var]
        if v.dimensions != ("time", "axis"):
            raise RecordingError(path, var, f"dimensions {v.dimensions}, expected ('time', 'axis')")
        kind = _attr(v, "sample_kind")
        if kind not in ("rate", "increment"):
            raise RecordingError(path, var, f"attribute sample_kind={kind!r}, expected 'rate' or 'increment'")
        units = internal_units(_attr(v, "units"))
        allowed = UNITS[(var, kind)]
        if units not in allowed:
            raise RecordingError(path, var, f"units={units!r} not allowed for sample_kind={kind!r}",
                                 f"declare one of {', '.join(allowed)}")
        kinds[var] = (kind, units)
    has_time = "time" in nc.variables
    if has_time:
        tv = nc.variables["time"][:]
        if np.ma.is_masked(tv):
            i = int(np.argmax(np.ma.getmaskarray(tv).reshape(-1)))
            raise RecordingError(path, "time", f"masked (_FillValue) time at sample {i}",
                                 "remove the samples without a time stamp before import")
        t = np.asarray(np.ma.getdata(tv), dtype=float)
        if t.shape != (n,):
            raise RecordingError(path, "time", f"shape {t.shape}, expected ({n},)")
        if not np.all(np.isfinite(t)):
            raise RecordingError(path, "time", "contains NaN or Inf")
        d = np.diff(t)
        if np.any(d <= 0):
            i = int(np.argmax(d <= 0))
            raise RecordingError(path, "time", f"not strictly increasing at sample {i + 1} "
                                 f"(t={t[i]:.6f} s then {t[i + 1]:.6f} s)")
        fs = _number(path, nc, "sample_rate_hz", 1.0 / np.median(d))
        t0 = float(t[0])
    else:
        fs = _number(path, nc, "sample_rate_hz")
        t0 = _number(path, nc, "t0_s")
        if fs is None or t0 is None:
            raise RecordingError(path, "time", "no time variable and no t0_s/sample_rate_hz attributes",
                                 "add a time coordinate or both global attributes")
    if not (fs > 0 and math.isfinite(fs)):
        raise RecordingError(path, "sample_rate_hz", f"value {fs} is not a positive rate")
    if not math.isfinite(t0):
        raise RecordingError(path, "t0_s", f"value {t0} is not finite")
    clock_summary = check_clock(path, t, fs).summary() if has_time else None
    g = _number(path, nc, "gravity_m_s2")
    if g is None:
        g = float(earth.normal_gravity(math.radians(lat), height))
    elif not (GRAVITY_RANGE_M_S2[0] <= g <= GRAVITY_RANGE_M_S2[1]):
        raise RecordingError(path, "gravity_m_s2", f"value {g} is not a local gravity in m s-2 (expected "
                             f"{GRAVITY_RANGE_M_S2[0]}..{GRAVITY_RANGE_M_S2[1]})",
                             "give local gravity in m s-2, or leave it out for WGS-84 normal gravity")
    attrs = {k: nc.getncattr(k) for k in nc.ncattrs()}
    return Header(str(path), n, fs, t0, has_time, lat, height, g,
                  kinds["accel"][0], kinds["accel"][1], kinds["gyro"][0], kinds["gyro"][1], attrs, clock_summary)


def declared_absent(path, value) -> tuple:
    """The triads named by a global attribute ``absent_sensors`` (space or comma separated); at most one."""
    names = tuple(str(value).replace(",", " ").split())
    for name in names:
        if name not in SENSORS:
            raise RecordingError(path, "absent_sensors", f"value {value!r}: names {name!r}",
                                 "name the absent triad: 'accel' or 'gyro'")
    if len(set(names)) == len(SENSORS):
        raise RecordingError(path, "absent_sensors", f"value {value!r}: a recording needs at least one triad",
                             "import the accelerometer or the gyroscope (or both)")
    return names


def require_sensors(header: Header, needed=SENSORS, path=None) -> None:
    """Refuse (:class:`RecordingError`, exit 2) a partial record that lacks a triad in ``needed``, naming it and
    what a partial record can go through instead."""
    missing = [s for s in needed if s not in header.sensors]
    if not missing:
        return
    holds = {"accel": "accelerometers", "gyro": "gyroscopes"}[header.sensors[0]]
    want = " and ".join({"accel": "the accelerometer", "gyro": "the gyroscope"}[s] for s in missing)
    raise RecordingError(path or header.path, missing[0], f"the recording holds {holds} only (absent_sensors = "
                         f"{' '.join(header.absent)!r}); this command needs {want} as well",
                         "give a recording of both triads; a partial record goes through calib validate, calib "
                         "noise (either triad), calib fieldcal and calib apply (accelerometer calibration)")


def _check_finite(path, name, arr, offset=0):
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(np.add.reduce(arr, axis=None)):   # no NaN or Inf can hide in a finite sum: the cheap test
            return
    bad = ~np.isfinite(arr)
    if bad.any():
        i = int(np.argmax(bad.reshape(len(arr), -1).any(axis=1)))
        raise RecordingError(path, name, f"NaN or Inf at sample {offset + i}",
                             "remove or interpolate the bad samples before import")


def _attribute_fills(var) -> list:
    """The values of a netCDF variable's ``_FillValue`` and ``missing_value`` attributes (those xarray masks)."""
    return [v for name in ("_FillValue", "missing_value") if name in var.ncattrs()
            for v in np.atleast_1d(var.getncattr(name)).tolist()]


def fill_values(var) -> list:
    """The values that mark a missing sample of a netCDF variable: ``_FillValue`` and ``missing_value``, or
    (no ``_FillValue`` attribute) the library's default fill of a 32- or 64-bit type (that of an 8- or 16-bit
    type, e.g. -32767, is a reading a clipped sensor can give); NaN fills left out (NaN is refused as such)."""
    out = _attribute_fills(var)
    if "_FillValue" not in var.ncattrs() and np.dtype(var.dtype).itemsize >= 4:
        fv = var.get_fill_value()
        if fv is not None:
            out.append(fv.item() if hasattr(fv, "item") else fv)
    return [v for v in out if not (isinstance(v, float) and math.isnan(v))]


def _check_fill(path, name, arr, fills, offset=0):
    for fv in fills:
        bad = arr == fv
        if bad.any():
            i = int(np.argmax(bad.reshape(len(arr), -1).any(axis=1)))
            raise RecordingError(path, name, f"masked sample (_FillValue {fv:g}) at sample {offset + i}: the "
                                 "value was never recorded", "remove or interpolate the missing samples before import")


#: files that passed :func:`validate` while :func:`reuse_validation` is active: identity -> Header (None: inactive)
_VALIDATED: dict | None = None


def identity(path):
    """What names one unchanged file: resolved path, device, inode, size, modification and change times
    (None when the file cannot be looked at; :func:`validate` then says why)."""
    try:
        st = os.stat(path)
        return (str(Path(path).resolve()), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    except (OSError, ValueError):
        return None


@contextlib.contextmanager
def reuse_validation():
    """Within the block, :func:`validate` checks each file once: a later call on the same, unchanged file (same
    inode, size, modification and change times) returns the header of the first check instead of reading every
    sample again. For one command that checks its inputs up front and then loads them (``calib diagnose``: the
    recording and the noise record); outside the block every call checks the file in full. Nests."""
    global _VALIDATED
    outer = _VALIDATED
    if outer is None:
        _VALIDATED = {}
    try:
        yield
    finally:
        if outer is None:
            _VALIDATED = None


def remember_validated(key, header: Header) -> None:
    """Within :func:`reuse_validation`: the file of identity ``key`` (:func:`identity`, taken before its check)
    passed :func:`validate` with ``header`` -- checked by another process of the same command (the helper of
    ``calib diagnose``); a later :func:`validate` of the unchanged file returns it."""
    if _VALIDATED is not None and key is not None:
        _VALIDATED[key] = dataclasses.replace(header, attrs=dict(header.attrs))


def validate(path, on_chunk=None, header: Header | None = None) -> Header:
    """Full check of a recording: header (time coordinate included), segment table and every sample (read
    in chunks: NaN/Inf and masked / _FillValue samples are refused with their index). ``on_chunk(first_index,
    accel, gyro)``: called with each chunk of raw samples once it passed, so that a further check of the samples
    needs no second read (not called when the file is known as validated: :func:`reuse_validation`). ``header``:
    :func:`read_header` of the file when the caller has it already (its checks, the whole time coordinate's
    included, are not run twice)."""
    memo = _VALIDATED
    key = identity(path) if memo is not None else None   # taken before the check: a file changed since misses
    if key is not None and key in memo:
        h = memo[key]
        return dataclasses.replace(h, attrs=dict(h.attrs))
    h = header or read_header(path)
    try:
        _validate_body(path, h, on_chunk)
    except RecordingError:
        raise
    except _OnChunkError as exc:
        raise exc.__cause__ from None
    except Exception as exc:  # noqa: BLE001 - a corrupted file fails anywhere inside the library
        raise _unreadable(path, exc) from exc
    if key is not None:
        memo[key] = dataclasses.replace(h, attrs=dict(h.attrs))
    return h


class _OnChunkError(Exception):
    """An exception of a validation's ``on_chunk``, carried out of the checks that name a failure the file's."""


#: the samples of a per-sample variable (segment index, temperature) :func:`validate` reads at a time
PER_SAMPLE_SLICE = 1_000_000


def _validate_body(path, h: Header, on_chunk=None) -> None:
    with netCDF4.Dataset(path, "r") as nc:   # the segment table and temperature, decoded as xarray decodes them
        var = nc.variables
        fills = {v: fill_values(var[v]) for v in SENSORS if v in var}
        nseg = len(nc.dimensions["segment"]) if "segment" in nc.dimensions else 0
        if "segment_index" in var:
            si = var["segment_index"]
            if si.dimensions != ("time",):
                raise RecordingError(path, "segment_index", f"dimensions {si.dimensions}, expected ('time',)")
            for i0 in range(0, si.shape[0], PER_SAMPLE_SLICE):   # one value per sample: in slices
                vals = index_values(si, slice(i0, i0 + PER_SAMPLE_SLICE))
                if vals.size and (vals.max() >= nseg or vals.min() < -1):
                    raise RecordingError(path, "segment_index", f"values must lie in -1..{nseg - 1}")
        if "segment" in nc.dimensions:
            for name in ("segment_kind",):
                if name not in var:
                    raise RecordingError(path, name, "segment table present but variable missing")
            kinds = string_values(var["segment_kind"])
            for i, k in enumerate(kinds):
                if k not in ("static", "rotation"):
                    raise RecordingError(path, "segment_kind", f"segment {i} has kind {k!r}")
            if "rotation_rate" in var:
                rr = float_values(var["rotation_rate"])
                for i, k in enumerate(kinds):
                    if k == "rotation" and not (np.isfinite(rr[i]) and rr[i] != 0.0):
                        raise RecordingError(path, "rotation_rate", f"rotation segment {i} has no rate ({rr[i]})",
                                             "give the table rate in deg/s, signed by the right-hand rule")
            elif "rotation" in kinds:
                raise RecordingError(path, "rotation_rate", "rotation segments present but no rates")
        if "temperature" in var:
            tv = var["temperature"]
            if tv.ndim == 1:   # one value per sample: read in slices, memory flat however long the record
                for i0 in range(0, tv.shape[0], PER_SAMPLE_SLICE):
                    _check_finite(path, "temperature", float_values(tv, slice(i0, i0 + PER_SAMPLE_SLICE)), i0)
            else:
                _check_finite(path, "temperature", float_values(tv))
    # dropouts and stuck runs (calib.core.dropouts) in a recorded file (a noise-free synthetic one may repeat rows)
    # (the threshold: the import's, stored as the attribute dropout_min_rows when its settings changed it)
    min_run = int(h.attrs.get("dropout_min_rows", dropouts.MIN_RUN))
    track = {v: dropouts.RunTracker(v, min_run) for v in SENSORS} if h.attrs.get("source") == "recorded" else {}
    for start, acc, gyr in iter_raw_chunks(path, h):
        for name, arr in (("accel", acc), ("gyro", gyr)):
            if arr is not None:   # (None: the triad a partial record declares absent)
                _check_finite(path, name, arr, start)
                _check_fill(path, name, arr, fills[name], start)
                if track:
                    track[name].add(arr)
        if on_chunk is not None:
            try:
                on_chunk(start, acc, gyr)
            except Exception as exc:  # noqa: BLE001 - not the file's fault: validate raises it as itself
                raise _OnChunkError() from exc
    # (a triad constant throughout is a placeholder, not a dropout: calib.signal.plausibility names it as such)
    runs = sorted((r for t in track.values() for r in t.finish() if (r.start, r.stop) != (0, h.n_samples)),
                  key=lambda r: r.start)
    if runs:
        sensor, problem, fix = dropouts.refusal(runs, 0, h.n_samples, _seconds_from_first(path, h), min_run)
        raise RecordingError(path, sensor, problem, "re-import the file (calib import trims such runs at the ends "
                             "and names the windows around one inside), or " + fix)


def _seconds_from_first(path, h: Header) -> np.ndarray:
    """Each sample's time from the first (the time coordinate, or the sample clock)."""
    if not h.has_time:
        return np.arange(h.n_samples) / h.sample_rate_hz
    with netCDF4.Dataset(path, "r") as nc:
        t = np.asarray(float_values(nc.variables["time"]), dtype=float)
    return t - t[0]


def slice_bounds(n_time_chunk: int | None, start: int, stop: int, target: int) -> list[tuple[int, int]]:
    """``[(i0, i1), ...]`` covering ``[start, stop)``: every boundary inside the range on a multiple of the
    file's chunk length ``n_time_chunk`` (None: contiguous storage, any boundary), slices of about ``target``
    samples (a whole number of chunks, at least one)."""
    target = max(int(target), 1)
    if n_time_chunk and n_time_chunk > 0:
        step = max(1, int(round(target / n_time_chunk))) * n_time_chunk
    else:
        step = target
    out = []
    i0 = start
    while i0 < stop:
        i1 = min(stop, (i0 // step + 1) * step)  # next multiple of step: aligned from the second slice on
        out.append((i0, i1))
        i0 = i1
    return out


def time_chunk(var) -> int | None:
    """The chunk length along ``time`` of a netCDF variable (None: contiguous storage)."""
    ch = var.chunking()
    return None if ch == "contiguous" or ch is None else int(ch[0])


def open_slices(path, header: Header | None = None, chunk: int = 1_000_000, start: int = 0, stop=None, *,
                auto_scale: bool = True):
    """The reading of ``[start, stop)`` in slices of about ``chunk`` samples made of whole chunks of the file
    (:func:`slice_bounds`): ``(open dataset, [(i0, i1), ...], read(i0, i1) -> (accel, gyro))``, raw float64 (n, 3);
    the caller closes the dataset; a triad a partial record declares absent reads as None. Every chunk of the file is read once, by one read, straight into the output (a
    slice across two chunks made the library read each of them twice: 2.3 against 0.7-0.8 s for the 240 h
    recording). ``auto_scale``: netCDF's scale_factor / add_offset applied (the navigation reads without)."""
    h = header or read_header(path)
    stop = h.n_samples if stop is None else min(int(stop), h.n_samples)
    nc = _open(path)
    try:
        nc.set_auto_mask(False)
        nc.set_auto_scale(auto_scale)
        va, vg = nc.variables.get("accel"), nc.variables.get("gyro")   # (None: declared absent)
        present = [v for v in (va, vg) if v is not None]
        tc = time_chunk(present[0])
        if any(time_chunk(v) != tc for v in present):
            tc = None   # different layouts: no common alignment, plain slices
        for v in present:
            v.set_var_chunk_cache(size=0)   # whole chunks only: no cache, no second copy
        bounds = slice_bounds(tc, max(int(start), 0), stop, chunk)
    except Exception as exc:  # noqa: BLE001 - a corrupted file fails anywhere inside the library
        nc.close()
        raise _unreadable(path, exc) from exc

    def read(i0, i1):
        try:
            return tuple(None if v is None else np.asarray(v[i0:i1], dtype=np.float64) for v in (va, vg))
        except Exception as exc:  # noqa: BLE001 - corrupted sample data fail inside the library
            raise _unreadable(path, exc) from exc

    return nc, bounds, read


def iter_raw_chunks(path, header: Header | None = None, chunk: int = 1_000_000, start: int = 0, stop=None, *,
                    auto_scale: bool = True):
    """Yield ``(first_sample_index, accel, gyro)`` raw float64 arrays (n, 3) of ``[start, stop)`` in order, the
    slices of :func:`open_slices`."""
    nc, bounds, read = open_slices(path, header, chunk, start, stop, auto_scale=auto_scale)
    try:
        for i0, i1 in bounds:
            yield (i0, *read(i0, i1))
    finally:
        nc.close()


def load(path, validate_all: bool = True) -> xr.Dataset:
    """Load a (small) recording fully into memory as an ``xarray.Dataset`` after validating it.

    Long files without a time coordinate get one computed from ``t0_s`` and ``sample_rate_hz``.
    """
    import xarray as xr

    h = validate(path) if validate_all else read_header(path)
    try:
        with xr.open_dataset(path, engine="netcdf4") as ds:
            ds = ds.load()
    except Exception as exc:  # noqa: BLE001 - a corrupted file fails anywhere inside the library
        raise _unreadable(path, exc) from exc
    if "time" not in ds.coords:
        ds = ds.assign_coords(time=h.t0_s + np.arange(h.n_samples) / h.sample_rate_hz)
    for name in ds.variables:
        if "units" in ds[name].attrs:
            ds[name].attrs["units"] = internal_units(ds[name].attrs["units"])
    ds.attrs["_path"] = str(path)
    return ds


#: variable attributes xarray's default decoding consumes (they are not in its ``attrs``)
_DECODED_ATTRS = ("_FillValue", "missing_value", "scale_factor", "add_offset", "_Unsigned", "_Encoding",
                  "coordinates")


@dataclass(frozen=True)
class ArrayVariable:
    """One variable of a :class:`RecordingArrays`: its values (numpy, decoded as xarray decodes them), attributes
    and dimension names -- what the diagnosis reads of an ``xarray.DataArray``."""
    values: np.ndarray
    attrs: dict
    dims: tuple


class RecordingArrays:
    """A recording read whole into numpy arrays with netCDF4, offering the part of ``xarray.Dataset`` that the
    diagnosis reads: ``attrs``, ``sizes``, ``coords`` (names), ``name in rec``, ``rec[name].values / .attrs /
    .dims``. ``calib diagnose`` reads its file this way: its process then never imports xarray and pandas (0.3 s
    of its 2 s). Made by :func:`load_arrays` only; anything else of a dataset (selection, copies, writing) needs
    :func:`load`."""

    def __init__(self, attrs: dict, variables: dict, sizes: dict):
        self.attrs = attrs
        self._variables = variables
        self.sizes = sizes
        # xarray's index coordinates: a variable named after its only dimension
        self.coords = tuple(k for k, v in variables.items() if v.dims == (k,))

    def __contains__(self, name) -> bool:
        return name in self._variables

    def __getitem__(self, name) -> ArrayVariable:
        return self._variables[name]

    @property
    def variables(self):
        return self._variables.keys()


def _needs_xarray_decoding(var) -> bool:
    """A variable whose default xarray decoding is more than masking: packed (its float type follows xarray's
    rules), unsigned-flagged, a time in 'units since epoch' or a duration in 'seconds' (decoded to dates and time
    deltas), or a character array (joined into strings along its last dimension, which xarray then drops)."""
    names = var.ncattrs()
    units = var.getncattr("units") if "units" in names else ""
    return (any(a in names for a in ("scale_factor", "add_offset", "_Unsigned"))
            or (isinstance(units, str) and (" since " in units or units in _TIMEDELTA_UNITS))
            or np.dtype(var.dtype).kind == "S")


#: the unit names xarray decodes a variable's values from into time deltas
_TIMEDELTA_UNITS = ("days", "hours", "minutes", "seconds", "milliseconds", "microseconds", "nanoseconds")


def _decoded(var) -> np.ndarray:
    """The values xarray's default decoding gives a variable that needs no more than masking: the values equal to
    its ``_FillValue`` or ``missing_value`` attributes as NaN (an integer variable with such an attribute as float,
    of xarray's width); no other value masked (netCDF4's own masking also hides the
    library's default fill and values outside ``valid_range``, which xarray keeps)."""
    if var.dtype == str:   # variable-length strings
        strings = string_values(var)
        return np.asarray(strings) if strings else np.asarray(strings, dtype=str)
    var.set_auto_maskandscale(False)
    raw = np.asarray(var[...])
    fills = _attribute_fills(var)
    if not fills:
        return raw
    # xarray's promotion of an integer type with a fill value: float32 for 8 and 16 bits, float64 above
    out = raw.astype(np.float32 if raw.dtype.itemsize <= 2 else np.float64) if raw.dtype.kind in "iu" else raw
    for fv in fills:
        missing = raw == fv   # (a NaN fill marks nothing: NaN equals nothing, and is NaN already)
        if missing.any():
            out = np.where(missing, np.nan, out)
    return out


def load_arrays(path, validate_all: bool = True):
    """The recording at ``path`` as :func:`load` gives it, read into a :class:`RecordingArrays` with netCDF4 (no
    xarray, no pandas): the same values (tests/io/test_recording.py compares every variable with :func:`load`'s),
    attributes (units in calib's spelling, ``_path``) and time coordinate (computed from ``t0_s`` and
    ``sample_rate_hz`` when the file has none). A file with a variable that needs more of xarray's decoding
    (:func:`_needs_xarray_decoding`: packed, unsigned-flagged, dates, character arrays) is read by :func:`load`
    instead (an ``xarray.Dataset``, same interface)."""
    path = Path(path)
    h = validate(path) if validate_all else read_header(path)
    nc = _open(path)
    try:
        if any(_needs_xarray_decoding(v) for v in nc.variables.values()):
            nc.close()
            return load(path, validate_all=False)
        attrs = {k: nc.getncattr(k) for k in nc.ncattrs()}
        # xarray's sizes: the dimensions its variables use
        sizes = {k: len(d) for k, d in nc.dimensions.items()
                 if any(k in v.dimensions for v in nc.variables.values())}
        variables = {}
        for name, var in nc.variables.items():
            va = {k: var.getncattr(k) for k in var.ncattrs() if k not in _DECODED_ATTRS}
            if "units" in va:
                va["units"] = internal_units(va["units"])
            variables[name] = ArrayVariable(_decoded(var), va, tuple(var.dimensions))
    except RecordingError:
        raise
    except Exception as exc:  # noqa: BLE001 - a corrupted file fails anywhere inside the library
        raise _unreadable(path, exc) from exc
    finally:
        if nc.isopen():
            nc.close()
    if "time" not in variables:
        variables["time"] = ArrayVariable(h.t0_s + np.arange(h.n_samples) / h.sample_rate_hz, {}, ("time",))
    attrs["_path"] = str(path)
    return RecordingArrays(attrs, variables, sizes)


def to_si(values, units: str, kind: str, dt: float, sensor: str):
    """Physical-unit samples to SI increments (m/s or rad) per sample for navigation.

    Raises ``ValueError`` for counts: those need a calibration first.
    """
    f = unit_factor(units)
    if f is None:
        raise ValueError(f"{sensor}: units 'count' need a calibration to become physical")
    v = np.asarray(values, dtype=np.float64) * f
    return v if kind == "increment" else v * dt


def make_dataset(accel, gyro, *, sample_rate_hz, latitude_deg, accel_units, gyro_units,
                 accel_kind="rate", gyro_kind="rate", time=None, t0_s=0.0, height_m=0.0, gravity_m_s2=None,
                 source="synthetic", sensor="", temperature=None, segment_index=None, segments=None,
                 table_angle=None, extra_attrs=None) -> xr.Dataset:
    """Build an in-memory ``calib-recording-1`` dataset.

    ``accel`` or ``gyro`` None: a partial record; that triad's variable is left out and named in the global
    attribute ``absent_sensors`` (its units and kind are ignored). ``segments`` is a dict of per-segment arrays: ``segment_kind``, ``segment_label``, ``rotation_axis``
    (n, 3), ``rotation_rate`` (n,) deg/s, ``nominal_attitude`` (n, 3, 3).
    """
    import xarray as xr

    if accel is None and gyro is None:
        raise ValueError("make_dataset: a recording needs the accelerometer or the gyroscope (or both)")
    data = {}
    if accel is not None:
        accel = np.asarray(accel)
        data["accel"] = (("time", "axis"), accel, {"sample_kind": accel_kind, "units": accel_units,
                                                   "long_name": "accelerometer triad output, body frame"})
    if gyro is not None:
        gyro = np.asarray(gyro)
        data["gyro"] = (("time", "axis"), gyro, {"sample_kind": gyro_kind, "units": gyro_units,
                                                 "long_name": "gyroscope triad output, body frame"})
    n = (accel if accel is not None else gyro).shape[0]
    coords = {"axis": list(AXES)}
    if time is None and n <= LONG_FILE_SAMPLES:
        time = t0_s + np.arange(n) / sample_rate_hz
    if time is not None:
        coords["time"] = ("time", np.asarray(time, dtype=np.float64), {"units": "s", "long_name": "time from start"})
    if temperature is not None:
        data["temperature"] = (("time",), np.asarray(temperature, dtype=np.float64),
                               {"units": "degC", "long_name": "unit temperature"})
    if segment_index is not None:
        data["segment_index"] = (("time",), np.asarray(segment_index, dtype=np.int32),
                                 {"long_name": "segment of each sample, -1 for transitions"})
    if table_angle is not None:
        data["table_angle"] = (("time",), np.asarray(table_angle, dtype=np.float64),
                               {"units": "deg", "long_name": "table angle about the current rotation axis"})
    if segments is not None:
        nseg = len(segments["segment_kind"])
        coords["segment"] = ("segment", np.arange(nseg, dtype=np.int32), {"long_name": "segment number"})
        data["segment_kind"] = (("segment",), np.asarray(segments["segment_kind"], dtype=str),
                                {"long_name": "segment kind: static or rotation"})
        data["segment_label"] = (("segment",), np.asarray(segments.get("segment_label", [""] * nseg), dtype=str),
                                 {"long_name": "segment label"})
        if "rotation_axis" in segments:
            data["rotation_axis"] = (("segment", "axis"), np.asarray(segments["rotation_axis"], dtype=float),
                                     {"long_name": "rotation axis, unit vector in the body frame"})
        if "rotation_rate" in segments:
            data["rotation_rate"] = (("segment",), np.asarray(segments["rotation_rate"], dtype=float),
                                     {"units": "deg s-1", "long_name": "table rate, right-hand rule"})
        if "nominal_attitude" in segments:
            data["nominal_attitude"] = (("segment", "row", "col"), np.asarray(segments["nominal_attitude"], float),
                                        {"long_name": "C_b^n body-to-ENU DCM at the segment start"})
    attrs = {"conventions": CONVENTIONS, "latitude_deg": float(latitude_deg), "height_m": float(height_m),
             "sample_rate_hz": float(sample_rate_hz), "source": source, "sensor": sensor}
    if time is None:
        attrs["t0_s"] = float(t0_s)
    if accel is None or gyro is None:
        attrs["absent_sensors"] = "accel" if accel is None else "gyro"
    if gravity_m_s2 is not None:
        attrs["gravity_m_s2"] = float(gravity_m_s2)
    if extra_attrs:
        attrs.update(extra_attrs)
    return xr.Dataset(data, coords=coords, attrs=attrs)


def write(ds: xr.Dataset, path, prov: dict | None = None) -> Path:
    """Write an in-memory recording atomically: it is validated under its temporary name and appears under
    ``path`` only when valid, so a refused recording never replaces an earlier file."""
    path = utf8_name(path, "recording")
    with atomic_path(path) as tmp:
        write_netcdf(ds, tmp, prov)
        try:
            validate(tmp)
        except RecordingError as exc:
            raise RecordingError(path, exc.variable, exc.problem, exc.fix or "") from None
    return path


class LongRecordingWriter:
    """Write a long recording chunk by chunk (no explicit time coordinate; ``t0_s`` + ``sample_rate_hz``).

    Usage::

        with LongRecordingWriter(path, n, fs, latitude_deg=30.58, ...) as w:
            w.append(accel_chunk, gyro_chunk)

    Memory stays flat with duration; the file appears under its final name only when complete.
    """

    def __init__(self, path, n_samples, sample_rate_hz, *, latitude_deg, accel_units, gyro_units,
                 accel_kind="increment", gyro_kind="increment", dtype="f8", height_m=0.0, t0_s=0.0,
                 source="synthetic", sensor="", extra_attrs=None, chunk_samples=262144, temperature=False):
        self._atomic = AtomicNetCDF(path)
        self.n = int(n_samples)
        self.pos = 0
        self.vt = None  # optional temperature(time) [degC] channel (``temperature=True``)
        self._temperature = bool(temperature)
        self._args = dict(fs=float(sample_rate_hz), lat=float(latitude_deg), au=accel_units, gu=gyro_units,
                          ak=accel_kind, gk=gyro_kind, dtype=dtype, h=float(height_m), t0=float(t0_s),
                          source=source, sensor=sensor, extra=extra_attrs or {}, chunk=int(chunk_samples))

    def __enter__(self):
        nc = self.nc = self._atomic.__enter__()
        try:
            self._define(nc)
        except BaseException as exc:  # not entered: the temporary file goes now
            self._atomic.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self

    def _define(self, nc):
        a = self._args
        nc.createDimension("time", self.n)
        nc.createDimension("axis", 3)
        ax = nc.createVariable("axis", str, ("axis",))
        for i, s in enumerate(AXES):
            ax[i] = s
        chunks = (min(a["chunk"], self.n), 3)
        self.va = nc.createVariable("accel", a["dtype"], ("time", "axis"), chunksizes=chunks)
        self.vg = nc.createVariable("gyro", a["dtype"], ("time", "axis"), chunksizes=chunks)
        self.va.setncatts({"sample_kind": a["ak"], "units": CF_UNITS.get(a["au"], a["au"]),
                           "long_name": "accelerometer triad output"})
        self.vg.setncatts({"sample_kind": a["gk"], "units": CF_UNITS.get(a["gu"], a["gu"]),
                           "long_name": "gyroscope triad output"})
        if self._temperature:
            self.vt = nc.createVariable("temperature", "f4", ("time",), chunksizes=(chunks[0],))
            self.vt.setncatts({"units": "degC", "long_name": "unit temperature"})
        attrs = {"Conventions": f"{CF_VERSION} {CONVENTIONS}", "latitude_deg": a["lat"], "height_m": a["h"],
                 "sample_rate_hz": a["fs"],
                 "t0_s": a["t0"], "source": a["source"], "sensor": a["sensor"]}
        attrs.update(a["extra"])
        nc.setncatts(attrs)

    def append(self, accel, gyro, temperature=None):
        k = len(accel)
        if self.pos + k > self.n:
            raise ValueError(f"writer overflow: {self.pos + k} > {self.n} samples")
        if (temperature is None) != (self.vt is None):
            raise ValueError("temperature samples must be given exactly when the writer was opened with temperature=True")
        self.va[self.pos:self.pos + k] = accel
        self.vg[self.pos:self.pos + k] = gyro
        if self.vt is not None:
            self.vt[self.pos:self.pos + k] = temperature
        self.pos += k

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None and self.pos != self.n:
            exc_type = ValueError
            self._atomic.__exit__(exc_type, None, None)
            raise ValueError(f"writer closed after {self.pos} of {self.n} samples")
        return self._atomic.__exit__(exc_type, exc, tb)
