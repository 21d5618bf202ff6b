"""imucal's labelled Ferraris sessions (static positions x_p, x_a, ... and turns x_rot, ...)."""
from __future__ import annotations

import json
import math
import re

import numpy as np
import xarray as xr

from calib.io import recording
from calib.ingest.common import (
    ImportDataError,
    ROTATION_KEYS,
    TURN_TOLERANCE,
    apply_triad,
    check_finite_columns,
    check_keys,
    data_file,
    declared_rate,
    finish,
    gyro_deg_factor,
    number_setting,
    parse_numeric,
    read_table,
    serr,
    split_fields,
    triad_settings,
)

#: the settings keys of this format (besides :data:`calib.ingest.common.COMMON_KEYS`)
KEYS = {"file", "segments_file", "label_column", "sample_column", "sample_rate_hz", "rotation", "labels"}


_IMUCAL_STATIC = re.compile(r"^([xyz])_([pa])$")
_IMUCAL_ROT = re.compile(r"^([xyz])_rot$")


def _label_meaning(settings, label):
    """(kind, axis index or None, up-sign or None) for an imucal label."""
    custom = (settings.get("labels") or {}).get(label)
    if custom is not None:
        kind = custom.get("kind")
        if kind not in ("static", "rotation"):
            raise serr(settings, f"labels.{label}.kind", f"value {kind!r}: 'static' or 'rotation'")
        ax = custom.get("axis")
        if kind == "rotation" and ax not in ("x", "y", "z"):
            raise serr(settings, f"labels.{label}.axis", f"value {ax!r}: a rotation needs axis x, y or z")
        return kind, ("xyz".index(ax) if ax in ("x", "y", "z") else None), None
    m = _IMUCAL_STATIC.match(label)
    if m:  # imucal: <axis>_p = that axis up (accel reads +1 g), <axis>_a = that axis down
        return "static", "xyz".index(m.group(1)), (1.0 if m.group(2) == "p" else -1.0)
    m = _IMUCAL_ROT.match(label)
    if m:
        return "rotation", "xyz".index(m.group(1)), None
    raise serr(settings, "labels", f"segment label {label!r} is not an imucal label (x_p, x_a, ..., x_rot, ...)",
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
            raise serr(settings, "rotation", "the file has rotation segments but no rotation settings",
                        "declare rotation: {angle_deg: 360, sign: +1 or -1 (right-hand rule about the labelled "
                        "axis), rate_deg_s: mean or a number}")
        for key in rot:
            if key not in ROTATION_KEYS:
                raise serr(settings, f"rotation.{key}", "unknown key", f"allowed: {', '.join(sorted(ROTATION_KEYS))}")
        for key in ROTATION_KEYS:
            if key not in rot:
                raise serr(settings, f"rotation.{key}", "required when the file has rotation segments (the file does "
                            "not say it)", "declare angle_deg (e.g. 360), sign (+1/-1, right-hand rule) and "
                            "rate_deg_s ('mean' = angle/duration, or the table rate)")
        angle = number_setting(settings, "rotation.angle_deg", rot["angle_deg"])
        sign = rot["sign"]
        if sign not in (1, -1):
            raise serr(settings, "rotation.sign", f"value {sign!r}: +1 or -1 (right-hand rule about the axis)")
        rate_cfg = rot["rate_deg_s"]
        if rate_cfg != "mean":
            r = number_setting(settings, "rotation.rate_deg_s", rate_cfg, positive=False)
            if r == 0 or np.sign(r) != sign:
                raise serr(settings, "rotation.rate_deg_s", f"value {r} disagrees with rotation.sign {sign}",
                            "give the rate with the sign of the turn, or 'mean'")
    bias = None
    static_rows = [np.arange(a, b) for (lab, a, b), m in zip(spans, meanings) if m[0] == "static"]
    if static_rows:
        bias = gyro[np.concatenate(static_rows)].mean(axis=0)
    fdeg = gyro_deg_factor(tg)
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
                    raise serr(settings, "rotation.sign", f"segment {lab!r} of {path}: the gyro integrates to "
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
    check_keys(settings, "imucal", KEYS)
    path = data_file(settings, "file")
    fs = declared_rate(settings)
    label_col = settings.get("label_column")
    seg_file = settings.get("segments_file")
    if bool(label_col) == bool(seg_file):
        raise serr(settings, "segments_file", "give exactly one of segments_file and label_column",
                    "segments_file for imucal's JSON segment list, label_column for a labelled CSV")
    sample_col = settings.get("sample_column")
    if not sample_col:
        raise serr(settings, "sample_column", "required (the column of sample numbers)",
                    "e.g. n_samples or samples")
    acc_cols = settings["accel"].get("columns") or ["acc_x", "acc_y", "acc_z"]
    gyr_cols = settings["gyro"].get("columns") or ["gyr_x", "gyr_y", "gyr_z"]
    names, lines, numbers = read_table(path, delimiter=",", header=True)
    want = [sample_col, *acc_cols, *gyr_cols] + ([label_col] if label_col else [])
    missing = [c for c in want if c not in names]
    if missing:
        raise ImportDataError(path, "header", f"header {names} lacks the declared column(s) {missing}",
                              "correct accel.columns / gyro.columns / sample_column / label_column")
    idx = [names.index(c) for c in [sample_col, *acc_cols, *gyr_cols]]
    data = parse_numeric(path, lines, numbers, idx, names, ",")
    check_finite_columns(path, data, [names[i] for i in idx], numbers)
    samples = data[:, 0]
    if label_col:
        li = names.index(label_col)
        labels = np.array([split_fields(s, ",")[li] for s in lines])
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
        sp = data_file(settings, "segments_file")
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
    ta, tg = triad_settings(settings, "accel"), triad_settings(settings, "gyro")
    segments, seg_index, angles, extra = _imucal_segments(settings, path, apply_triad(accel, ta), apply_triad(gyro, tg), fs,
                                                          spans, ta, tg)
    ds = finish(settings, "imucal", path, accel, gyro, fs, time=samples / fs, sources=sources, segments=segments,
                 segment_index=seg_index, extra=extra)
    ds["rotation_angle"] = (("segment",), angles, {"units": "deg", "long_name": "declared total turn of the "
                                                   "segment about rotation_axis, right-hand rule (0 for static)"})
    return ds
