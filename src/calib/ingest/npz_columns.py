"""NumPy ``.npz`` files with a 2-D data array and its column names."""
from __future__ import annotations

import numpy as np
import xarray as xr

from calib.ingest.common import (
    ImportDataError,
    check_finite_columns,
    check_keys,
    data_file,
    declared_rate,
    finish,
    present_triads,
    serr,
)

#: the settings keys of this format (besides :data:`calib.ingest.common.COMMON_KEYS`)
KEYS = {"file", "sample_rate_hz", "data_key", "columns_key"}


def import_npz_columns(settings) -> xr.Dataset:
    """NumPy ``.npz`` with a 2-D ``data`` array and a ``columns`` array of names (keys configurable by
    ``data_key`` / ``columns_key``). ``accel.columns`` / ``gyro.columns`` name the three columns of each triad
    in body-axis order; ``sample_rate_hz`` required. Loaded with ``allow_pickle=False``."""
    check_keys(settings, "npz_columns", KEYS, partial=True)
    path = data_file(settings, "file")
    fs = declared_rate(settings)
    dk, ck = settings.get("data_key", "data"), settings.get("columns_key", "columns")
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ImportDataError(path, "-", f"not a readable .npz ({exc})", "check the file (truncated?)") from None
    with z:
        for key in (dk, ck):
            if key not in z.files:
                raise ImportDataError(path, key, f"array missing (the file holds {z.files})",
                                      "set data_key / columns_key")
        try:
            data = np.asarray(z[dk], dtype=np.float64)
            names = [str(c) for c in z[ck]]
        except (OSError, ValueError, EOFError) as exc:
            raise ImportDataError(path, dk, f"array unreadable ({exc})", "the file is damaged: re-copy it") from None
    if data.ndim != 2 or data.shape[1] != len(names):
        raise ImportDataError(path, ck, f"{len(names)} column names for data of shape {data.shape}",
                              "the file's data and columns arrays do not match")
    cols = {}
    tris = present_triads(settings)   # one of them: a partial record
    for tri in tris:
        c = settings[tri].get("columns")
        if not isinstance(c, (list, tuple)) or len(c) != 3:
            raise serr(settings, f"{tri}.columns", f"value {c!r}: three column names (x, y, z)")
        for name in c:
            if name not in names:
                raise ImportDataError(path, ck, f"column {name!r} (settings '{tri}.columns') not among {names}",
                                      "correct the column names in the settings")
        cols[tri] = [names.index(name) for name in c]
    use = [c for tri in tris for c in cols[tri]]
    sub = data[:, use]
    check_finite_columns(path, sub, [names[i] for i in use])
    triads = {tri: sub[:, 3 * j:3 * j + 3] for j, tri in enumerate(tris)}
    return finish(settings, "npz_columns", path, triads.get("accel"), triads.get("gyro"), fs, sources=(path,))
