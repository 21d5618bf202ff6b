"""Import recordings made elsewhere into ``calib-recording-1`` (see :mod:`calib.io.recording`).

One function per source format, each ``import_<format>(settings) -> xarray.Dataset``; :func:`import_recording`
dispatches on ``settings['format']`` and writes atomically with :func:`calib.io.recording.write` (a failed import
never leaves a file under the output name). Settings are plain dicts, normally read from
``config/import/*.yaml`` with :func:`load_settings`.

Nothing is guessed: units, sample kind, sample rate, site latitude, axis signs and the sense of hand-made
turns come from the settings (or the file, where it says so). What *can* be checked against the data is:

* accel units: the median accel norm over the quietest quarter of the record must be within
  ``units_check_tolerance`` (default 20 %) of local gravity in the declared units (1 g = 9.80665 m s-2);
  for counts only when ``accel.approx_counts_per_g`` is given;
* gyro units: peak rate below 5000 deg/s; and for labelled turns the integrated angle about the labelled
  axis must have the declared sign and be within 25 % of the declared angle (counts: only with
  ``gyro.approx_counts_per_deg_s``);
* structure: every row complete (a short last row means a truncated file), no NaN/Inf, header names as
  declared, time strictly increasing and consistent with a declared rate, the two IMU-TK files sharing
  their timestamps row for row.

Every failure raises :class:`ImportDataError` (a :class:`calib.io.recording.RecordingError`, hence a
``ValueError``) naming the file, the field and the fix.

Settings keys
-------------
Common to all formats:

``format`` (required)
    ``imu_tk`` | ``imucal`` | ``mikoff`` | ``npz_columns`` | ``columns``.
``latitude_deg`` (required), ``height_m`` (default 0), ``gravity_m_s2`` (optional local gravity, m s-2)
    Site; stored as global attributes. ``site_note``: free text on where the site values come from.
``sensor``, ``description``: free text stored as attributes.
``data_dir``: directory the file names are relative to (default: :func:`default_data_root`, i.e. ``$CALIB_DATA``
or the shared data folder ``../shared/data`` beside the repository); a relative ``data_dir`` is taken relative to the
    settings file's directory (:func:`load_settings`) or, for a dict built in code, the working directory.
``accel``, ``gyro`` (required): triad declarations, keys
    ``units`` (required; one of :data:`calib.io.recording.UNITS` for the kind), ``sample_kind`` (required:
    ``rate`` | ``increment``), ``columns`` (format dependent), ``scale`` (number or 3 numbers, default 1),
    ``sign`` (3 of +1/-1, default +1): stored value = sign * scale * raw, per body axis x, y, z (with
    ``columns`` this also remaps axes, e.g. to make a left-handed frame right-handed -- declared, never
    inferred); ``approx_counts_per_g`` (accel in counts: enables the gravity-norm check),
    ``approx_zero_count`` (accel counts at zero input, for that check only, default 0),
    ``approx_counts_per_deg_s`` (gyro in counts: enables the turn-angle check).
``units_check_tolerance``: relative tolerance of the gravity-norm check (default 0.2).

Per format (see each function for details): ``imu_tk``: ``files: {accel, gyro}``, ``sample_rate_hz``
(optional nominal rate, checked against the timestamps). ``imucal``: ``file``, ``segments_file`` or
``label_column``, ``sample_column``, ``sample_rate_hz``, ``rotation: {angle_deg, sign, rate_deg_s}``,
``labels``. ``mikoff``: ``file``, ``sample_rate_hz``. ``npz_columns``: ``file``, ``sample_rate_hz``,
``data_key``, ``columns_key``. ``columns``: ``file``, ``delimiter``, ``header``, ``comment``,
``skip_rows``, ``time: {column, units}`` or ``sample_rate_hz``, ``temperature: {column}``.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import re
from pathlib import Path

import numpy as np
import xarray as xr

from calib.core import earth
from calib.io import recording
from calib.signal.detect import moving_variance_norm, window_samples
from calib.io.recording import RecordingError

FORMATS = ("imu_tk", "imucal", "mikoff", "npz_columns", "columns")

COMMON_KEYS = {"format", "latitude_deg", "height_m", "gravity_m_s2", "site_note", "sensor", "description",
               "data_dir", "accel", "gyro", "units_check_tolerance"}
FORMAT_KEYS = {
    "imu_tk": {"files", "sample_rate_hz"},
    "imucal": {"file", "segments_file", "label_column", "sample_column", "sample_rate_hz", "rotation", "labels"},
    "mikoff": {"file", "sample_rate_hz"},
    "npz_columns": {"file", "sample_rate_hz", "data_key", "columns_key"},
    "columns": {"file", "delimiter", "header", "comment", "skip_rows", "time", "sample_rate_hz", "temperature"},
}
TRIAD_KEYS = {"units", "sample_kind", "columns", "scale", "sign", "approx_counts_per_g", "approx_zero_count",
              "approx_counts_per_deg_s"}
ROTATION_KEYS = {"angle_deg", "sign", "rate_deg_s"}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
MAX_GYRO_DEG_S = 5000.0  # no MEMS or tactical gyro in this project's scope measures faster
TURN_TOLERANCE = 0.25  # relative, on the integrated angle of a labelled turn


class ImportDataError(RecordingError):
    """An import that cannot proceed; names the file (or settings file), the field and the fix."""


def _settings_name(settings) -> str:
    return settings.get("_source", "<import settings>")


def _serr(settings, key, problem, fix=""):
    return ImportDataError(_settings_name(settings), key, problem, fix)


# --------------------------------------------------------------------------- settings


def load_settings(path) -> dict:
    """Read an import-settings YAML; relative ``data_dir`` is then resolved against the file's directory."""
    import yaml

    path = Path(path)
    if not path.exists():
        raise ImportDataError(path, "-", "import settings file not found")
    with open(path) as fh:
        s = yaml.safe_load(fh)
    if not isinstance(s, dict):
        raise ImportDataError(path, "-", "import settings must be a YAML mapping")
    s["_source"] = str(path)
    s["_base_dir"] = str(path.resolve().parent)
    return s


def _check_keys(settings, fmt):
    allowed = COMMON_KEYS | FORMAT_KEYS[fmt]
    for key in settings:
        if key.startswith("_"):
            continue
        if key not in allowed:
            raise _serr(settings, key, f"unknown key for format '{fmt}'",
                        f"remove it or correct the spelling (allowed: {', '.join(sorted(allowed))})")
    for tri in ("accel", "gyro"):
        t = settings.get(tri)
        if not isinstance(t, dict):
            raise _serr(settings, tri, "triad declaration missing or not a mapping",
                        f"declare {tri}: {{units: ..., sample_kind: rate|increment}}")
        for key in t:
            if key not in TRIAD_KEYS:
                raise _serr(settings, f"{tri}.{key}", "unknown key",
                            f"allowed: {', '.join(sorted(TRIAD_KEYS))}")


def default_data_root() -> Path:
    """Where recordings named by import settings without ``data_dir`` are looked for: the environment variable
    ``CALIB_DATA`` if set, else the shared data folder beside the repository (``<repo>/../shared/data``)."""
    env = os.environ.get("CALIB_DATA")
    if env:
        return Path(env).expanduser()
    repo = Path(__file__).resolve().parents[3]
    base = repo if (repo / "pyproject.toml").exists() else Path.cwd()
    return (base / ".." / "shared" / "data").resolve()


def _data_dir(settings) -> Path:
    if "data_dir" not in settings:
        return default_data_root()
    d = Path(settings["data_dir"])
    if not d.is_absolute():
        d = Path(settings.get("_base_dir", Path.cwd())) / d
    return d


def _file(settings, key, value=None) -> Path:
    name = settings.get(key) if value is None else value
    if not name:
        raise _serr(settings, key, "file name missing", f"give '{key}' relative to data_dir or absolute")
    p = Path(name)
    if not p.is_absolute():
        p = (_data_dir(settings) / p).resolve()
    if not p.exists():
        raise ImportDataError(p, key, "input file not found",
                              f"check '{key}' and data_dir (resolved to {_data_dir(settings)})")
    return p


def _number(settings, key, value, positive=True):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise _serr(settings, key, f"value {value!r} is not a number") from None
    if not math.isfinite(v) or (positive and v <= 0):
        raise _serr(settings, key, f"value {v} must be a finite{' positive' if positive else ''} number")
    return v


def _rate(settings, required=True):
    if "sample_rate_hz" not in settings:
        if required:
            raise _serr(settings, "sample_rate_hz", "required: the file holds no timestamps",
                        "declare the sample rate in Hz")
        return None
    return _number(settings, "sample_rate_hz", settings["sample_rate_hz"])


def _site(settings):
    if "latitude_deg" not in settings:
        raise _serr(settings, "latitude_deg", "required (the recording holds no site)",
                    "declare the site latitude in degrees (north positive)")
    lat = _number(settings, "latitude_deg", settings["latitude_deg"], positive=False)
    if not -90.0 <= lat <= 90.0:
        raise _serr(settings, "latitude_deg", f"value {lat} outside [-90, 90]")
    h = _number(settings, "height_m", settings.get("height_m", 0.0), positive=False)
    g = settings.get("gravity_m_s2")
    if g is not None:
        g = _number(settings, "gravity_m_s2", g)
        if not 9.7 < g < 9.9:
            raise _serr(settings, "gravity_m_s2", f"value {g} m s-2 is not a local gravity on Earth",
                        "give local gravity in m s-2 (about 9.78-9.83)")
    return lat, h, g


def _triad(settings, name):
    t = settings[name]
    kind = t.get("sample_kind")
    if kind not in ("rate", "increment"):
        raise _serr(settings, f"{name}.sample_kind", f"value {kind!r}: declare 'rate' or 'increment'")
    units = t.get("units")
    allowed = recording.UNITS[(name, kind)]
    if units not in allowed:
        raise _serr(settings, f"{name}.units", f"value {units!r} not allowed for sample_kind={kind!r}",
                    f"declare one of: {', '.join(allowed)}")
    scale = t.get("scale", 1.0)
    scale = np.broadcast_to(np.asarray(scale, dtype=float), (3,)).copy() if np.ndim(scale) == 0 else \
        np.asarray(scale, dtype=float)
    if scale.shape != (3,) or not np.all(np.isfinite(scale)) or np.any(scale == 0):
        raise _serr(settings, f"{name}.scale", f"value {t.get('scale')!r}: one or three finite non-zero numbers")
    sign = np.asarray(t.get("sign", [1, 1, 1]), dtype=float)
    if sign.shape != (3,) or not np.all(np.isin(sign, (-1.0, 1.0))):
        raise _serr(settings, f"{name}.sign", f"value {t.get('sign')!r}: three of +1 / -1 (x, y, z)")
    out = {"units": units, "kind": kind, "factor": sign * scale, "columns": t.get("columns")}
    for key in ("approx_counts_per_g", "approx_counts_per_deg_s"):
        if key in t:
            out[key] = _number(settings, f"{name}.{key}", t[key])
    out["approx_zero_count"] = _number(settings, f"{name}.approx_zero_count", t.get("approx_zero_count", 0.0),
                                       positive=False)
    return out


def _display_name(settings, path) -> str:
    """Source file name as stored in attributes: relative to data_dir when inside it (machine independent)."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(_data_dir(settings).resolve()))
    except ValueError:
        return str(p)


def _sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for blk in iter(lambda: fh.read(1 << 20), b""):
            h.update(blk)
    return h.hexdigest()


# --------------------------------------------------------------------------- text tables


def _split(line, delimiter):
    return line.split() if delimiter is None else [f.strip() for f in line.split(delimiter)]


def _read_table(path, *, delimiter=None, header=False, comment=None, skip_rows=0, n_fields=None,
                field="row"):
    """Read a delimited text table: returns (names or None, data lines, their 1-based line numbers).

    Checks that every data row has the same number of fields as the header (or ``n_fields``, or the first
    row); a short last row is reported as a truncated file.
    """
    try:
        text = Path(path).read_text()
    except UnicodeDecodeError:
        raise ImportDataError(path, "-", "not a text file", "check the 'format' setting") from None
    lines = text.splitlines()
    keep, numbers = [], []
    for i, line in enumerate(lines[skip_rows:], start=skip_rows + 1):
        s = line.strip()
        if not s or (comment and s.startswith(comment)):
            continue
        keep.append(s)
        numbers.append(i)
    names = None
    if header:
        if not keep:
            raise ImportDataError(path, "header", "file is empty", "check the file")
        names = [n.strip().strip('"').strip("'") for n in _split(keep[0], delimiter)]
        keep, numbers = keep[1:], numbers[1:]
        n_fields = n_fields or len(names)
    if not keep:
        raise ImportDataError(path, field, "no data rows", "check the file and skip_rows/comment settings")
    counts = np.fromiter((len(_split(s, delimiter)) for s in keep), dtype=np.int64, count=len(keep))
    expected = int(n_fields or counts[0])
    bad = np.flatnonzero(counts != expected)
    if bad.size:
        i = int(bad[0])
        if i == len(keep) - 1 and counts[i] < expected:
            raise ImportDataError(path, field, f"last row (line {numbers[i]}) has {counts[i]} of {expected} fields: "
                                  "file truncated", "re-export or re-copy the file (or delete the incomplete last "
                                  "line if the loss is acceptable)")
        raise ImportDataError(path, field, f"line {numbers[i]} has {counts[i]} fields, expected {expected}",
                              "check the 'delimiter' setting and the file")
    return names, keep, numbers


def _parse_numeric(path, lines, numbers, cols, names, delimiter):
    """Parse the given column indices of the data lines as float64 (n, len(cols))."""
    try:
        return np.loadtxt(lines, delimiter=delimiter, usecols=cols, dtype=np.float64, ndmin=2)
    except ValueError:
        pass
    for s, ln in zip(lines, numbers):
        f = _split(s, delimiter)
        for c in cols:
            try:
                float(f[c])
            except ValueError:
                name = names[c] if names else f"column {c}"
                truncated = ln == numbers[-1]
                raise ImportDataError(path, name, f"line {ln}: value {f[c]!r} is not a number"
                                      + (" (last row: file truncated?)" if truncated else ""),
                                      "re-export the file" + (" or delete the incomplete last line" if truncated
                                                              else "")) from None
    raise ImportDataError(path, "-", "could not parse the numeric columns", "check delimiter/header settings")


def _check_finite_columns(path, data, names, numbers=None):
    bad = ~np.isfinite(data)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        where = f"line {numbers[r]}" if numbers is not None else f"row {r}"
        raise ImportDataError(path, names[c], f"NaN or Inf at {where} (sample {r})",
                              "remove or interpolate the bad samples before import")


def _column_index(path, settings, key, ref, names):
    """Column reference (name, or 0-based index) to index."""
    if isinstance(ref, (int, np.integer)) and not isinstance(ref, bool):
        n = len(names) if names else None
        if ref < 0 or (n is not None and ref >= n):
            raise _serr(settings, key, f"column index {ref} out of range", "columns are numbered from 0")
        return int(ref)
    if names is None:
        raise _serr(settings, key, f"column {ref!r} given by name but the file has no header",
                    "set header: true or give 0-based column indices")
    if ref not in names:
        raise ImportDataError(path, "header", f"column {ref!r} (settings '{key}') not in the header "
                              f"{names}", "correct the column names in the settings (or the header row)")
    return names.index(ref)


# --------------------------------------------------------------------------- checks


def _gravity_ref(lat, h, g):
    return g if g is not None else float(earth.normal_gravity(math.radians(lat), h))


def _check_accel_units(path, settings, accel, tri, fs, g_ref):
    """Median accel norm over the quietest quarter of the record vs local gravity in the declared units."""
    tol = _number(settings, "units_check_tolerance", settings.get("units_check_tolerance", 0.2))
    units, kind = tri["units"], tri["kind"]
    dt = 1.0 / fs
    if units == "count":
        if "approx_counts_per_g" not in tri or kind != "rate":
            return "skipped (counts without accel.approx_counts_per_g)"
        per_unit = {"count": tri["approx_counts_per_g"] / earth.STANDARD_GRAVITY}
        x = accel - tri["approx_zero_count"]
    else:
        per_unit = None
        x = accel
    w = window_samples(1.0, fs) if len(x) >= window_samples(1.0, fs) else 3
    stat = moving_variance_norm(x, w) if len(x) >= w else np.zeros(len(x))
    quiet = stat <= np.percentile(stat, 25)
    m = float(np.median(np.linalg.norm(x[quiet], axis=1)))

    def expected(u):  # gravity expressed in unit u (per sample for increments)
        if per_unit is not None:
            val = g_ref * per_unit["count"]
        else:
            val = g_ref / recording.unit_factor(u)
        return val * dt if kind == "increment" else val

    exp = expected(units)
    ratio = m / exp
    if abs(ratio - 1.0) <= tol:
        return f"passed: quiet-sample accel norm {m:.5g} {units} = {ratio:.4f} x local gravity"
    if units == "count":
        fix = "check accel.approx_counts_per_g / approx_zero_count"
    else:
        fix = "check accel.units and accel.scale"
        for u in recording.UNITS[("accel", kind)]:
            if u != units and recording.unit_factor(u) is not None and abs(m / expected(u) - 1.0) <= tol:
                fix = f"the data look like '{u}': declare accel.units: '{u}'"
                break
    raise ImportDataError(path, "accel.units", f"declared '{units}' but the median accel norm at rest is {m:.5g}, "
                          f"{ratio:.3g} x local gravity ({exp:.5g} {units})", fix)


def _gyro_deg_factor(tri):
    """Multiplier taking stored gyro values to deg/s (rate) or deg (increment); None when unknown."""
    if tri["units"] == "count":
        if tri["kind"] == "rate" and "approx_counts_per_deg_s" in tri:
            return 1.0 / tri["approx_counts_per_deg_s"]
        return None
    f = recording.unit_factor(tri["units"])
    return None if f is None else f * 180.0 / math.pi


def _check_gyro_peak(path, gyro, tri, fs):
    f = _gyro_deg_factor(tri)
    if f is None:
        return
    peak = float(np.max(np.abs(gyro))) * f * (fs if tri["kind"] == "increment" else 1.0)
    if peak > MAX_GYRO_DEG_S:
        raise ImportDataError(path, "gyro.units", f"declared '{tri['units']}' gives a peak rate of {peak:.4g} deg/s, "
                              f"implausible (> {MAX_GYRO_DEG_S:g} deg/s)",
                              "check gyro.units (deg s-1 data declared as rad s-1?) and gyro.scale")


# --------------------------------------------------------------------------- assembly


def _apply(raw, tri):
    return np.ascontiguousarray(raw, dtype=np.float64) * tri["factor"]


def _finish(settings, fmt, path, accel, gyro, fs, *, time=None, sources=(), segments=None, segment_index=None,
            temperature=None, extra=None):
    lat, h, g = _site(settings)
    ta, tg = _triad(settings, "accel"), _triad(settings, "gyro")
    accel = _apply(accel, ta)
    gyro = _apply(gyro, tg)
    if len(accel) < 2:
        raise ImportDataError(path, "time", f"only {len(accel)} samples", "import a longer recording")
    check = _check_accel_units(path, settings, accel, ta, fs, _gravity_ref(lat, h, g))
    _check_gyro_peak(path, gyro, tg, fs)
    attrs = {"import_format": fmt, "units_check": check,
             "source_files": "; ".join(_display_name(settings, p) for p in sources),
             "source_sha256": "; ".join(f"{Path(p).name}={_sha256(p)}" for p in sources),
             "import_settings": settings.get("_source", "dict")}
    for key in ("site_note", "description"):
        if settings.get(key):
            attrs[key] = str(settings[key])
    if extra:
        attrs.update(extra)
    return recording.make_dataset(
        accel, gyro, sample_rate_hz=fs, latitude_deg=lat, height_m=h, gravity_m_s2=g,
        accel_units=ta["units"], gyro_units=tg["units"], accel_kind=ta["kind"], gyro_kind=tg["kind"],
        time=time, source="recorded", sensor=str(settings.get("sensor", "")), temperature=temperature,
        segments=segments, segment_index=segment_index, extra_attrs=attrs)


def _check_time(path, t, field, numbers=None, fs_declared=None, settings=None):
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0))
        where = f"line {numbers[i + 1]}" if numbers is not None else f"row {i + 1}"
        raise ImportDataError(path, field, f"timestamps not strictly increasing at {where} "
                              f"({t[i]:.6f} then {t[i + 1]:.6f})", "fix or drop the out-of-order samples")
    fs_med = 1.0 / float(np.median(d))
    if fs_declared is not None and abs(fs_med / fs_declared - 1.0) > 0.01:
        raise _serr(settings, "sample_rate_hz", f"declared {fs_declared:g} Hz but the timestamps in {path} give "
                    f"{fs_med:.6g} Hz (median step)", "correct sample_rate_hz or the time column's units")
    return fs_declared if fs_declared is not None else fs_med


# --------------------------------------------------------------------------- formats


def import_imu_tk(settings) -> xr.Dataset:
    """IMU-TK text pair: ``files: {accel: ..., gyro: ...}``, each row ``timestamp_s x y z`` (whitespace).

    The two files must hold the same timestamps row for row. Time is kept as in the files (seconds).
    ``sample_rate_hz`` (optional) is the nominal rate, checked to 1 % against the median time step;
    without it the median step gives the rate. Units/kind from ``accel``/``gyro`` (raw Xsens: count, rate).
    """
    _check_keys(settings, "imu_tk")
    files = settings.get("files")
    if not isinstance(files, dict) or set(files) != {"accel", "gyro"}:
        raise _serr(settings, "files", "needs exactly the two entries accel and gyro",
                    "files: {accel: xsens_acc.mat, gyro: xsens_gyro.mat}")
    for tri in ("accel", "gyro"):
        if settings[tri].get("columns") is not None:
            raise _serr(settings, f"{tri}.columns", "the IMU-TK layout is fixed (timestamp x y z)",
                        "remove columns, or use format: columns")
    pa, pg = _file(settings, "files.accel", files["accel"]), _file(settings, "files.gyro", files["gyro"])
    tables = {}
    for key, p in (("accel", pa), ("gyro", pg)):
        _, lines, numbers = _read_table(p, delimiter=None, n_fields=4)
        data = _parse_numeric(p, lines, numbers, [0, 1, 2, 3], None, None)
        _check_finite_columns(p, data, ["timestamp", f"{key} x", f"{key} y", f"{key} z"], numbers)
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
    fs = _check_time(pa, t, "timestamp", na, _rate(settings, required=False), settings)
    return _finish(settings, "imu_tk", pa, a[:, 1:], g[:, 1:], fs, time=t, sources=(pa, pg))


_IMUCAL_STATIC = re.compile(r"^([xyz])_([pa])$")
_IMUCAL_ROT = re.compile(r"^([xyz])_rot$")


def _label_meaning(settings, label):
    """(kind, axis index or None, up-sign or None) for an imucal label."""
    custom = (settings.get("labels") or {}).get(label)
    if custom is not None:
        kind = custom.get("kind")
        if kind not in ("static", "rotation"):
            raise _serr(settings, f"labels.{label}.kind", f"value {kind!r}: 'static' or 'rotation'")
        ax = custom.get("axis")
        if kind == "rotation" and ax not in ("x", "y", "z"):
            raise _serr(settings, f"labels.{label}.axis", f"value {ax!r}: a rotation needs axis x, y or z")
        return kind, ("xyz".index(ax) if ax in ("x", "y", "z") else None), None
    m = _IMUCAL_STATIC.match(label)
    if m:  # imucal: <axis>_p = that axis up (accel reads +1 g), <axis>_a = that axis down
        return "static", "xyz".index(m.group(1)), (1.0 if m.group(2) == "p" else -1.0)
    m = _IMUCAL_ROT.match(label)
    if m:
        return "rotation", "xyz".index(m.group(1)), None
    raise _serr(settings, "labels", f"segment label {label!r} is not an imucal label (x_p, x_a, ..., x_rot, ...)",
                f"declare it: labels: {{{label}: {{kind: static}}}} or {{kind: rotation, axis: x}}")


def _imucal_segments(settings, path, accel, gyro, fs, spans, ta, tg):
    """Segment table from [(label, start, stop)] sorted by start; checks labels against the data."""
    n = len(accel)
    seg_index = np.full(n, -1, dtype=np.int32)
    kinds, labels, axes, rates, angles = [], [], [], [], []
    rot = settings.get("rotation")
    meanings = [_label_meaning(settings, lab) for lab, _, _ in spans]
    has_rot = any(m[0] == "rotation" for m in meanings)
    if has_rot:
        if not isinstance(rot, dict):
            raise _serr(settings, "rotation", "the file has rotation segments but no rotation settings",
                        "declare rotation: {angle_deg: 360, sign: +1 or -1 (right-hand rule about the labelled "
                        "axis), rate_deg_s: mean or a number}")
        for key in rot:
            if key not in ROTATION_KEYS:
                raise _serr(settings, f"rotation.{key}", "unknown key", f"allowed: {', '.join(sorted(ROTATION_KEYS))}")
        for key in ROTATION_KEYS:
            if key not in rot:
                raise _serr(settings, f"rotation.{key}", "required when the file has rotation segments (the file does "
                            "not say it)", "declare angle_deg (e.g. 360), sign (+1/-1, right-hand rule) and "
                            "rate_deg_s ('mean' = angle/duration, or the table rate)")
        angle = _number(settings, "rotation.angle_deg", rot["angle_deg"])
        sign = rot["sign"]
        if sign not in (1, -1):
            raise _serr(settings, "rotation.sign", f"value {sign!r}: +1 or -1 (right-hand rule about the axis)")
        rate_cfg = rot["rate_deg_s"]
        if rate_cfg != "mean":
            r = _number(settings, "rotation.rate_deg_s", rate_cfg, positive=False)
            if r == 0 or np.sign(r) != sign:
                raise _serr(settings, "rotation.rate_deg_s", f"value {r} disagrees with rotation.sign {sign}",
                            "give the rate with the sign of the turn, or 'mean'")
    bias = None
    static_rows = [np.arange(a, b) for (lab, a, b), m in zip(spans, meanings) if m[0] == "static"]
    if static_rows:
        bias = gyro[np.concatenate(static_rows)].mean(axis=0)
    fdeg = _gyro_deg_factor(tg)
    checks = []
    for i, ((lab, a, b), (kind, ax, up)) in enumerate(zip(spans, meanings)):
        seg_index[a:b] = i
        kinds.append(kind)
        labels.append(lab)
        axis = np.zeros(3)
        if kind == "static":
            if up is not None and (ta["units"] != "count" or "approx_counts_per_g" in ta):
                mean = accel[a:b].mean(axis=0) - (ta["approx_zero_count"] if ta["units"] == "count" else 0.0)
                if int(np.argmax(np.abs(mean))) != ax or np.sign(mean[ax]) != up:
                    raise ImportDataError(path, "accel.sign", f"segment {lab!r} (samples {a}..{b - 1}) should have "
                                          f"{'+' if up > 0 else '-'}{'xyz'[ax]} up, but its mean accel is "
                                          f"{np.round(mean, 4).tolist()} {ta['units']}",
                                          "check the labels and the accel axis signs in the settings")
            rates.append(0.0)
            angles.append(0.0)
        else:
            axis[ax] = 1.0
            nominal = sign * angle
            dur = (b - a) / fs
            rate = nominal / dur if rate_cfg == "mean" else float(rate_cfg)
            rates.append(rate)
            angles.append(nominal)
            if fdeg is not None:
                w = gyro[a:b, ax] - (bias[ax] if bias is not None else 0.0)
                total = float(w.sum()) * fdeg * (1.0 / fs if tg["kind"] == "rate" else 1.0)
                if np.sign(total) != sign:
                    raise _serr(settings, "rotation.sign", f"segment {lab!r} of {path}: the gyro integrates to "
                                f"{total:+.1f} deg about {'xyz'[ax]}, declared sign {sign:+d}",
                                f"set rotation.sign: {int(np.sign(total)):+d} (or check gyro.sign)")
                if abs(abs(total) / angle - 1.0) > TURN_TOLERANCE:
                    fix = "check gyro.units / approx_counts_per_deg_s, sample_rate_hz and rotation.angle_deg"
                    if tg["units"] != "count":
                        for u in recording.UNITS[("gyro", tg["kind"])]:
                            f_u = recording.unit_factor(u)
                            if u != tg["units"] and f_u is not None:
                                alt = total / fdeg * f_u * 180.0 / math.pi
                                if abs(abs(alt) / angle - 1.0) <= TURN_TOLERANCE:
                                    fix = f"the data look like '{u}' ({alt:+.1f} deg): declare gyro.units: '{u}'"
                                    break
                    raise ImportDataError(path, "gyro.units", f"segment {lab!r}: the gyro integrates to {total:+.1f} "
                                          f"deg about {'xyz'[ax]} in the declared units '{tg['units']}' at "
                                          f"{fs:g} Hz, declared turn {nominal:+g} deg", fix)
                checks.append(f"{lab}: {total:+.1f} deg")
        axes.append(axis)
    segments = {"segment_kind": kinds, "segment_label": labels, "rotation_axis": np.array(axes),
                "rotation_rate": np.array(rates, dtype=float)}
    extra = {}
    if has_rot:
        extra["rotation_rate_source"] = ("declared rate" if rate_cfg != "mean" else
                                         "mean over the segment: declared angle / segment duration (hand-made "
                                         "turn, true rate unknown)")
        extra["rotation_check"] = ("integrated gyro (bias from static segments removed): " + ", ".join(checks)
                                   if checks else "skipped: gyro in counts without gyro.approx_counts_per_deg_s")
    return segments, seg_index, np.array(angles), extra


def import_imucal(settings) -> xr.Dataset:
    """imucal Ferraris session CSV (comma separated, header row).

    Two layouts: (a) ``segments_file``: imucal's segment-list JSON ``{label: {start, end}}`` in sample
    positions, ``end`` exclusive (imucal slices ``data.iloc[start:end]``); samples outside every segment get
    ``segment_index`` -1. (b) ``label_column`` (e.g. ``part``): every row labelled; rows may be grouped by
    label, so they are sorted by ``sample_column``; each run of one label is one segment.
    ``sample_column`` (e.g. ``n_samples`` or ``samples``): sample numbers, must be 0..n-1 without gaps after
    sorting; time = sample / ``sample_rate_hz`` (required). Columns default to imucal's ``acc_x..acc_z``,
    ``gyr_x..gyr_z`` (override with ``accel.columns`` / ``gyro.columns``).

    Labels (imucal's convention): ``<axis>_p`` static with that axis up, ``<axis>_a`` axis down,
    ``<axis>_rot`` a turn about that body axis; others via ``labels``. Turns: ``rotation.angle_deg``,
    ``rotation.sign`` (right-hand rule about the labelled axis; imucal's default is clockwise, -360 deg) and
    ``rotation.rate_deg_s`` (``mean`` = signed angle / segment duration, or the table rate) -- all required,
    the file says none of them. Extra variable ``rotation_angle(segment)`` [deg]: the declared turn.
    """
    _check_keys(settings, "imucal")
    path = _file(settings, "file")
    fs = _rate(settings)
    label_col = settings.get("label_column")
    seg_file = settings.get("segments_file")
    if bool(label_col) == bool(seg_file):
        raise _serr(settings, "segments_file", "give exactly one of segments_file and label_column",
                    "segments_file for imucal's JSON segment list, label_column for a labelled CSV")
    sample_col = settings.get("sample_column")
    if not sample_col:
        raise _serr(settings, "sample_column", "required (the column of sample numbers)",
                    "e.g. n_samples or samples")
    acc_cols = settings["accel"].get("columns") or ["acc_x", "acc_y", "acc_z"]
    gyr_cols = settings["gyro"].get("columns") or ["gyr_x", "gyr_y", "gyr_z"]
    names, lines, numbers = _read_table(path, delimiter=",", header=True)
    want = [sample_col, *acc_cols, *gyr_cols] + ([label_col] if label_col else [])
    missing = [c for c in want if c not in names]
    if missing:
        raise ImportDataError(path, "header", f"header {names} lacks the declared column(s) {missing}",
                              "correct accel.columns / gyro.columns / sample_column / label_column")
    idx = [names.index(c) for c in [sample_col, *acc_cols, *gyr_cols]]
    data = _parse_numeric(path, lines, numbers, idx, names, ",")
    _check_finite_columns(path, data, [names[i] for i in idx], numbers)
    samples = data[:, 0]
    if label_col:
        li = names.index(label_col)
        labels = np.array([_split(s, ",")[li] for s in lines])
        order = np.argsort(samples, kind="stable")
        data, labels, samples = data[order], labels[order], samples[order]
        numbers = [numbers[i] for i in order]
    n = len(samples)
    if not np.array_equal(samples, np.arange(n)):
        d = np.diff(samples)
        i = int(np.flatnonzero(d != 1)[0]) if np.any(d != 1) else -1
        raise ImportDataError(path, sample_col, "sample numbers are not 0..n-1 without gaps or repeats"
                              + (f" (sample {samples[i]:g} followed by {samples[i + 1]:g})" if i >= 0 else
                                 f" (first is {samples[0]:g})"), "import a complete session")
    accel, gyro = data[:, 1:4], data[:, 4:7]
    if label_col:
        change = np.flatnonzero(labels[1:] != labels[:-1]) + 1
        starts = np.concatenate([[0], change])
        stops = np.concatenate([change, [n]])
        spans = [(str(labels[a]), int(a), int(b)) for a, b in zip(starts, stops)]
        sources = (path,)
    else:
        sp = _file(settings, "segments_file")
        try:
            js = json.loads(sp.read_text())
        except json.JSONDecodeError as exc:
            raise ImportDataError(sp, "-", f"not valid JSON ({exc})", "re-export the segment list") from None
        spans = []
        for lab, v in js.items():
            if not isinstance(v, dict) or "start" not in v or "end" not in v:
                raise ImportDataError(sp, lab, "entry needs 'start' and 'end'", "re-export the segment list")
            a, b = v["start"], v["end"]
            if not (isinstance(a, int) and isinstance(b, int) and 0 <= a < b <= n):
                raise ImportDataError(sp, lab, f"start={a!r}, end={b!r} outside 0 <= start < end <= {n}",
                                      "the segment list does not belong to this session")
            spans.append((lab, a, b))
        spans.sort(key=lambda s: s[1])
        for (l0, a0, b0), (l1, a1, b1) in zip(spans, spans[1:]):
            if a1 < b0:
                raise ImportDataError(sp, l1, f"segment {l1!r} [{a1}, {b1}) overlaps {l0!r} [{a0}, {b0})",
                                      "fix the segment list")
        sources = (path, sp)
    ta, tg = _triad(settings, "accel"), _triad(settings, "gyro")
    segments, seg_index, angles, extra = _imucal_segments(settings, path, _apply(accel, ta), _apply(gyro, tg), fs,
                                                          spans, ta, tg)
    ds = _finish(settings, "imucal", path, accel, gyro, fs, time=samples / fs, sources=sources, segments=segments,
                 segment_index=seg_index, extra=extra)
    ds["rotation_angle"] = (("segment",), angles, {"units": "deg", "long_name": "declared total turn of the "
                                                   "segment about rotation_axis, right-hand rule (0 for static)"})
    return ds


def _table_triads(settings, path, names, n_cols):
    out = {}
    for tri in ("accel", "gyro"):
        cols = settings[tri].get("columns")
        if not isinstance(cols, (list, tuple)) or len(cols) != 3:
            raise _serr(settings, f"{tri}.columns", f"value {cols!r}: three column names or 0-based indices (x, y, z)")
        out[tri] = [_column_index(path, settings, f"{tri}.columns", c, names) for c in cols]
        for c in out[tri]:
            if c >= n_cols:
                raise _serr(settings, f"{tri}.columns", f"column index {c} but the file has {n_cols} columns")
    return out


def import_columns(settings) -> xr.Dataset:
    """Generic delimited text: ``file``, ``delimiter`` (null = whitespace), ``header`` (bool),
    ``comment`` (line prefix), ``skip_rows``; ``accel.columns`` / ``gyro.columns``: three names (with a
    header) or 0-based indices, in body-axis order x, y, z (a permutation remaps axes; ``sign`` flips them);
    ``time: {column, units: s|ms|us|ns}`` and/or ``sample_rate_hz`` (at least one; both: checked to 1 %);
    optional ``temperature: {column}`` [degC]. Every row must have the header's (or the first row's)
    number of fields.
    """
    _check_keys(settings, "columns")
    path = _file(settings, "file")
    delim = settings.get("delimiter")
    header = bool(settings.get("header", False))
    names, lines, numbers = _read_table(path, delimiter=delim, header=header, comment=settings.get("comment"),
                                        skip_rows=int(settings.get("skip_rows", 0)))
    n_cols = len(names) if names else len(_split(lines[0], delim))
    cols = _table_triads(settings, path, names, n_cols)
    use = cols["accel"] + cols["gyro"]
    tcfg, tcol = settings.get("time"), None
    if tcfg is not None:
        if not isinstance(tcfg, dict) or "column" not in tcfg:
            raise _serr(settings, "time", "needs {column: name or index, units: s|ms|us|ns}")
        tu = tcfg.get("units", "s")
        if tu not in TIME_UNITS:
            raise _serr(settings, "time.units", f"value {tu!r}: one of {', '.join(TIME_UNITS)}")
        tcol = _column_index(path, settings, "time.column", tcfg["column"], names)
        use.append(tcol)
    temp_col = None
    if settings.get("temperature") is not None:
        temp = settings["temperature"]
        if not isinstance(temp, dict) or "column" not in temp:
            raise _serr(settings, "temperature", "needs {column: name or index} (degC)")
        temp_col = _column_index(path, settings, "temperature.column", temp["column"], names)
        use.append(temp_col)
    data = _parse_numeric(path, lines, numbers, use, names, delim)
    labels = [names[c] if names else f"column {c}" for c in use]
    _check_finite_columns(path, data, labels, numbers)
    accel, gyro = data[:, 0:3], data[:, 3:6]
    fs_decl = _rate(settings, required=tcol is None)
    time = None
    if tcol is not None:
        time = data[:, 6] * TIME_UNITS[settings["time"].get("units", "s")]
        fs = _check_time(path, time, labels[6], numbers, fs_decl, settings)
    else:
        fs = fs_decl
    temperature = data[:, -1] if temp_col is not None else None
    mapping = {tri: ", ".join(f"{ax}={int(np.sign(f)):+d}*{abs(f):g}*{labels[j]}"
                              for ax, f, j in zip("xyz", _triad(settings, tri)["factor"], off))
               for tri, off in (("accel", range(0, 3)), ("gyro", range(3, 6)))}
    return _finish(settings, "columns", path, accel, gyro, fs, time=time, sources=(path,), temperature=temperature,
                   extra={"accel_column_map": mapping["accel"], "gyro_column_map": mapping["gyro"]})


def import_mikoff(settings) -> xr.Dataset:
    """mikoff/imu-calib log: six whitespace-separated numbers a row, no header, no time:
    ``ax ay az gx gy gz``. ``sample_rate_hz`` required; units declared in ``accel``/``gyro`` (the data are
    m s-2 and rad s-1)."""
    _check_keys(settings, "mikoff")
    path = _file(settings, "file")
    fs = _rate(settings)
    names = ["ax", "ay", "az", "gx", "gy", "gz"]
    for tri in ("accel", "gyro"):
        if settings[tri].get("columns") is not None:
            raise _serr(settings, f"{tri}.columns", "the mikoff layout is fixed (ax ay az gx gy gz)",
                        "remove columns, or use format: columns")
    _, lines, numbers = _read_table(path, delimiter=None, n_fields=6)
    data = _parse_numeric(path, lines, numbers, list(range(6)), names, None)
    _check_finite_columns(path, data, names, numbers)
    return _finish(settings, "mikoff", path, data[:, :3], data[:, 3:], fs, sources=(path,))


def import_npz_columns(settings) -> xr.Dataset:
    """NumPy ``.npz`` with a 2-D ``data`` array and a ``columns`` array of names (keys configurable by
    ``data_key`` / ``columns_key``). ``accel.columns`` / ``gyro.columns`` name the three columns of each triad
    in body-axis order; ``sample_rate_hz`` required. Loaded with ``allow_pickle=False``."""
    _check_keys(settings, "npz_columns")
    path = _file(settings, "file")
    fs = _rate(settings)
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
    for tri in ("accel", "gyro"):
        c = settings[tri].get("columns")
        if not isinstance(c, (list, tuple)) or len(c) != 3:
            raise _serr(settings, f"{tri}.columns", f"value {c!r}: three column names (x, y, z)")
        for name in c:
            if name not in names:
                raise ImportDataError(path, ck, f"column {name!r} (settings '{tri}.columns') not among {names}",
                                      "correct the column names in the settings")
        cols[tri] = [names.index(name) for name in c]
    use = cols["accel"] + cols["gyro"]
    sub = data[:, use]
    _check_finite_columns(path, sub, [names[i] for i in use])
    return _finish(settings, "npz_columns", path, sub[:, :3], sub[:, 3:], fs, sources=(path,))


IMPORTERS = {"imu_tk": import_imu_tk, "imucal": import_imucal, "mikoff": import_mikoff,
             "npz_columns": import_npz_columns, "columns": import_columns}


def import_dataset(settings: dict) -> xr.Dataset:
    """Dispatch on ``settings['format']`` and return the in-memory ``calib-recording-1`` dataset."""
    fmt = settings.get("format")
    if fmt not in IMPORTERS:
        raise _serr(settings, "format", f"value {fmt!r} unknown", f"one of: {', '.join(FORMATS)}")
    return IMPORTERS[fmt](settings)


def import_recording(settings: dict, out_path, prov: dict | None = None) -> Path:
    """Import per ``settings`` and write ``out_path`` atomically (validated after writing).

    ``prov``: provenance attributes; default :func:`calib.io.netcdf.provenance` ('import', the settings).
    """
    from calib.io.netcdf import provenance

    ds = import_dataset(settings)
    if prov is None:
        prov = provenance("import", {k: v for k, v in settings.items() if not k.startswith("_")})
    return recording.write(ds, out_path, prov)
