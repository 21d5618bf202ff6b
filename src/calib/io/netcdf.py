"""The one place where ``calib`` writes netCDF.

Every netCDF file the project writes goes through :func:`write_netcdf` (small products) or
:class:`AtomicNetCDF` (long recordings written chunk by chunk). Both use the ``netcdf4`` engine and write
to a temporary name in the target directory (:mod:`calib.io.atomic`), renaming only when the file is
complete, so a failure never leaves a half-written file under the final name.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import subprocess
from pathlib import Path

import netCDF4
import xarray as xr

from calib.io.atomic import atomic_path, temp_path
from calib import __version__

ENGINE = "netcdf4"


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
    path = Path(path)
    ds = ds.copy()
    if prov:
        ds.attrs.update({k: v for k, v in prov.items() if v is not None})
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine=ENGINE)
    return path


class AtomicNetCDF:
    """Context manager giving a ``netCDF4.Dataset`` open for writing under a temporary name.

    On a clean exit the file is closed and renamed to ``path``; on an exception it is deleted.
    """

    def __init__(self, path):
        self.path = Path(path)
        self.tmp = temp_path(self.path)
        self.nc = None

    def __enter__(self) -> netCDF4.Dataset:
        try:
            self.nc = netCDF4.Dataset(self.tmp, "w", format="NETCDF4")
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                self.tmp.unlink()
            raise
        return self.nc

    def __exit__(self, exc_type, exc, tb):
        try:
            self.nc.close()
            if exc_type is None:
                os.replace(self.tmp, self.path)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                self.tmp.unlink()
            raise
        if exc_type is not None:
            with contextlib.suppress(FileNotFoundError):
                self.tmp.unlink()
        return False
