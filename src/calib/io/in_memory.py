"""A recording read whole into memory, in one of two forms.

:func:`load` gives an ``xarray.Dataset`` (selection, copies, writing: what the simulator, the studies and the
commands that make new recordings use). :func:`load_arrays` gives the same values as numpy arrays in a
:class:`RecordingArrays` read with netCDF4 alone: ``calib diagnose`` reads its file so and never imports xarray
and pandas. Both check the file first (:func:`calib.io.validation.validate`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calib.io.header import read_header, reading, unreadable
from calib.io.netcdf import attribute_fills, internal_units, string_values
from calib.io.validation import validate

if TYPE_CHECKING:   # imported by load only: a process that reads its file with load_arrays never imports xarray
    import xarray as xr


def load(path, validate_all: bool = True) -> xr.Dataset:
    """Load a (small) recording fully into memory as an ``xarray.Dataset`` after validating it.

    Long files without a time coordinate get one computed from ``t0_s`` and ``sample_rate_hz``.
    """
    import xarray as xr   # optional heavy import: only a caller of load pays for xarray and pandas

    h = validate(path) if validate_all else read_header(path)
    try:
        with xr.open_dataset(path, engine="netcdf4") as ds:
            ds = ds.load()
    except Exception as exc:  # noqa: BLE001 - a corrupted file fails anywhere inside the library
        raise unreadable(path, exc) from exc
    if "time" not in ds.coords:
        ds = ds.assign_coords(time=h.sample_times())
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
    fills = attribute_fills(var)
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
    with reading(path) as nc:
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
    if "time" not in variables:
        variables["time"] = ArrayVariable(h.sample_times(), {}, ("time",))
    attrs["_path"] = str(path)
    return RecordingArrays(attrs, variables, sizes)
