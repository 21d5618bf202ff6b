"""The full check of a recording: its header, segment table and every sample.

:func:`validate` reads the header (:func:`calib.io.header.read_header`: the time coordinate's clock included),
then the body: the segment table against the per-sample segment index, the temperature, and every sample of
the triads in chunks (:func:`calib.io.chunked_reading.iter_raw_chunks`), refusing NaN or Inf, masked
(``_FillValue``) samples and, in a recorded file, dropouts and stuck runs (:mod:`calib.core.dropouts`), each by
its index. Within :func:`calib.io.validation_cache.reuse_validation` a file is checked once.
"""
from __future__ import annotations

import netCDF4
import numpy as np

from calib.core import dropouts
from calib.io import validation_cache
from calib.io.chunked_reading import iter_raw_chunks
from calib.io.header import SENSORS, Header, RecordingError, clock_times, read_header, unreadable
from calib.io.netcdf import fill_values, float_values, index_values, string_values


def validate(path, on_chunk=None, header: Header | None = None) -> Header:
    """Full check of a recording: header (time coordinate included), segment table and every sample (read
    in chunks: NaN/Inf and masked / _FillValue samples are refused with their index). ``on_chunk(first_index,
    accel, gyro)``: called with each chunk of raw samples once it passed, so that a further check of the samples
    needs no second read (not called when the file is known as validated:
    :func:`calib.io.validation_cache.reuse_validation`). ``header``: :func:`calib.io.header.read_header` of the file
    when the caller has it already (its checks, the whole time coordinate's included, are not run twice)."""
    # the identity is taken before the check: a file changed since misses
    key = validation_cache.identity(path) if validation_cache.active() else None
    known = validation_cache.recalled(key)
    if known is not None:
        return known
    h = header or read_header(path)
    try:
        _validate_body(path, h, on_chunk)
    except RecordingError:
        raise
    except _OnChunkError as exc:
        raise exc.__cause__ from None
    except Exception as exc:  # noqa: BLE001 - a corrupted file fails anywhere inside the library
        raise unreadable(path, exc) from exc
    validation_cache.remember_validated(key, h)
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
        return clock_times(h.n_samples, h.sample_rate_hz)
    with netCDF4.Dataset(path, "r") as nc:
        t = np.asarray(float_values(nc.variables["time"]), dtype=float)
    return t - t[0]


def _check_finite(path, name, arr, offset=0):
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(np.add.reduce(arr, axis=None)):   # no NaN or Inf can hide in a finite sum: the cheap test
            return
    bad = ~np.isfinite(arr)
    if bad.any():
        i = int(np.argmax(bad.reshape(len(arr), -1).any(axis=1)))
        raise RecordingError(path, name, f"NaN or Inf at sample {offset + i}",
                             "remove or interpolate the bad samples before import")


def _check_fill(path, name, arr, fills, offset=0):
    for fv in fills:
        bad = arr == fv
        if bad.any():
            i = int(np.argmax(bad.reshape(len(arr), -1).any(axis=1)))
            raise RecordingError(path, name, f"masked sample (_FillValue {fv:g}) at sample {offset + i}: the "
                                 "value was never recorded", "remove or interpolate the missing samples before import")
