"""The one place where ``calib`` writes netCDF.

Every netCDF file the project writes goes through :func:`write_netcdf` (small products) or
:class:`AtomicNetCDF` (long recordings written chunk by chunk). Both use the ``netcdf4`` engine and write
to a temporary name in the target directory (:mod:`calib.io.atomic`), renaming only when the file is
complete, so a failure never leaves a half-written file under the final name.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING

import netCDF4
import numpy as np

from calib.io.atomic import atomic_path, utf8_name
from calib import __version__

if TYPE_CHECKING:   # xarray is imported by the functions that use it: a process that only checks files never does
    import xarray as xr

ENGINE = "netcdf4"
#: the CF version every file declares in its ``Conventions`` attribute (with the file's own format after it)
CF_VERSION = "CF-1.11"
#: CF (UDUNITS-2) spelling of the unit strings used inside calib; files carry the CF spelling
CF_UNITS = {"deg": "degree", "deg s-1": "degree s-1", "deg h-1": "degree h-1", "deg s-2": "degree s-2"}
FROM_CF_UNITS = {v: k for k, v in CF_UNITS.items()}


def internal_units(units):
    """The unit string calib uses internally for a unit read from a file (``degree s-1`` -> ``deg s-1``)."""
    return FROM_CF_UNITS.get(units, units) if isinstance(units, str) else units


def conventions(attrs) -> str:
    """The file's own format named in its ``Conventions`` attribute (``CF-1.8 calib-recording-1`` ->
    ``calib-recording-1``), or the legacy lower-case ``conventions`` attribute of earlier files; '' if none."""
    conv = attrs.get("Conventions", attrs.get("conventions", ""))
    names = [c for c in re.split(r"[ ,]+", str(conv)) if c and not c.startswith("CF-")]
    return names[0] if names else ""


def float_values(var, index=slice(None)) -> np.ndarray:
    """A netCDF variable's values as float64, decoded by netCDF4: ``scale_factor`` / ``add_offset`` applied and the
    samples marked missing (``_FillValue``, ``missing_value``) as NaN, as xarray decodes them -- and, unlike
    xarray, also a sample equal to the library's default fill (no ``_FillValue`` attribute) or outside a
    ``valid_range`` / ``valid_min`` / ``valid_max`` as NaN. For the checks that read a few variables without xarray
    (:func:`calib.io.recording.validate`): a process that only checks a file does not import xarray and pandas
    (0.3 s). ``index``: the part to read (default: all)."""
    return np.ma.filled(np.ma.asarray(var[index], dtype=np.float64), np.nan)


def index_values(var, index=slice(None), missing: int = -1) -> np.ndarray:
    """An integer netCDF variable's values in their own integer type (no float copy: a segment index of a long
    recording is one value per sample), the samples marked missing as ``missing`` (-1: no segment). ``index``: the
    part to read (default: all)."""
    v = var[index]
    return np.ma.filled(v, missing) if np.ma.is_masked(v) else np.asarray(np.ma.getdata(v))


def string_values(var) -> list:
    """A netCDF string variable's values as a list of ``str`` (variable-length strings, or a character array with
    an ``_Encoding`` attribute, as xarray decodes them)."""
    return [str(v) for v in var[:]]


def attribute_fills(var) -> list:
    """The values of a netCDF variable's ``_FillValue`` and ``missing_value`` attributes (those xarray masks)."""
    return [v for name in ("_FillValue", "missing_value") if name in var.ncattrs()
            for v in np.atleast_1d(var.getncattr(name)).tolist()]


def fill_values(var) -> list:
    """The values that mark a missing sample of a netCDF variable: ``_FillValue`` and ``missing_value``, or
    (no ``_FillValue`` attribute) the library's default fill of a 32- or 64-bit type (that of an 8- or 16-bit
    type, e.g. -32767, is a reading a clipped sensor can give); NaN fills left out (NaN is refused as such)."""
    out = attribute_fills(var)
    if "_FillValue" not in var.ncattrs() and np.dtype(var.dtype).itemsize >= 4:
        fv = var.get_fill_value()
        if fv is not None:
            out.append(fv.item() if hasattr(fv, "item") else fv)
    return [v for v in out if not (isinstance(v, float) and math.isnan(v))]


def cf_dataset(ds: xr.Dataset) -> xr.Dataset:
    """``ds`` as written: a ``Conventions`` attribute (CF plus the file's own format) and CF unit spellings."""
    ds = ds.copy()
    own = conventions(ds.attrs)
    ds.attrs.pop("conventions", None)
    ds.attrs["Conventions"] = f"{CF_VERSION} {own}" if own else CF_VERSION
    for name in list(ds.variables):
        v = ds[name]
        u = v.attrs.get("units")
        if isinstance(u, str) and u in CF_UNITS:
            v.attrs["units"] = CF_UNITS[u]
    return ds


def git_commit() -> str:
    """Commit hash of the source tree this package runs from, or 'unknown'."""
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5)
        if out.returncode == 0:
            return out.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return "unknown"


def config_hash(cfg) -> str:
    """SHA-256 (first 16 hex digits) of a JSON-serialisable configuration, key order independent."""
    blob = json.dumps(cfg, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def provenance(rule: str = "", cfg=None, seed=None) -> dict:
    """Provenance attributes carried by every scientific netCDF file."""

    attrs = {"calib_version": __version__, "git_commit": git_commit(), "made_by_rule": rule or "cli"}
    if cfg is not None:
        attrs["config_hash"] = config_hash(cfg)
    if seed is not None:
        attrs["seed"] = int(seed)
    return attrs


def write_netcdf(ds: xr.Dataset, path, prov: dict | None = None) -> Path:
    """Write ``ds`` to ``path`` atomically (temporary name, then rename) with the fixed engine."""
    path = utf8_name(path, "netCDF output")
    ds = cf_dataset(ds)
    if prov is None and "calib_version" not in ds.attrs:
        prov = provenance()
    if prov:
        ds.attrs.update({k: v for k, v in prov.items() if v is not None})
    encoding = {c: {"_FillValue": None} for c in ds.coords if ds[c].dtype.kind == "f"}
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine=ENGINE, encoding=encoding)
    return path


class AtomicNetCDF:
    """Context manager giving a ``netCDF4.Dataset`` open for writing under a temporary name
    (:func:`calib.io.atomic.atomic_path`: created on entry, never before).

    On a clean exit the file is closed and renamed to ``path``; on an exception it is deleted.
    """

    def __init__(self, path):
        self.path = utf8_name(path, "netCDF output")
        self.nc = None
        self._file = None

    def __enter__(self) -> netCDF4.Dataset:
        self._file = atomic_path(self.path)
        tmp = self._file.__enter__()
        try:
            self.nc = netCDF4.Dataset(tmp, "w", format="NETCDF4")
        except BaseException as exc:
            self._file.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self.nc

    def __exit__(self, exc_type, exc, tb):
        try:
            self.nc.close()
        except BaseException as err:
            self._file.__exit__(type(err), err, err.__traceback__)
            raise
        return self._file.__exit__(exc_type, exc, tb)
