"""IMU-TK's two text files (accelerometer and gyroscope, shared time stamps)."""
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
    parse_numeric,
    read_table,
    serr,
    time_clock,
)

#: the settings keys of this format (besides :data:`calib.ingest.common.COMMON_KEYS`)
KEYS = {"files", "sample_rate_hz"}


def import_imu_tk(settings) -> xr.Dataset:
    """IMU-TK text pair: ``files: {accel: ..., gyro: ...}``, each row ``timestamp_s x y z`` (whitespace).

    The two files must hold the same timestamps row for row. Time is kept as in the files (seconds).
    The rate is the least-squares clock of the timestamps (:func:`calib.core.clock.fit_clock`; stored with
    its uncertainty, jitter and dropped samples as ``clock_*`` attributes); ``sample_rate_hz`` (optional) is the
    nominal rate, checked against it (:func:`calib.ingest.common.time_clock`). Units/kind from ``accel``/``gyro`` (raw Xsens: count, rate).
    """
    check_keys(settings, "imu_tk", KEYS)
    files = settings.get("files")
    if not isinstance(files, dict) or set(files) != {"accel", "gyro"}:
        raise serr(settings, "files", "needs exactly the two entries accel and gyro",
                    "files: {accel: xsens_acc.mat, gyro: xsens_gyro.mat}")
    for tri in ("accel", "gyro"):
        if settings[tri].get("columns") is not None:
            raise serr(settings, f"{tri}.columns", "the IMU-TK layout is fixed (timestamp x y z)",
                        "remove columns, or use format: columns")
    pa, pg = data_file(settings, "files.accel", files["accel"]), data_file(settings, "files.gyro", files["gyro"])
    tables = {}
    for key, p in (("accel", pa), ("gyro", pg)):
        _, lines, numbers = read_table(p, delimiter=None, n_fields=4)
        data = parse_numeric(p, lines, numbers, [0, 1, 2, 3], None, None)
        check_finite_columns(p, data, ["timestamp", f"{key} x", f"{key} y", f"{key} z"], numbers)
        tables[key] = (data, numbers)
    (a, na), (g, ng) = tables["accel"], tables["gyro"]
    if len(a) != len(g):
        raise ImportDataError(f"{pa} / {pg}", "timestamp", f"row counts differ: {len(a)} accel rows, "
                              f"{len(g)} gyro rows", "the two files must come from the same session, row for row")
    diff = np.flatnonzero(a[:, 0] != g[:, 0])
    if diff.size:
        i = int(diff[0])
        raise ImportDataError(f"{pa} / {pg}", "timestamp", f"timestamps differ from row {i + 1} on "
                              f"(accel line {na[i]}: {a[i, 0]!r} s, gyro line {ng[i]}: {g[i, 0]!r} s; "
                              f"{diff.size} rows differ)", "the two files must share their timestamps row for row")
    t = a[:, 0]
    fs, clk = time_clock(pa, t, "timestamp", na, declared_rate(settings, required=False), settings)
    return finish(settings, "imu_tk", pa, a[:, 1:], g[:, 1:], fs, time=t, sources=(pa, pg), extra=clk.attrs())
