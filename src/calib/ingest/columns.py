"""Generic delimited text tables with named or numbered columns."""
from __future__ import annotations

import numpy as np
import xarray as xr

from calib.ingest.common import (
    TIME_UNITS,
    check_finite_columns,
    check_keys,
    column_index,
    data_file,
    declared_rate,
    finish,
    present_triads,
    parse_numeric,
    read_table,
    serr,
    split_fields,
    time_clock,
    triad_settings,
)

#: the settings keys of this format (besides :data:`calib.ingest.common.COMMON_KEYS`)
KEYS = {"file", "delimiter", "header", "comment", "skip_rows", "time", "sample_rate_hz", "temperature"}


def _table_triads(settings, path, names, n_cols):
    out = {}
    for tri in present_triads(settings):
        cols = settings[tri].get("columns")
        if not isinstance(cols, (list, tuple)) or len(cols) != 3:
            raise serr(settings, f"{tri}.columns", f"value {cols!r}: three column names or 0-based indices (x, y, z)")
        out[tri] = [column_index(path, settings, f"{tri}.columns", c, names) for c in cols]
        for c in out[tri]:
            if c >= n_cols:
                raise serr(settings, f"{tri}.columns", f"column index {c} but the file has {n_cols} columns")
    return out


def import_columns(settings) -> xr.Dataset:
    """Generic delimited text: ``file``, ``delimiter`` (null = whitespace), ``header`` (bool),
    ``comment`` (line prefix), ``skip_rows``; ``accel.columns`` / ``gyro.columns``: three names (with a
    header) or 0-based indices, in body-axis order x, y, z (a permutation remaps axes; ``sign`` flips them);
    ``time: {column, units: s|ms|us|ns}`` and/or ``sample_rate_hz`` (at least one; with a time column the rate
    is its least-squares clock, :func:`calib.core.clock.fit_clock`, and a declared rate is checked against it);
    optional ``temperature: {column}`` [degC]. Every row must have the header's (or the first row's)
    number of fields.
    """
    check_keys(settings, "columns", KEYS, partial=True)
    path = data_file(settings, "file")
    delim = settings.get("delimiter")
    header = bool(settings.get("header", False))
    names, lines, numbers = read_table(path, delimiter=delim, header=header, comment=settings.get("comment"),
                                        skip_rows=int(settings.get("skip_rows", 0)))
    n_cols = len(names) if names else len(split_fields(lines[0], delim))
    cols = _table_triads(settings, path, names, n_cols)
    tris = list(cols)   # the declared triads (one of them: a partial record)
    use = [c for tri in tris for c in cols[tri]]
    tcfg, tcol = settings.get("time"), None
    if tcfg is not None:
        if not isinstance(tcfg, dict) or "column" not in tcfg:
            raise serr(settings, "time", "needs {column: name or index, units: s|ms|us|ns}")
        tu = tcfg.get("units", "s")
        if tu not in TIME_UNITS:
            raise serr(settings, "time.units", f"value {tu!r}: one of {', '.join(TIME_UNITS)}")
        tcol = column_index(path, settings, "time.column", tcfg["column"], names)
        use.append(tcol)
    temp_col = None
    if settings.get("temperature") is not None:
        temp = settings["temperature"]
        if not isinstance(temp, dict) or "column" not in temp:
            raise serr(settings, "temperature", "needs {column: name or index} (degC)")
        temp_col = column_index(path, settings, "temperature.column", temp["column"], names)
        use.append(temp_col)
    data = parse_numeric(path, lines, numbers, use, names, delim)
    labels = [names[c] if names else f"column {c}" for c in use]
    check_finite_columns(path, data, labels, numbers)
    triads = {tri: data[:, 3 * j:3 * j + 3] for j, tri in enumerate(tris)}
    accel, gyro = triads.get("accel"), triads.get("gyro")
    fs_decl = declared_rate(settings, required=tcol is None)
    time, clock_attrs = None, {}
    if tcol is not None:
        jt = 3 * len(tris)
        time = data[:, jt] * TIME_UNITS[settings["time"].get("units", "s")]
        fs, clk = time_clock(path, time, labels[jt], numbers, fs_decl, settings)
        clock_attrs = clk.attrs()
    else:
        fs = fs_decl
    temperature = data[:, -1] if temp_col is not None else None
    mapping = {f"{tri}_column_map": ", ".join(f"{ax}={int(np.sign(f)):+d}*{abs(f):g}*{labels[j]}"
                                              for ax, f, j in zip("xyz", triad_settings(settings, tri)["factor"],
                                                                  range(3 * k, 3 * k + 3)))
               for k, tri in enumerate(tris)}
    return finish(settings, "columns", path, accel, gyro, fs, time=time, sources=(path,), temperature=temperature,
                   extra={**mapping, **clock_attrs})
