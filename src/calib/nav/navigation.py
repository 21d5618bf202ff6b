"""Streaming pure-inertial navigation of ``calib-recording-1`` files (high level over :mod:`calib.nav.strapdown`).

:func:`navigate_recording` reads a recording chunk by chunk (memory flat in its duration), converts the raw
samples to SI body-frame increments, pre-integrates them to the navigation rate, navigates with the
vertical channel held and returns the navigation errors against the stationary truth (initial position,
zero velocity, initial attitude) as an ``xarray.Dataset`` on a time axis in seconds from the start.

Raw samples to SI increments
----------------------------
* physical units (``m s-1``/``rad``/``deg`` increments or ``m s-2``/``g``/``rad s-1``/``deg s-1``/``deg h-1``
  rates): :func:`calib.io.recording.to_si`.
* counts: need a calibration object (:class:`Calibration` protocol) turning the raw *rate* reading
  (counts per second; for increment counts, counts / dt) into the SI rate in the body frame. For a pair of
  :class:`calib.core.triad.TriadModel` (N = K E x + b, Liu 2021 eqs. 1-4) use :class:`TriadCalibration`: each
  model's :class:`calib.core.triad.TriadCorrection`, x = (K E)^-1 (N - b) in the triad's input unit, then to SI.

Initial conditions (``init``)
-----------------------------
* a :class:`calib.nav.strapdown.NavInit` or a dict ``{"pitch_deg", "roll_deg", "yaw_deg"[, "longitude_deg"]}``
  (e.g. the true attitude from the configuration);
* ``None`` or ``"attrs"``: the recording's global attributes ``attitude_pitch_deg``, ``attitude_roll_deg``,
  ``attitude_yaw_deg`` (written by :mod:`calib.sim.static_session`) or else the first ``nominal_attitude`` of its
  segment table; ``longitude_deg`` if present (else 0);
* ``"align"``: coarse + fine self-alignment on the first ``align_window_s`` of the recording
  (:mod:`calib.nav.alignment`; the base must be stationary during that window).

The truth attitude of a stationary recording is taken from its attributes when present, else it is the
initial attitude used.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import netCDF4
import numpy as np
import xarray as xr

from calib.core import clock
from calib.nav import alignment
from calib.nav import reader
from calib.core import earth
from calib.io import recording
from calib.nav import strapdown
from calib.io.recording import RecordingError
from calib.nav.strapdown import NavInit
from calib.core.rotations import dcm_to_euler
from calib.core.triad import TriadCorrection, TriadModel

ARCMIN = math.pi / 180.0 / 60.0
#: SI unit of the rate each triad's correction gives
SI_RATE = {"accel": "m s-2", "gyro": "rad s-1"}


# ======================================================================================================
# calibration protocol
# ======================================================================================================
@runtime_checkable
class Calibration(Protocol):
    """Turns raw count *rates* into SI body-frame rates.

    ``raw_units``: the unit of the raw rate it expects (``"count s-1"``). Recordings in ``count`` (increment)
    or ``count s-1`` (rate) units can use it; recordings in physical units cannot.
    """

    raw_units: str

    def apply_accel(self, raw_rate: np.ndarray) -> np.ndarray:  # (n, 3) count/s -> m/s^2
        ...

    def apply_gyro(self, raw_rate: np.ndarray) -> np.ndarray:  # (n, 3) count/s -> rad/s
        ...


def _input_factor(unit: str, sensor: str) -> float:
    f = recording.unit_factor(unit)
    if f is None:
        raise ValueError(f"{sensor} calibration: input unit {unit!r} is not a physical unit "
                         "(expected e.g. 'g', 'm s-2', 'deg h-1', 'rad s-1')")
    return f


@dataclass
class TriadCalibration:
    """Calibration from two triad models N = K E x + b (Liu 2021 eqs. 1-4): their corrections
    (:class:`calib.core.triad.TriadCorrection`) x = s (K E)^-1 (N - b), s the factor of the model's input unit to SI."""

    accel: TriadModel  # input unit e.g. 'g', output 'count s-1'
    gyro: TriadModel  # input unit e.g. 'deg h-1', output 'count s-1'
    raw_units: str = "count s-1"
    corrections: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        for name, tm in (("accel", self.accel), ("gyro", self.gyro)):
            if tm.output_unit != self.raw_units:
                raise ValueError(f"{name} calibration: output unit {tm.output_unit!r} != {self.raw_units!r}")
            self.corrections[name] = TriadCorrection.from_model(tm, name, output_unit=SI_RATE[name],
                                                                output_factor=_input_factor(tm.input_unit, name))

    def apply_accel(self, raw_rate):
        return self.corrections["accel"].apply(raw_rate)

    def apply_gyro(self, raw_rate):
        return self.corrections["gyro"].apply(raw_rate)


def check_units(header: recording.Header, calibration) -> None:
    """Raise :class:`RecordingError` when the recording's units and the calibration do not fit together."""
    for sensor, units in (("accel", header.accel_units), ("gyro", header.gyro_units)):
        is_count = recording.unit_factor(units) is None
        if is_count and calibration is None:
            raise RecordingError(header.path, sensor, f"units {units!r} are raw counts and no calibration was given",
                                 "give the unit's calibration: calib navigate --calibration default_calibration.nc "
                                 "(written by calib calibrate); in Python calibration=TriadCalibration(accel_model, "
                                 "gyro_model) or any object with apply_accel/apply_gyro")
        if not is_count and calibration is not None:
            raise RecordingError(header.path, sensor, f"units {units!r} are physical but a count calibration was "
                                 f"given (expects {getattr(calibration, 'raw_units', '?')!r})",
                                 "leave the calibration out for a recording in physical units (calib navigate "
                                 "without --calibration; in Python calibration=None)")
    if calibration is not None:
        if not (hasattr(calibration, "apply_accel") and hasattr(calibration, "apply_gyro")):
            raise TypeError("calibration must provide apply_accel(raw_rate) and apply_gyro(raw_rate)")
        ru = getattr(calibration, "raw_units", "count s-1")
        if ru != "count s-1":
            raise RecordingError(header.path, "accel/gyro", f"calibration expects raw units {ru!r}; "
                                 "count recordings give 'count s-1' rates", "use a calibration for count rates")


def raw_to_increments(header: recording.Header, accel, gyro, calibration=None):
    """Raw chunk -> (dtheta [rad], dv [m/s]) body-frame increments per sample."""
    dt = header.dt
    out = []
    for sensor, raw, units, kind in (("gyro", gyro, header.gyro_units, header.gyro_kind),
                                     ("accel", accel, header.accel_units, header.accel_kind)):
        if recording.unit_factor(units) is None:
            rate = raw / dt if kind == "increment" else raw
            si = calibration.apply_gyro(rate) if sensor == "gyro" else calibration.apply_accel(rate)
            out.append(np.ascontiguousarray(si * dt))
        elif kind == "increment" and recording.unit_factor(units) == 1.0:
            out.append(np.ascontiguousarray(raw, dtype=np.float64))  # already SI increments: no copy
        else:
            out.append(np.ascontiguousarray(recording.to_si(raw, units, kind, dt, sensor)))
    return out[0], out[1]


def check_time(header: recording.Header) -> None:
    """With a time coordinate: the clock fitted to it (:func:`calib.io.recording.check_clock`, which refuses a gap
    naming the windows either side) must hold no dropped sample, since the navigation integrates one sample
    period per sample; jitter of the stamps is not in the samples and is accepted. Else
    :class:`RecordingError` naming the first drop."""
    if not header.has_time:
        return
    with netCDF4.Dataset(header.path, "r") as nc:
        nc.set_auto_mask(False)
        t = np.asarray(nc.variables["time"][:], dtype=float)
    clk = recording.check_clock(header.path, t, header.sample_rate_hz)
    if clk.n_dropped:
        j, c = int(clk.dropped_after[0]), int(clk.dropped_count[0])
        windows = [(0.0, 0.5 * (t[j] + t[j + 1]) - t[0]), (0.5 * (t[j] + t[j + 1]) - t[0], t[-1] - t[0] + header.dt)]
        raise RecordingError(header.path, "time", f"{clk.n_dropped} dropped sample(s), the first {c} between samples "
                             f"{j} and {j + 1} (t = {t[j]:.6f} s): the navigation integrates one sample period per "
                             "sample", clock.window_fix(windows, "the drops") + " (or fill the drops at the source)")


# ======================================================================================================
# streaming navigator
# ======================================================================================================
class StrapdownNavigator:
    """Stateful streaming navigation of high-rate increments, one or several compensated streams.

    ``feed(dtheta, dv)`` returns the output records (S, n, 9) completed by this chunk; the state
    (pre-integration carry, navigation state, output phase) is carried to the next call. With one stream
    and no compensation the fused kernel runs (pre-integration and navigation in one pass); otherwise the
    increments are pre-integrated once and the streams share them (:func:`calib.nav.strapdown.navigate_multi`).
    """

    def __init__(self, init: NavInit, dt: float, n_sub: int, out_every: int, gyro_bias_rad_s=None,
                 accel_bias=None, vertical: str = "hold", parallel: bool = True):
        self.dt, self.n_sub, self.out_every = float(dt), int(n_sub), int(out_every)
        self.dt_nav = self.dt * self.n_sub
        self.gb = None if gyro_bias_rad_s is None else np.atleast_2d(np.asarray(gyro_bias_rad_s, float))
        self.ab = None if accel_bias is None else np.atleast_2d(np.asarray(accel_bias, float))
        self.n_streams = self.gb.shape[0] if self.gb is not None else (self.ab.shape[0] if self.ab is not None else 1)
        self.fused = self.gb is None and self.ab is None
        if not self.fused and self.gb is None:
            self.gb = np.zeros((self.n_streams, 3))
        self.init = init
        self.state = strapdown.NavState.from_init(init, self.n_streams)
        self.carry = None
        self.vertical = vertical
        self.parallel = parallel

    @property
    def steps(self) -> int:
        return self.state.steps

    def feed(self, dtheta, dv) -> np.ndarray:
        if len(dtheta) == 0:
            return np.empty((self.n_streams, 0, strapdown.NOUT))
        if self.carry is None:
            self.carry = strapdown.new_carry(dtheta[0], dv[0])
        if self.fused:
            out, self.state, self.carry = strapdown.navigate_highrate(
                dtheta, dv, self.dt, self.n_sub, self.state, self.carry, self.out_every, self.vertical)
            return out[None]
        Dth, Dv = strapdown.preintegrate(dtheta, dv, self.n_sub, self.carry)
        out, self.state = strapdown.navigate_multi(Dth, Dv, self.dt_nav, self.state, self.gb, self.ab,
                                                   self.out_every, self.vertical, parallel=self.parallel)
        return out

    def initial_record(self) -> np.ndarray:
        i = self.init
        p, r, y = dcm_to_euler(i.cbn())
        return np.array([p, r, y, i.vE, i.vN, 0.0 if self.vertical == "hold" else i.vU, i.lat, i.lon, i.h])


# ======================================================================================================
# errors against a stationary truth
# ======================================================================================================
def euler_to_dcm_batch(pitch, roll, yaw):
    """C_b^n (..., 3, 3) = Rz(yaw) Rx(pitch) Ry(roll), vectorised."""
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    cy, sy = np.cos(yaw), np.sin(yaw)
    C = np.empty(np.shape(pitch) + (3, 3))
    C[..., 0, 0] = cy * cr - sy * sp * sr
    C[..., 0, 1] = -sy * cp
    C[..., 0, 2] = cy * sr + sy * sp * cr
    C[..., 1, 0] = sy * cr + cy * sp * sr
    C[..., 1, 1] = cy * cp
    C[..., 1, 2] = sy * sr - cy * sp * cr
    C[..., 2, 0] = -cp * sr
    C[..., 2, 1] = sp
    C[..., 2, 2] = cp * cr
    return C


def misalignment(pitch, roll, yaw, C_true, block: int = 65536):
    """phi (..., 3) [rad] with C_b^n(computed) = (I - [phi x]) C_b^n(true) (exact rotation vector of
    C_true C_computed^T), from computed Euler angles; vectorised, in blocks along the last axis."""
    pitch, roll, yaw = np.asarray(pitch, float), np.asarray(roll, float), np.asarray(yaw, float)
    if pitch.ndim and pitch.shape[-1] > block:
        return np.concatenate([misalignment(pitch[..., i:i + block], roll[..., i:i + block], yaw[..., i:i + block],
                                            C_true, block) for i in range(0, pitch.shape[-1], block)], axis=-2)
    Cc = euler_to_dcm_batch(pitch, roll, yaw)
    R = np.einsum("ij,...kj->...ik", np.asarray(C_true, float), Cc)
    w = 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = np.linalg.norm(w, axis=-1)
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    a = np.arctan2(s, c)
    k = np.where(s > 1e-300, a / np.where(s > 1e-300, s, 1.0), 1.0)
    return w * k[..., None]


def wrap_pi(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def errors_dataset(out, t_s, truth: NavInit, attrs=None) -> xr.Dataset:
    """Dataset of navigation results and errors from output records ``out`` (S, n, 9) or (n, 9).

    Angles in rad (``*_arcmin`` companions for attitude and position), velocities m/s, positions also
    in metres (north_err_m, east_err_m); ``time`` in seconds from the start.
    """
    out = np.asarray(out)
    single = out.ndim == 2
    if single:
        out = out[None]
    C = truth.cbn()
    p0, r0, y0 = (float(a) for a in dcm_to_euler(C))
    r_m, r_n = earth.radii(truth.lat)
    phi = misalignment(out[..., 0], out[..., 1], out[..., 2], C)
    dims = ("stream", "time")
    v = {}

    def put(name, arr, units, long):
        v[name] = (dims, arr, {"units": units, "long_name": long})

    angles = (("pitch", "pitch"), ("roll", "roll"), ("yaw", "yaw (ENU, from North towards West)"))
    for i, (name, long) in enumerate(angles):
        put(name, out[..., i], "rad", f"navigated {long}")
    put("vE", out[..., 3], "m s-1", "navigated east velocity")
    put("vN", out[..., 4], "m s-1", "navigated north velocity")
    put("vU", out[..., 5], "m s-1", "navigated up velocity (0: vertical channel held)")
    put("lat", out[..., 6], "rad", "navigated latitude")
    put("lon", out[..., 7], "rad", "navigated longitude")
    put("h", out[..., 8], "m", "navigated height")
    put("pitch_err", out[..., 0] - p0, "rad", "pitch error (navigated - true)")
    put("roll_err", wrap_pi(out[..., 1] - r0), "rad", "roll error (navigated - true)")
    put("yaw_err", wrap_pi(out[..., 2] - y0), "rad", "yaw error (navigated - true)")
    for i, c in enumerate("ENU"):
        put(f"phi_{c}", phi[..., i], "rad", f"misalignment phi_{c}, C_computed = (I - [phi x]) C_true")
    put("vE_err", out[..., 3] - truth.vE, "m s-1", "east velocity error")
    put("vN_err", out[..., 4] - truth.vN, "m s-1", "north velocity error")
    put("lat_err", out[..., 6] - truth.lat, "rad", "latitude error")
    put("lon_err", out[..., 7] - truth.lon, "rad", "longitude error")
    put("north_err_m", (out[..., 6] - truth.lat) * (r_m + truth.h), "m", "north position error")
    put("east_err_m", (out[..., 7] - truth.lon) * (r_n + truth.h) * math.cos(truth.lat), "m", "east position error")
    for name in ("pitch_err", "roll_err", "yaw_err", "lat_err", "lon_err"):
        put(name + "_arcmin", v[name][1] / ARCMIN, "arcmin", v[name][2]["long_name"])
    time = ("time", np.asarray(t_s, float), {"units": "s", "long_name": "time from start"})
    ds = xr.Dataset(v, coords={"time": time, "stream": ("stream", np.arange(out.shape[0]), {"long_name": "stream"})},
                    attrs=dict(attrs or {}))
    ds.attrs.update({"truth_latitude_rad": truth.lat, "truth_longitude_rad": truth.lon, "truth_height_m": truth.h,
                     "truth_pitch_rad": p0, "truth_roll_rad": r0, "truth_yaw_rad": y0,
                     "attitude_convention": "C_b^n = Rz(yaw) Rx(pitch) Ry(roll), ENU"})
    return ds.isel(stream=0, drop=True) if single else ds


# ======================================================================================================
# initial conditions
# ======================================================================================================
def attitude_from_attrs(path, header: recording.Header):
    """(pitch, roll, yaw) [rad] of the recording's attributes or first nominal attitude, else None."""
    a = header.attrs
    keys = ("attitude_pitch_deg", "attitude_roll_deg", "attitude_yaw_deg")
    if all(k in a for k in keys):
        return tuple(math.radians(float(a[k])) for k in keys)
    nc = netCDF4.Dataset(path, "r")
    try:
        if "nominal_attitude" in nc.variables:
            C = np.asarray(nc.variables["nominal_attitude"][0], float)
            return tuple(float(x) for x in dcm_to_euler(C))
    finally:
        nc.close()
    return None


def resolve_init(path, header: recording.Header, init, calibration=None, align_window_s: float = 600.0,
                 n_sub: int = 10, chunk: int | None = None):
    """Initial navigation state and the truth attitude for a recording (see module docstring)."""
    lat = math.radians(header.latitude_deg)
    lon = math.radians(float(header.attrs.get("longitude_deg", 0.0)))
    h = header.height_m
    true_att = attitude_from_attrs(path, header)
    if isinstance(init, NavInit):
        start = init
    elif isinstance(init, dict):
        try:
            att = tuple(math.radians(float(init[k])) for k in ("pitch_deg", "roll_deg", "yaw_deg"))
        except KeyError as exc:
            raise ValueError(f"init dict needs pitch_deg, roll_deg, yaw_deg (missing {exc})") from None
        lon = math.radians(float(init.get("longitude_deg", math.degrees(lon))))
        start = NavInit(lat=lat, lon=lon, h=h, pitch=att[0], roll=att[1], yaw=att[2])
    elif init is None or init == "attrs":
        if true_att is None:
            raise RecordingError(path, "attitude_pitch_deg", "no initial attitude in the recording attributes",
                                 "self-align on the first static minutes (calib navigate --align; in Python "
                                 "init='align'), or give the attitude (init={'pitch_deg':..,'roll_deg':..,"
                                 "'yaw_deg':..})")
        start = NavInit(lat=lat, lon=lon, h=h, pitch=true_att[0], roll=true_att[1], yaw=true_att[2])
    elif init == "align":
        n = int(round(align_window_s * header.sample_rate_hz))
        n -= n % n_sub
        if n > header.n_samples or n < n_sub:
            raise ValueError(f"{path}: align_window_s = {align_window_s} s does not fit the recording")
        dth, dv = [], []
        for _, acc, gyr in reader.iter_raw_chunks(path, header, chunk=chunk, stop=n):
            a, b = raw_to_increments(header, acc, gyr, calibration)
            dth.append(a)
            dv.append(b)
        dth, dv = np.concatenate(dth), np.concatenate(dv)
        C = alignment.align(dth, dv, header.dt, lat, h, n_sub=n_sub)
        start = NavInit(lat=lat, lon=lon, h=h, C_bn=C)
    else:
        raise ValueError(f"init={init!r}: expected NavInit, a dict of degrees, None/'attrs' or 'align'")
    if true_att is not None:
        truth = NavInit(lat=lat, lon=lon, h=h, pitch=true_att[0], roll=true_att[1], yaw=true_att[2])
    else:
        truth = NavInit(lat=start.lat, lon=start.lon, h=start.h, C_bn=start.cbn())
    return start, truth


# ======================================================================================================
# the recording-level entry point
# ======================================================================================================
def navigate_recording(path, calibration=None, init=None, nav_rate_hz: float = 10.0, output_interval_s: float = 1.0,
                       chunk: int | None = None, progress=None, gyro_bias_rad_s=None, accel_bias=None,
                       vertical: str = "hold", align_window_s: float = 600.0, parallel: bool = True,
                       header: recording.Header | None = None) -> xr.Dataset:
    """Pure-inertial navigation of a stationary recording, streamed; returns navigation errors.

    path: a ``calib-recording-1`` file. calibration: :class:`Calibration` for count recordings, None for
    physical units (a mismatch raises :class:`RecordingError`). init: see module docstring.
    nav_rate_hz must divide the sample rate; output_interval_s must be a multiple of the navigation
    interval. gyro_bias_rad_s (S, 3) [rad/s] / accel_bias (S, 3) [m/s^2]: optional constant compensations;
    with S > 1 the result has a ``stream`` dimension. progress(samples_done, n_samples) is called per chunk.
    chunk: samples per read (default about 2**20, rounded to whole chunks of the file); the samples are read
    by :func:`calib.nav.reader.for_each_chunk`: the next slice is read while this one is navigated in a
    worker thread (memory flat: two slices in memory at a time); a ``calibration`` object must not use
    netCDF (it runs in that worker thread). header: :func:`calib.io.recording.read_header` of ``path`` when the
    caller has it (a recording's time coordinate is read whole for its checks).

    Returns an ``xarray.Dataset`` on ``time`` [h] (the first record is the initial state at t = 0) with the
    navigated pitch, roll, yaw, vE, vN, vU, lat, lon, h and the errors pitch_err, roll_err, yaw_err,
    phi_E/N/U [rad] (+ ``*_arcmin``), vE_err, vN_err [m/s], lat_err, lon_err [rad] (+ ``*_arcmin``),
    north_err_m, east_err_m [m].
    """
    # missing latitude, bad units, non-monotonic time -> RecordingError (``header``: the caller's read of it)
    h = header or recording.read_header(path)
    check_units(h, calibration)
    n_sub_f = h.sample_rate_hz / float(nav_rate_hz)
    n_sub = int(round(n_sub_f))
    if n_sub < 1 or abs(n_sub_f - n_sub) > 1e-9 * n_sub_f:
        raise ValueError(f"nav_rate_hz = {nav_rate_hz} does not divide the sample rate {h.sample_rate_hz} Hz of "
                         f"{path} -- fix: choose a divisor of the sample rate")
    dt_nav = n_sub * h.dt
    oe_f = float(output_interval_s) / dt_nav
    out_every = int(round(oe_f))
    if out_every < 1 or abs(oe_f - out_every) > 1e-6 * max(oe_f, 1.0):
        raise ValueError(f"output_interval_s = {output_interval_s} is not a multiple of the navigation interval "
                         f"{dt_nav} s -- fix: choose a multiple")
    check_time(h)
    start, truth = resolve_init(path, h, init, calibration, align_window_s, n_sub, chunk)
    nav = StrapdownNavigator(start, h.dt, n_sub, out_every, gyro_bias_rad_s, accel_bias, vertical, parallel)
    outs = [np.broadcast_to(nav.initial_record(), (nav.n_streams, 1, strapdown.NOUT))]

    def navigate_slice(i0, acc, gyr):  # in a worker thread while the next slice is read (no netCDF here)
        dth, dv = raw_to_increments(h, acc, gyr, calibration)
        outs.append(nav.feed(dth, dv))

    reader.for_each_chunk(path, navigate_slice, h, chunk=chunk,
                          progress=None if progress is None else (lambda done: progress(done, h.n_samples)))
    out = np.concatenate(outs, axis=1)
    t = np.arange(out.shape[1]) * out_every * dt_nav
    attrs = {"source_file": str(path), "nav_rate_hz": 1.0 / dt_nav, "output_interval_s": out_every * dt_nav,
             "sample_rate_hz": h.sample_rate_hz, "vertical_channel": vertical,
             "n_samples_used": nav.steps * n_sub, "n_samples": h.n_samples,
             "algorithm": "calib.nav.strapdown two-speed (coning/sculling pre-integration), ENU, WGS-84"}
    ds = errors_dataset(out, t, truth, attrs)
    return ds.isel(stream=0, drop=True) if nav.n_streams == 1 and gyro_bias_rad_s is None and accel_bias is None else ds
