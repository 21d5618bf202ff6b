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

The public face of the format
-----------------------------
``calib.io.recording`` is the recording format's documented API (``recording.load``, ``recording.validate``,
``recording.write``, ...; docs/recording-format.md): it holds no code and re-exports the names of the modules
that implement it, one concern each, so that a caller names the format, not the module that happens to hold a
function:

* :mod:`calib.io.header`: the format's names and units, :class:`RecordingError`, :class:`Header`,
  :func:`read_header` (everything checked without the samples, the time coordinate's clock included);
* :mod:`calib.io.validation`: :func:`validate`, the check of every sample;
  :mod:`calib.io.validation_cache`: :func:`reuse_validation`, one check per file within a command;
* :mod:`calib.io.chunked_reading`: the samples in slices of whole file chunks (:func:`iter_raw_chunks`);
* :mod:`calib.io.in_memory`: :func:`load` (an ``xarray.Dataset``) and :func:`load_arrays` (numpy arrays, no
  xarray: a process that only checks or diagnoses a file never imports xarray and pandas);
* :mod:`calib.io.writing`: :func:`make_dataset`, :func:`write`, :class:`LongRecordingWriter`.

A name patched here (a test's monkeypatch) is not seen by the module that implements and calls it: patch it there.
"""
from calib.io.chunked_reading import iter_raw_chunks, open_slices, slice_bounds, time_chunk
from calib.io.header import (AXES, CLOCK_REL_TOL, CONVENTIONS, GRAVITY_RANGE_M_S2, LONG_FILE_SAMPLES,
                             SAMPLE_INTERVAL_START, SAMPLE_TIME_CONVENTIONS, SENSORS, TO_SI, UNITS, UNREADABLE_FIX,
                             Header, RecordingError, check_clock, declared_absent, read_header, require_sensors,
                             to_si, unit_factor)
from calib.io.in_memory import ArrayVariable, RecordingArrays, load, load_arrays
from calib.io.netcdf import fill_values
from calib.io.validation import validate
from calib.io.validation_cache import identity, remember_validated, reuse_validation
from calib.io.writing import LongRecordingWriter, make_dataset, write

__all__ = [
    # the format's names and units, its error, the header (calib.io.header)
    "AXES", "CLOCK_REL_TOL", "CONVENTIONS", "GRAVITY_RANGE_M_S2", "LONG_FILE_SAMPLES", "SAMPLE_INTERVAL_START",
    "SAMPLE_TIME_CONVENTIONS", "SENSORS", "TO_SI", "UNITS", "UNREADABLE_FIX", "Header", "RecordingError",
    "check_clock", "declared_absent", "read_header", "require_sensors", "to_si", "unit_factor",
    # the check of every sample and its memory (calib.io.validation, calib.io.validation_cache)
    "fill_values", "identity", "remember_validated", "reuse_validation", "validate",
    # reading in slices (calib.io.chunked_reading)
    "iter_raw_chunks", "open_slices", "slice_bounds", "time_chunk",
    # the two in-memory forms (calib.io.in_memory)
    "ArrayVariable", "RecordingArrays", "load", "load_arrays",
    # writing (calib.io.writing)
    "LongRecordingWriter", "make_dataset", "write",
]
