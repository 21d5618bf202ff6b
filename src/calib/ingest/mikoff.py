"""mikoff/imu-calib logs: six numbers a row (ax ay az gx gy gz), no header, no time."""
from __future__ import annotations

import xarray as xr

from calib.ingest.common import (
    check_finite_columns,
    check_keys,
    data_file,
    declared_rate,
    finish,
    parse_numeric,
    read_table,
    serr,
)

#: the settings keys of this format (besides :data:`calib.ingest.common.COMMON_KEYS`)
KEYS = {"file", "sample_rate_hz"}


def import_mikoff(settings) -> xr.Dataset:
    """mikoff/imu-calib log: six whitespace-separated numbers a row, no header, no time:
    ``ax ay az gx gy gz``. ``sample_rate_hz`` required; units declared in ``accel``/``gyro`` (the data are
    m s-2 and rad s-1)."""
    check_keys(settings, "mikoff", KEYS)
    path = data_file(settings, "file")
    fs = declared_rate(settings)
    names = ["ax", "ay", "az", "gx", "gy", "gz"]
    for tri in ("accel", "gyro"):
        if settings[tri].get("columns") is not None:
            raise serr(settings, f"{tri}.columns", "the mikoff layout is fixed (ax ay az gx gy gz)",
                        "remove columns, or use format: columns")
    _, lines, numbers = read_table(path, delimiter=None, n_fields=6)
    data = parse_numeric(path, lines, numbers, list(range(6)), names, None)
    check_finite_columns(path, data, names, numbers)
    return finish(settings, "mikoff", path, data[:, :3], data[:, 3:], fs, sources=(path,))
