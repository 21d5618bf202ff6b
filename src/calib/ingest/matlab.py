"""MATLAB ``.mat`` files: v4/v5/v7 through :func:`scipy.io.loadmat`, v7.3 (HDF5) through h5py.

Variables are mapped in the settings as the column reader maps columns. Per triad (``accel``, ``gyro``; a triad
left out is a partial record, declared absent):

* ``variable``: one (n, 3) array (a stored 3 x n array is read transposed), or a wider (n, k) array with
  ``columns``: the three 0-based column indices in body-axis order x, y, z; or
* ``variables``: three variables, one (n,) vector per body axis x, y, z.

Names may reach into structs with dots (``data.acc``: field ``acc`` of the struct ``data``). ``time: {variable,
units: s|ms|us|ns}`` (its least-squares clock gives the rate; a declared ``sample_rate_hz`` is checked against
it) or ``sample_rate_hz`` (a number) or ``sample_rate_variable`` (a scalar variable of the file holding the rate in
Hz); optional ``temperature: {variable}`` [degC]. Units, sample kind, ``scale`` and ``sign`` as for every format
(:mod:`calib.ingest`).
"""
from __future__ import annotations

import numpy as np
import scipy.io
import xarray as xr

from calib.ingest.common import (
    TIME_UNITS,
    ImportDataError,
    check_finite_columns,
    check_keys,
    data_file,
    declared_rate,
    finish,
    number_setting,
    present_triads,
    serr,
    time_clock,
)

#: the settings keys of this format (besides :data:`calib.ingest.common.COMMON_KEYS`)
KEYS = {"file", "time", "sample_rate_hz", "sample_rate_variable", "temperature"}
#: a triad's keys of this format (besides :data:`calib.ingest.common.TRIAD_KEYS`)
TRIAD_KEYS = {"variable", "variables"}


class _MatFile:
    """The variables of a .mat file by (dotted) name, as float64 arrays in MATLAB's row and column order."""

    def __init__(self, path):
        self.path = path
        try:
            major, _ = scipy.io.matlab.matfile_version(str(path))
        except (ValueError, TypeError, OSError, scipy.io.matlab.MatReadError) as exc:
            if not _is_hdf5(path):   # (an HDF5 file without MATLAB's 128-byte header is read as v7.3)
                raise ImportDataError(path, "-", f"not a MATLAB .mat file ({exc})",
                                      "check the 'format' and 'file' settings (save it in MATLAB with save(..., "
                                      "'-v7') or '-v7.3')") from None
            major = 2
        self.version = "7.3 (HDF5)" if major == 2 else ("4" if major == 0 else "5/7")
        self._h5 = None
        if major == 2:
            import h5py  # only v7.3 files need it (HDF5); v4-v7 files are read by scipy

            try:
                self._h5 = h5py.File(path, "r")
            except OSError as exc:
                raise ImportDataError(path, "-", f"not a readable MATLAB v7.3 (HDF5) file ({exc})",
                                      "re-save or re-copy the file (truncated?)") from None
            self._vars = None
        else:
            try:
                self._vars = scipy.io.loadmat(str(path), simplify_cells=True)
            except (ValueError, TypeError, OSError, NotImplementedError, scipy.io.matlab.MatReadError) as exc:
                raise ImportDataError(path, "-", f"not a readable MATLAB .mat file ({type(exc).__name__}: {exc})",
                                      "re-save or re-copy the file (truncated?)") from None

    def close(self):
        if self._h5 is not None:
            self._h5.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def names(self, node=None, prefix="") -> list:
        """Every numeric variable's dotted name (struct fields included), for the messages."""
        node = (self._h5 if self._h5 is not None else self._vars) if node is None else node
        out = []
        for key in node.keys():
            if key.startswith("__") or key.startswith("#"):
                continue
            v = node[key]
            if isinstance(v, dict) or (self._h5 is not None and not hasattr(v, "shape")):
                out += self.names(v, f"{prefix}{key}.")
            else:
                out.append(f"{prefix}{key}")
        return out

    def get(self, name, field) -> np.ndarray:
        """The variable ``name`` (dotted: struct fields) as a float64 array; ``field``: the settings key naming it."""
        node = self._h5 if self._h5 is not None else self._vars
        for part in str(name).split("."):
            try:
                node = node[part]
            except (KeyError, TypeError, ValueError, IndexError):
                node = None
            if node is None:
                raise ImportDataError(self.path, name, f"no variable {name!r} (settings '{field}') in the file; it "
                                      f"holds: {', '.join(self.names()) or 'nothing numeric'}",
                                      f"correct '{field}' (struct fields as data.acc)")
        if self._h5 is not None:
            if not hasattr(node, "shape"):
                raise ImportDataError(self.path, name, "is a struct, not an array", f"name one of its fields in "
                                      f"'{field}' (e.g. {name}.{next(iter(node.keys()), 'x')})")
            raw = np.asarray(node[()])
            raw = raw.T   # HDF5 keeps MATLAB's column-major layout: dimensions read reversed
        else:
            if isinstance(node, dict):
                raise ImportDataError(self.path, name, "is a struct, not an array",
                                      f"name one of its fields in '{field}' (e.g. {name}.{next(iter(node), 'x')})")
            raw = np.asarray(node)
        if raw.dtype.kind not in "iufb":
            raise ImportDataError(self.path, name, f"holds {raw.dtype} values, not numbers",
                                  f"name a numeric variable in '{field}'")
        return np.asarray(raw, dtype=np.float64)


def _is_hdf5(path) -> bool:
    """Whether ``path`` is an HDF5 file (its signature at offset 0, 512, 1024, ...: where a user block ends)."""
    sig = b"\x89HDF\r\n\x1a\n"
    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
    return any(head[o:o + 8] == sig for o in [0] + [512 << k for k in range(8)])


def _vector(mat, name, field) -> np.ndarray:
    v = mat.get(name, field)
    if v.ndim > 1 and sum(d > 1 for d in v.shape) > 1:
        raise ImportDataError(mat.path, name, f"shape {v.shape}: one value per sample expected",
                              f"name a vector in '{field}'")
    return v.reshape(-1)


def _triad(settings, mat, tri):
    """``(samples (n, 3), description)`` of one triad's variables."""
    t = settings[tri]
    var, vars3, cols = t.get("variable"), t.get("variables"), t.get("columns")
    if (var is None) == (vars3 is None):
        raise serr(settings, f"{tri}.variable", "give either 'variable' (an n x 3 array, or n x k with 'columns') or "
                   "'variables' (three vectors x, y, z)", f"e.g. {tri}: {{variable: data.{tri}, ...}}")
    if vars3 is not None:
        if not isinstance(vars3, (list, tuple)) or len(vars3) != 3:
            raise serr(settings, f"{tri}.variables", f"value {vars3!r}: three variable names (x, y, z)")
        if cols is not None:
            raise serr(settings, f"{tri}.columns", "applies to 'variable' (one array), not to 'variables'",
                       "remove columns")
        vecs = [_vector(mat, v, f"{tri}.variables") for v in vars3]
        if len({len(v) for v in vecs}) != 1:
            raise ImportDataError(mat.path, f"{tri}.variables", f"lengths differ: {[len(v) for v in vecs]}",
                                  "the three variables must hold the same samples")
        return np.stack(vecs, axis=1), ", ".join(f"{ax}={v}" for ax, v in zip("xyz", vars3))
    a = mat.get(var, f"{tri}.variable")
    if a.ndim != 2:
        raise ImportDataError(mat.path, var, f"shape {a.shape}: a 2-D array (samples x axes) expected",
                              f"name an n x 3 array in '{tri}.variable', or three vectors in '{tri}.variables'")
    note = ""
    if cols is None:
        if a.shape[1] != 3 and a.shape[0] == 3:
            a, note = a.T, " (stored 3 x n: read transposed)"
        if a.shape[1] != 3:
            raise ImportDataError(mat.path, var, f"shape {a.shape}: three columns (x, y, z) expected",
                                  f"give '{tri}.columns': the three 0-based column indices of x, y, z")
        return a, f"{var}[:, 0:3]{note}"
    if not isinstance(cols, (list, tuple)) or len(cols) != 3 or \
            not all(isinstance(c, int) and not isinstance(c, bool) for c in cols):
        raise serr(settings, f"{tri}.columns", f"value {cols!r}: three 0-based column indices (x, y, z)")
    if any(c < 0 or c >= a.shape[1] for c in cols):
        raise serr(settings, f"{tri}.columns", f"indices {cols} but {var} has {a.shape[1]} columns (shape {a.shape})",
                   "columns are numbered from 0")
    return a[:, list(cols)], f"{var}[:, {list(cols)}]"


def import_matlab(settings) -> xr.Dataset:
    """MATLAB ``.mat`` (module docstring): ``file``; per triad ``variable`` (+ ``columns``) or ``variables``;
    ``time: {variable, units}`` and/or ``sample_rate_hz`` / ``sample_rate_variable``; ``temperature:
    {variable}``."""
    check_keys(settings, "matlab", KEYS, partial=True, triad_keys=TRIAD_KEYS)
    path = data_file(settings, "file")
    tris = present_triads(settings)
    tcfg = settings.get("time")
    if tcfg is not None and (not isinstance(tcfg, dict) or "variable" not in tcfg):
        raise serr(settings, "time", "needs {variable: name, units: s|ms|us|ns}")
    if "sample_rate_hz" in settings and "sample_rate_variable" in settings:
        raise serr(settings, "sample_rate_variable", "give sample_rate_hz or sample_rate_variable, not both")
    with _MatFile(path) as mat:
        triads, maps = {}, {}
        for tri in tris:
            triads[tri], maps[tri] = _triad(settings, mat, tri)
        n = {len(v) for v in triads.values()}
        if len(n) != 1:
            raise ImportDataError(path, "accel", f"the triads hold different numbers of samples "
                                  f"({', '.join(f'{k} {len(v)}' for k, v in triads.items())})",
                                  "map variables of the same recording")
        n = n.pop()
        time = None
        if tcfg is not None:
            tu = tcfg.get("units", "s")
            if tu not in TIME_UNITS:
                raise serr(settings, "time.units", f"value {tu!r}: one of {', '.join(TIME_UNITS)}")
            time = _vector(mat, tcfg["variable"], "time.variable") * TIME_UNITS[tu]
            if len(time) != n:
                raise ImportDataError(path, tcfg["variable"], f"{len(time)} time stamps for {n} samples",
                                      "map the time variable of the same recording")
        fs_decl = declared_rate(settings, required=False)
        if "sample_rate_variable" in settings:
            v = _vector(mat, settings["sample_rate_variable"], "sample_rate_variable")
            if v.size != 1:
                raise ImportDataError(path, settings["sample_rate_variable"], f"{v.size} values: one number (the "
                                      "sample rate in Hz) expected", "name a scalar in 'sample_rate_variable'")
            fs_decl = number_setting(settings, "sample_rate_variable", v[0])
        temperature = None
        if settings.get("temperature") is not None:
            temp = settings["temperature"]
            if not isinstance(temp, dict) or "variable" not in temp:
                raise serr(settings, "temperature", "needs {variable: name} (degC)")
            temperature = _vector(mat, temp["variable"], "temperature.variable")
            if len(temperature) != n:
                raise ImportDataError(path, temp["variable"], f"{len(temperature)} values for {n} samples",
                                      "map the temperature variable of the same recording")
        version = mat.version
    for tri, x in triads.items():
        check_finite_columns(path, x, [f"{tri} x", f"{tri} y", f"{tri} z"])
    if time is None and fs_decl is None:
        raise serr(settings, "sample_rate_hz", "required: no time variable mapped",
                   "declare sample_rate_hz (Hz), sample_rate_variable (a scalar of the file) or time: {variable: t}")
    clock_attrs = {}
    if time is not None:
        check_finite_columns(path, time[:, None], [str(tcfg["variable"])])
        fs, clk = time_clock(path, time, str(tcfg["variable"]), None, fs_decl, settings)
        clock_attrs = clk.attrs()
    else:
        fs = fs_decl
    if temperature is not None:
        check_finite_columns(path, temperature[:, None], [str(settings["temperature"]["variable"])])
    extra = {"matlab_version": version, **{f"{tri}_variable_map": m for tri, m in maps.items()}, **clock_attrs}
    return finish(settings, "matlab", path, triads.get("accel"), triads.get("gyro"), fs, time=time, sources=(path,),
                  temperature=temperature, extra=extra)
