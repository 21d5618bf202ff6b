"""What every importer shares: the settings (keys, data folder, site, triads), reading text tables, the unit
and structure checks, and the assembly of a ``calib-recording-1`` dataset. See :mod:`calib.ingest` for the
settings keys of each format; each format module declares its own keys (``KEYS``) next to its importer."""
from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path

import numpy as np
import yaml

from calib.core import clock, dropouts, earth
from calib.core.triad import TriadCorrection
from calib.io import recording
from calib.signal.detect import moving_variance_norm, window_samples
from calib.io.recording import RecordingError

COMMON_KEYS = {"format", "latitude_deg", "height_m", "gravity_m_s2", "site_note", "sensor", "description",
               "data_dir", "accel", "gyro", "units_check_tolerance",
               "start_s", "stop_s", "dropout_min_rows",   # the part of the file to import; see finish()
               "fieldcal"}   # the field calibration's settings may live in the same file (read by calib fieldcal)
TRIAD_KEYS = {"units", "sample_kind", "columns", "scale", "sign", "approx_counts_per_g", "approx_zero_count",
              "approx_counts_per_deg_s"}
ROTATION_KEYS = {"angle_deg", "sign", "rate_deg_s"}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
MAX_GYRO_DEG_S = 5000.0  # no MEMS or tactical gyro in this project's scope measures faster
TURN_TOLERANCE = 0.25  # relative, on the integrated angle of a labelled turn


class ImportDataError(RecordingError):
    """An import that cannot proceed; names the file (or settings file), the field and the fix."""


def settings_name(settings) -> str:
    return settings.get("_source", "<import settings>")


def serr(settings, key, problem, fix=""):
    return ImportDataError(settings_name(settings), key, problem, fix)


# --------------------------------------------------------------------------- settings


def load_settings(path, data_root=None) -> dict:
    """Read an import-settings YAML; relative ``data_dir`` is then resolved against the file's directory.

    ``data_root``: where the named files are when the settings give no ``data_dir`` (a workflow's ``data_root``
    config key; relative to the working directory); default :func:`default_data_root`.
    """
    path = Path(path)
    if not path.exists():
        raise ImportDataError(path, "-", "import settings file not found")
    with open(path) as fh:
        s = yaml.safe_load(fh)
    if not isinstance(s, dict):
        raise ImportDataError(path, "-", "import settings must be a YAML mapping")
    s["_source"] = str(path)
    s["_base_dir"] = str(path.resolve().parent)
    if data_root is not None and "data_dir" not in s:
        s["_data_root"] = str(Path(data_root).expanduser().resolve())
    return s


def check_keys(settings, fmt, format_keys, partial: bool = False, triad_keys=()):
    """Refuse keys that are neither common nor among the ``format_keys`` of format ``fmt`` (its module's ``KEYS``),
    and triad declarations that are missing or hold unknown keys. ``partial``: the format maps each triad's
    columns or variables, so a recording may hold one triad only -- the other simply not declared (a partial
    record, :func:`present_triads`); at least one is needed. ``triad_keys``: the format's own keys of a triad
    declaration besides :data:`TRIAD_KEYS`."""
    allowed = COMMON_KEYS | set(format_keys)
    for key in settings:
        if key.startswith("_"):
            continue
        if key not in allowed:
            raise serr(settings, key, f"unknown key for format '{fmt}'",
                        f"remove it or correct the spelling (allowed: {', '.join(sorted(allowed))})")
    if partial and not any(settings.get(tri) is not None for tri in recording.SENSORS):
        raise serr(settings, "accel", "neither triad declared (accel, gyro)",
                   "declare the accelerometer, the gyroscope or both: accel: {units: ..., sample_kind: rate, ...}")
    for tri in present_triads(settings) if partial else recording.SENSORS:
        t = settings.get(tri)
        if not isinstance(t, dict):
            raise serr(settings, tri, "triad declaration missing or not a mapping",
                        f"declare {tri}: {{units: ..., sample_kind: rate|increment}}")
        for key in t:
            if key not in TRIAD_KEYS | set(triad_keys):
                raise serr(settings, f"{tri}.{key}", "unknown key",
                            f"allowed: {', '.join(sorted(TRIAD_KEYS | set(triad_keys)))}")


def present_triads(settings) -> tuple:
    """The triads the settings declare (``accel``, ``gyro``); a format that maps columns or variables
    (``check_keys(..., partial=True)``) imports a recording of one triad alone, the other declared absent."""
    return tuple(tri for tri in recording.SENSORS if settings.get(tri) is not None)


def default_data_root() -> Path:
    """Where recordings named by import settings without ``data_dir`` (and loaded without a ``data_root``) are
    looked for: the environment variable ``CALIB_DATA`` if set, else the shared data folder beside the
    repository (``<repo>/../shared/data``)."""
    env = os.environ.get("CALIB_DATA")
    if env:
        return Path(env).expanduser()
    repo = Path(__file__).resolve().parents[3]
    base = repo if (repo / "pyproject.toml").exists() else Path.cwd()
    return (base / ".." / "shared" / "data").resolve()


def data_dir(settings) -> Path:
    """The folder the settings' file names are relative to: ``data_dir`` of the settings, else the ``data_root``
    they were loaded with (:func:`load_settings`), else :func:`default_data_root`."""
    if "data_dir" not in settings:
        if settings.get("_data_root"):
            return Path(settings["_data_root"])
        return default_data_root()
    d = Path(settings["data_dir"])
    if not d.is_absolute():
        d = Path(settings.get("_base_dir", Path.cwd())) / d
    return d


def data_file(settings, key, value=None) -> Path:
    name = settings.get(key) if value is None else value
    if not name:
        raise serr(settings, key, "file name missing", f"give '{key}' relative to data_dir or absolute")
    p = Path(name)
    if not p.is_absolute():
        p = (data_dir(settings) / p).resolve()
    if not p.exists():
        raise ImportDataError(p, key, "input file not found",
                              f"check '{key}' and data_dir (resolved to {data_dir(settings)})")
    return p


def number_setting(settings, key, value, positive=True):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise serr(settings, key, f"value {value!r} is not a number") from None
    if not math.isfinite(v) or (positive and v <= 0):
        raise serr(settings, key, f"value {v} must be a finite{' positive' if positive else ''} number")
    return v


def declared_rate(settings, required=True):
    if "sample_rate_hz" not in settings:
        if required:
            raise serr(settings, "sample_rate_hz", "required: the file holds no timestamps",
                        "declare the sample rate in Hz")
        return None
    return number_setting(settings, "sample_rate_hz", settings["sample_rate_hz"])


def site_attrs(settings):
    if "latitude_deg" not in settings:
        raise serr(settings, "latitude_deg", "required (the recording holds no site)",
                    "declare the site latitude in degrees (north positive)")
    lat = number_setting(settings, "latitude_deg", settings["latitude_deg"], positive=False)
    if not -90.0 <= lat <= 90.0:
        raise serr(settings, "latitude_deg", f"value {lat} outside [-90, 90]")
    h = number_setting(settings, "height_m", settings.get("height_m", 0.0), positive=False)
    g = settings.get("gravity_m_s2")
    if g is not None:
        g = number_setting(settings, "gravity_m_s2", g)
        if not 9.7 < g < 9.9:
            raise serr(settings, "gravity_m_s2", f"value {g} m s-2 is not a local gravity on Earth",
                        "give local gravity in m s-2 (about 9.78-9.83)")
    return lat, h, g


def triad_settings(settings, name):
    t = settings[name]
    kind = t.get("sample_kind")
    if kind not in ("rate", "increment"):
        raise serr(settings, f"{name}.sample_kind", f"value {kind!r}: declare 'rate' or 'increment'")
    units = t.get("units")
    allowed = recording.UNITS[(name, kind)]
    if units not in allowed:
        raise serr(settings, f"{name}.units", f"value {units!r} not allowed for sample_kind={kind!r}",
                    f"declare one of: {', '.join(allowed)}")
    scale = t.get("scale", 1.0)
    scale = np.broadcast_to(np.asarray(scale, dtype=float), (3,)).copy() if np.ndim(scale) == 0 else \
        np.asarray(scale, dtype=float)
    if scale.shape != (3,) or not np.all(np.isfinite(scale)) or np.any(scale == 0):
        raise serr(settings, f"{name}.scale", f"value {t.get('scale')!r}: one or three finite non-zero numbers")
    sign = np.asarray(t.get("sign", [1, 1, 1]), dtype=float)
    if sign.shape != (3,) or not np.all(np.isin(sign, (-1.0, 1.0))):
        raise serr(settings, f"{name}.sign", f"value {t.get('sign')!r}: three of +1 / -1 (x, y, z)")
    out = {"units": units, "kind": kind, "factor": sign * scale, "columns": t.get("columns")}
    for key in ("approx_counts_per_g", "approx_counts_per_deg_s"):
        if key in t:
            out[key] = number_setting(settings, f"{name}.{key}", t[key])
    out["approx_zero_count"] = number_setting(settings, f"{name}.approx_zero_count", t.get("approx_zero_count", 0.0),
                                       positive=False)
    return out


def display_name(settings, path) -> str:
    """Source file name as stored in attributes: relative to data_dir when inside it (machine independent)."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(data_dir(settings).resolve()))
    except ValueError:
        return str(p)


def sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for blk in iter(lambda: fh.read(1 << 20), b""):
            h.update(blk)
    return h.hexdigest()


# --------------------------------------------------------------------------- text tables


def split_fields(line, delimiter):
    return line.split() if delimiter is None else [f.strip() for f in line.split(delimiter)]


def read_table(path, *, delimiter=None, header=False, comment=None, skip_rows=0, n_fields=None,
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
        names = [n.strip().strip('"').strip("'") for n in split_fields(keep[0], delimiter)]
        keep, numbers = keep[1:], numbers[1:]
        n_fields = n_fields or len(names)
    if not keep:
        raise ImportDataError(path, field, "no data rows", "check the file and skip_rows/comment settings")
    counts = np.fromiter((len(split_fields(s, delimiter)) for s in keep), dtype=np.int64, count=len(keep))
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


def parse_numeric(path, lines, numbers, cols, names, delimiter):
    """Parse the given column indices of the data lines as float64 (n, len(cols))."""
    try:
        return np.loadtxt(lines, delimiter=delimiter, usecols=cols, dtype=np.float64, ndmin=2)
    except ValueError:
        pass
    for s, ln in zip(lines, numbers):
        f = split_fields(s, delimiter)
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


def check_finite_columns(path, data, names, numbers=None):
    bad = ~np.isfinite(data)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        where = f"line {numbers[r]}" if numbers is not None else f"row {r}"
        raise ImportDataError(path, names[c], f"NaN or Inf at {where} (sample {r})",
                              "remove or interpolate the bad samples before import")


def column_index(path, settings, key, ref, names):
    """Column reference (name, or 0-based index) to index."""
    if isinstance(ref, (int, np.integer)) and not isinstance(ref, bool):
        n = len(names) if names else None
        if ref < 0 or (n is not None and ref >= n):
            raise serr(settings, key, f"column index {ref} out of range", "columns are numbered from 0")
        return int(ref)
    if names is None:
        raise serr(settings, key, f"column {ref!r} given by name but the file has no header",
                    "set header: true or give 0-based column indices")
    if ref not in names:
        raise ImportDataError(path, "header", f"column {ref!r} (settings '{key}') not in the header "
                              f"{names}", "correct the column names in the settings (or the header row)")
    return names.index(ref)


# --------------------------------------------------------------------------- checks


def gravity_ref(lat, h, g):
    return g if g is not None else float(earth.normal_gravity(math.radians(lat), h))


def check_accel_units(path, settings, accel, tri, fs, g_ref):
    """Median accel norm over the quietest quarter of the record vs local gravity in the declared units."""
    tol = number_setting(settings, "units_check_tolerance", settings.get("units_check_tolerance", 0.2))
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


def gyro_deg_factor(tri):
    """Multiplier taking stored gyro values to deg/s (rate) or deg (increment); None when unknown."""
    if tri["units"] == "count":
        if tri["kind"] == "rate" and "approx_counts_per_deg_s" in tri:
            return 1.0 / tri["approx_counts_per_deg_s"]
        return None
    f = recording.unit_factor(tri["units"])
    return None if f is None else f * 180.0 / math.pi


def check_gyro_peak(path, gyro, tri, fs):
    f = gyro_deg_factor(tri)
    if f is None:
        return
    peak = float(np.max(np.abs(gyro))) * f * (fs if tri["kind"] == "increment" else 1.0)
    if peak > MAX_GYRO_DEG_S:
        raise ImportDataError(path, "gyro.units", f"declared '{tri['units']}' gives a peak rate of {peak:.4g} deg/s, "
                              f"implausible (> {MAX_GYRO_DEG_S:g} deg/s)",
                              "check gyro.units (deg s-1 data declared as rad s-1?) and gyro.scale")


# --------------------------------------------------------------------------- assembly


def apply_triad(raw, tri, sensor=""):
    """The samples in the declared units: raw times the declared per-axis ``sign`` x ``scale`` (``tri`` of
    :func:`triad_settings`), the triad's correction without a matrix or bias
    (:class:`calib.core.triad.TriadCorrection`: each axis on its own)."""
    return TriadCorrection(sensor, None, None, tri["units"], tri["units"], factor=tri["factor"]).apply(raw)


def _window(settings, t_rel) -> tuple[int, int]:
    """Rows ``[lo, hi)`` inside the settings' ``start_s <= t < stop_s`` (``t_rel``: seconds from the first row)."""
    lo, hi = 0, len(t_rel)
    if settings.get("start_s") is not None:
        lo = int(np.searchsorted(t_rel, number_setting(settings, "start_s", settings["start_s"], positive=False)))
    if settings.get("stop_s") is not None:
        hi = int(np.searchsorted(t_rel, number_setting(settings, "stop_s", settings["stop_s"], positive=False)))
    if hi - lo < 2:
        raise serr(settings, "start_s" if settings.get("start_s") is not None else "stop_s",
                   f"the window start_s..stop_s holds {max(hi - lo, 0)} of the {len(t_rel)} samples "
                   f"({t_rel[-1]:.6g} s from the first sample to the last)", "widen start_s / stop_s")
    return lo, hi


def _cut(settings, path, accel, gyro, t_rel, window=True):
    """The rows to import ``(lo, hi, notes)``: the settings' window (``start_s`` / ``stop_s``), then without the
    dropouts and stuck runs at its ends (:mod:`calib.core.dropouts`, reported in ``notes``); a run inside is
    refused, naming the windows either side."""
    lo, hi = _window(settings, t_rel) if window else (0, len(t_rel))
    min_run = settings.get("dropout_min_rows", dropouts.MIN_RUN)
    if isinstance(min_run, bool) or not isinstance(min_run, int) or min_run < 0 or min_run == 1:
        raise serr(settings, "dropout_min_rows", f"value {min_run!r}: a whole number of rows >= 2 (default "
                   f"{dropouts.MIN_RUN}), or 0 to import runs of identical rows as they are")
    runs = dropouts.find_runs({"accel": None if accel is None else accel[lo:hi],
                               "gyro": None if gyro is None else gyro[lo:hi]}, min_run, offset=lo)
    # a triad constant throughout is a placeholder, not a dropout: the plausibility check names it as such
    runs = [r for r in runs if (r.start, r.stop) != (lo, hi)]
    elo, ehi = dropouts.ends(runs, lo, hi)
    stuck = dropouts.inside(runs, elo, ehi)
    if elo >= ehi or stuck:
        sensor, problem, fix = dropouts.refusal(stuck or runs, elo if stuck else lo, ehi if stuck else hi, t_rel,
                                                min_run)
        raise ImportDataError(path, sensor, problem + (" inside the recording" if stuck else " over the whole window"),
                              fix)
    notes = [f"{r.describe()} trimmed at the {'start' if r.start <= elo else 'end'}" for r in runs]
    return elo, ehi, notes


def finish(settings, fmt, path, accel, gyro, fs, *, time=None, sources=(), segments=None, segment_index=None,
            temperature=None, extra=None, window=True):
    """The ``calib-recording-1`` dataset of the imported samples after the unit checks; ``accel`` or ``gyro``
    None: a partial record (that triad not declared in the settings; written as declared absent).

    The rows imported are the settings' window ``start_s <= t < stop_s`` (seconds from the first sample;
    ``window`` False: the importer applied it), less the dropouts and stuck runs at its ends
    (:func:`_cut`). With a time coordinate, its clock is fitted and judged (:func:`calib.core.clock.fit_clock`)
    on the rows imported: a gap is refused, naming the windows either side; rate, jitter and dropped samples are
    stored as ``clock_*`` attributes and said in ``import_summary``."""
    lat, h, g = site_attrs(settings)
    ta = triad_settings(settings, "accel") if accel is not None else {"units": None, "kind": None}
    tg = triad_settings(settings, "gyro") if gyro is not None else {"units": None, "kind": None}
    accel = apply_triad(accel, ta) if accel is not None else None
    gyro = apply_triad(gyro, tg) if gyro is not None else None
    n = len(accel if accel is not None else gyro)
    if n >= 2:
        t_rel = np.asarray(time, dtype=float) - float(time[0]) if time is not None else np.arange(n) / fs
        lo, hi, trimmed = _cut(settings, path, accel, gyro, t_rel, window)
        if (lo, hi) != (0, n):
            accel = accel[lo:hi] if accel is not None else None
            gyro = gyro[lo:hi] if gyro is not None else None
            time = None if time is None else np.asarray(time)[lo:hi]
            temperature = None if temperature is None else np.asarray(temperature)[lo:hi]
            segment_index = None if segment_index is None else np.asarray(segment_index)[lo:hi]
            n = hi - lo
        summary = [] if not trimmed else [f"{len(trimmed)} dropout run(s) trimmed: " + "; ".join(trimmed)]
        extra = dict(extra or {})
        if trimmed:
            extra["dropouts_trimmed"] = "; ".join(trimmed)
        if "dropout_min_rows" in settings:   # the threshold the recording's validation uses too
            extra["dropout_min_rows"] = int(settings["dropout_min_rows"])
        if lo or hi != len(t_rel):
            extra["imported_rows"] = f"{lo}..{hi - 1} of the file's 0..{len(t_rel) - 1}"
        if time is not None:
            clk = clock.fit_clock(time)
            if clk.gaps:
                problem, fix = clk.gap_refusal(offset_s=float(t_rel[lo]), first=lo)
                raise ImportDataError(path, "time", problem, fix)
            if "clock_rate_hz" in extra:   # stamps the importer fitted its rate to (not times made from a rate)
                if (lo, hi) != (0, len(t_rel)):   # the rate of the rows imported (else the importer's, the same)
                    fs = clk.rate_hz
                extra.update(clk.attrs())
                summary.insert(0, f"clock: {clk.summary()}")
        if summary:
            extra["import_summary"] = "; ".join(([extra["import_summary"]] if extra.get("import_summary") else [])
                                                + summary)
    if n < 2:
        raise ImportDataError(path, "time", f"only {n} samples", "import a longer recording")
    if accel is not None:
        check = check_accel_units(path, settings, accel, ta, fs, gravity_ref(lat, h, g))
    else:
        check = "no accelerometer (partial record): gravity-norm check not applicable"
    if gyro is not None:
        check_gyro_peak(path, gyro, tg, fs)
    attrs = {"import_format": fmt, "units_check": check,
             "source_files": "; ".join(display_name(settings, p) for p in sources),
             "source_sha256": "; ".join(f"{Path(p).name}={sha256(p)}" for p in sources),
             "import_settings": settings.get("_source", "dict")}
    for key in ("site_note", "description"):
        if settings.get(key):
            attrs[key] = str(settings[key])
    if extra:
        attrs.update(extra)
    if accel is None or gyro is None:   # said by calib import: a partial record, declared as such
        held = "accelerometers" if gyro is None else "gyroscopes"
        absent = "gyro" if gyro is None else "accel"
        attrs.setdefault("import_summary", f"a partial record: {held} only ('{absent}' not in the settings, "
                                           f"declared absent_sensors = {absent!r})")
    return recording.make_dataset(
        accel, gyro, sample_rate_hz=fs, latitude_deg=lat, height_m=h, gravity_m_s2=g,
        accel_units=ta["units"], gyro_units=tg["units"], accel_kind=ta["kind"], gyro_kind=tg["kind"],
        time=time, source="recorded", sensor=str(settings.get("sensor", "")), temperature=temperature,
        segments=segments, segment_index=segment_index, extra_attrs=attrs)


#: a declared sample_rate_hz must agree with the fitted clock within max(CLOCK_SIGMAS x its standard uncertainty,
#: CLOCK_REL_FLOOR x the rate); the floor allows for the clock's own offset from its nominal rate (crystal
#: oscillators: tens to hundreds of ppm; the IMU-TK Xsens data run 100 ppm fast of their nominal 100 Hz)
CLOCK_SIGMAS = 5.0
CLOCK_REL_FLOOR = 1e-3


def time_clock(path, t, field, numbers=None, fs_declared=None, settings=None):
    """Check a time column and fit its sample clock (:func:`calib.core.clock.fit_clock`).

    Returns ``(rate_hz, clock)``: the fitted clock's rate (the recording's ``sample_rate_hz``) and the
    :class:`~calib.core.clock.ClockFit`. A declared ``fs_declared`` is checked against the fitted rate with
    the tolerance max(:data:`CLOCK_SIGMAS` sigma, :data:`CLOCK_REL_FLOOR` relative)."""
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0))
        where = f"line {numbers[i + 1]}" if numbers is not None else f"row {i + 1}"
        raise ImportDataError(path, field, f"timestamps not strictly increasing at {where} "
                              f"({t[i]:.6f} then {t[i + 1]:.6f})", "fix or drop the out-of-order samples")
    try:
        clk = clock.fit_clock(t)
    except clock.ClockError as exc:
        raise ImportDataError(path, field, str(exc), "check the time column") from None
    fs = clk.rate_hz
    if fs_declared is not None:
        tol = max(CLOCK_SIGMAS * clk.rate_std_hz, CLOCK_REL_FLOOR * fs)
        if abs(fs - fs_declared) > tol:
            raise serr(settings, "sample_rate_hz", f"declared {fs_declared:g} Hz but the timestamps in {path} give "
                        f"{fs:.9g} +- {clk.rate_std_hz:.2g} Hz (least-squares clock, {clk.n_dropped} dropped "
                        f"sample(s); tolerance {tol:.3g} Hz)",
                        f"declare sample_rate_hz: {fs:.6g}, remove it, or correct the time column's units")
    return fs, clk


def check_time(path, t, field, numbers=None, fs_declared=None, settings=None):
    """:func:`time_clock`'s rate alone."""
    return time_clock(path, t, field, numbers, fs_declared, settings)[0]
