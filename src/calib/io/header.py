"""The vocabulary of ``calib-recording-1`` and the check of a file without its samples.

The format's names and units (:data:`CONVENTIONS`, :data:`UNITS`, :data:`SAMPLE_TIME_CONVENTIONS`, ...), the
error every reader raises (:class:`RecordingError`), what a reader knows before loading samples (:class:`Header`)
and :func:`read_header`, which opens a file and checks everything but the samples: dimensions, global
attributes, the two triads (or the one of a partial record) and the time coordinate by its fitted clock
(:func:`check_clock`). The layout itself is described in :mod:`calib.io.recording`.
"""
from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from pathlib import Path

import netCDF4
import numpy as np

from calib.core import clock, earth
from calib.core.errors import InputError
from calib.io.netcdf import CF_VERSION, conventions, internal_units

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


#: which interval the output of a sample covers relative to its time stamp (:mod:`calib.io.recording`); the
#: first is the default and the simulator's
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

    def sample_times(self) -> np.ndarray:
        """Each sample's time [s] by the sample clock: ``t0_s + k / sample_rate_hz`` (the time coordinate of a
        file that stores none)."""
        return clock_times(self.n_samples, self.sample_rate_hz, self.t0_s)


def clock_times(n: int, sample_rate_hz: float, t0_s: float = 0.0) -> np.ndarray:
    """The stamps [s] of ``n`` samples by the sample clock, ``t0_s + k / sample_rate_hz``: the time coordinate of a
    file that stores none, and the one a writer stores."""
    return t0_s + np.arange(n) / sample_rate_hz


def unit_factor(units: str) -> float | None:
    """Multiplier taking a physical unit to SI; ``g`` uses standard gravity; ``None`` for counts."""
    if units == "g":
        return earth.STANDARD_GRAVITY
    return TO_SI.get(units)


def to_si(values, units: str, kind: str, dt: float, sensor: str):
    """Physical-unit samples to SI increments (m/s or rad) per sample for navigation.

    Raises ``ValueError`` for counts: those need a calibration first.
    """
    f = unit_factor(units)
    if f is None:
        raise ValueError(f"{sensor}: units 'count' need a calibration to become physical")
    v = np.asarray(values, dtype=np.float64) * f
    return v if kind == "increment" else v * dt


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


def unreadable(path, exc) -> RecordingError:
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


def open_recording(path):
    """``path`` opened for reading with the netCDF library; a missing, folder or unreadable path is refused
    (:class:`RecordingError`)."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(path, "-", "file not found")
    if path.is_dir():
        raise RecordingError(path, "-", "is a folder, not a recording file", "give the path of a .nc recording")
    try:
        return netCDF4.Dataset(path, "r")
    except Exception as exc:  # noqa: BLE001 - whatever the netCDF library raises, the file is unreadable
        raise unreadable(path, exc) from exc


@contextlib.contextmanager
def reading(path):
    """``path`` open for reading (:func:`open_recording`) within the block and closed after it; an exception of the
    netCDF library inside the block (a corrupted file fails anywhere inside it) is raised as the refusal of an
    unreadable file (:func:`unreadable`), a :class:`RecordingError` as it is."""
    nc = open_recording(path)
    try:
        yield nc
    except RecordingError:
        raise
    except Exception as exc:  # noqa: BLE001 - a corrupted file fails anywhere inside the library
        raise unreadable(path, exc) from exc
    finally:
        if nc.isopen():
            nc.close()


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
    with reading(path) as nc:
        return _header(path, nc)


def _header(path, nc) -> Header:
    attrs = {k: nc.getncattr(k) for k in nc.ncattrs()}
    conv = conventions(attrs)
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
    conv_t = str(_attr(nc, "sample_time_convention", SAMPLE_TIME_CONVENTIONS[0]))
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
