"""Writing recordings: an in-memory ``xarray.Dataset`` (:func:`make_dataset`, :func:`write`) or a long recording
chunk by chunk (:class:`LongRecordingWriter`). Every file appears under its name only when complete (and, for
:func:`write`, valid), so a failure never leaves a half-written or refused file behind.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calib.io.atomic import atomic_path, utf8_name
from calib.io.header import AXES, CONVENTIONS, LONG_FILE_SAMPLES, RecordingError, clock_times
from calib.io.netcdf import CF_UNITS, CF_VERSION, AtomicNetCDF, write_netcdf
from calib.io.validation import validate

if TYPE_CHECKING:   # imported by make_dataset only: checking or reading a file needs neither xarray nor pandas
    import xarray as xr


def make_dataset(accel, gyro, *, sample_rate_hz, latitude_deg, accel_units, gyro_units,
                 accel_kind="rate", gyro_kind="rate", time=None, t0_s=0.0, height_m=0.0, gravity_m_s2=None,
                 source="synthetic", sensor="", temperature=None, segment_index=None, segments=None,
                 table_angle=None, extra_attrs=None) -> xr.Dataset:
    """Build an in-memory ``calib-recording-1`` dataset.

    ``accel`` or ``gyro`` None: a partial record; that triad's variable is left out and named in the global
    attribute ``absent_sensors`` (its units and kind are ignored). ``segments`` is a dict of per-segment arrays:
    ``segment_kind``, ``segment_label``, ``rotation_axis`` (n, 3), ``rotation_rate`` (n,) deg/s,
    ``nominal_attitude`` (n, 3, 3).
    """
    import xarray as xr   # optional heavy import: only a caller that makes a dataset pays for xarray and pandas

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
        time = clock_times(n, sample_rate_hz, t0_s)
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
            raise ValueError("temperature samples must be given exactly when the writer was opened with "
                             "temperature=True")
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
