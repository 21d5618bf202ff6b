"""The dispatch: format name -> importer; :func:`import_recording` imports and writes atomically.

A new format is one module (``import_<format>(settings) -> xarray.Dataset`` and its settings ``KEYS``, checked
with :func:`calib.ingest.common.check_keys`) plus one entry in :data:`IMPORTERS`."""
from __future__ import annotations

from pathlib import Path

import xarray as xr

from calib.io import recording
from calib.io.netcdf import provenance
from calib.ingest.common import ImportDataError, default_data_root, load_settings, serr  # noqa: F401
from calib.ingest.columns import import_columns
from calib.ingest.imu_tk import import_imu_tk
from calib.ingest.imucal import import_imucal
from calib.ingest.matlab import import_matlab
from calib.ingest.mikoff import import_mikoff
from calib.ingest.npz_columns import import_npz_columns
from calib.ingest.rosbag import import_rosbag

#: format name (the settings' ``format``) -> its importer
IMPORTERS = {"imu_tk": import_imu_tk, "imucal": import_imucal, "mikoff": import_mikoff,
             "npz_columns": import_npz_columns, "columns": import_columns, "rosbag": import_rosbag,
             "matlab": import_matlab}
FORMATS = tuple(IMPORTERS)


def import_dataset(settings: dict) -> xr.Dataset:
    """Dispatch on ``settings['format']`` and return the in-memory ``calib-recording-1`` dataset."""
    fmt = settings.get("format")
    if fmt not in IMPORTERS:
        raise serr(settings, "format", f"value {fmt!r} unknown", f"one of: {', '.join(IMPORTERS)}")
    return IMPORTERS[fmt](settings)


def import_recording(settings: dict, out_path, prov: dict | None = None) -> Path:
    """Import per ``settings`` and write ``out_path`` atomically (validated after writing).

    ``prov``: provenance attributes; default :func:`calib.io.netcdf.provenance` ('import', the settings).
    """
    ds = import_dataset(settings)
    if prov is None:
        prov = provenance("import", {k: v for k, v in settings.items() if not k.startswith("_")})
    return recording.write(ds, out_path, prov)
