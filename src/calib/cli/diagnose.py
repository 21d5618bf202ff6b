"""``calib diagnose RECORDING.nc --out DIR``: the mismatch diagnosis of one recording (report.json, report.md,
figures), on the segment table of the recording, the static intervals of a field calibration (``--fieldcal``), or
those ``calib fieldcal`` finds with its default settings -- after the same checks, so that the two commands give
one answer per file.

The library modules the functions need (numpy, netCDF, scipy and more behind them) are imported inside them:
loaded only when a command runs, so that ``calib --help`` and a usage error answer at once."""
from __future__ import annotations

import argparse
import gc
import importlib
import json

from calib.cli.shared import FORCE_HELP, checked_recording, emit, output_dir
from calib.core.errors import InputError, ResultCheckError, input_file, load_mapping


def _at_least_two(text):
    """argparse type of --limits-reps: an integer >= 2 (argparse then exits 2 naming the option)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 2:
        raise argparse.ArgumentTypeError(f"{v}: at least 2 repetitions per magnitude")
    return v


def cmd_diagnose(a):
    from calib.io import recording

    # the recording and the noise record are checked in full (every sample) once, not again when loaded
    try:
        with recording.reuse_validation():
            return _diagnose(a)
    finally:
        gc.unfreeze()   # what _load_long_lived froze is collectable again (an in-process caller goes on running)


def _load_long_lived(*modules) -> None:
    """Import ``modules`` with the cyclic garbage collector paused, then freeze every object alive
    (:func:`gc.freeze`): the ~120 000 objects of numpy, scipy, netCDF, numba and matplotlib live as long as the
    process. Without it the collector walks them in full passes during and after the imports, finding nothing:
    0.26-0.55 s of collection in a cold ``calib diagnose`` of a Liu-2021 null session (gc.callbacks; the more the
    machine is loaded, the more), 0.05-0.07 s with it. The collector keeps collecting everything made afterwards."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        for name in modules:
            importlib.import_module(name)
    finally:
        if enabled:
            gc.enable()
    gc.freeze()


def _diagnose(a):
    settings = None
    if a.settings:   # overrides of calib.diagnosis.DEFAULT_SETTINGS
        settings = load_mapping(a.settings)
    output_dir(a.out)
    _load_long_lived("calib.diagnosis")
    from calib.diagnosis import DEFAULT_SETTINGS, diagnose
    from calib.diagnosis.problem import settings_of
    from calib.io.atomic import output_set

    if settings:   # names, types and ranges, refused naming the file and the setting
        settings_of(settings, file=a.settings)

    # a refused input (exit 2) writes nothing: no report beside or instead of an earlier one
    h, _ = checked_recording(a.recording, a.force)
    if a.noise_record:   # a long static record of the same unit: the measured slow noise of the adequacy tests
        checked_recording(a.noise_record, a.force, "noise record")
        settings = {**(settings or {}), "noise_record": str(a.noise_record)}
    intervals, source = None, ""
    if a.fieldcal:   # the static intervals the field calibration used: one answer per file
        intervals, source = _fieldcal_intervals(a.fieldcal), str(a.fieldcal)
    elif not _has_segment_table(a.recording):
        intervals, source, failed = _field_calibration_intervals(a, h)
        if failed is not None:   # the field calibration's own exit-3 outcome: the diagnosis cannot be run on it
            from calib.diagnosis import inconclusive_report
            from calib.diagnosis.run import write_report

            rep = inconclusive_report(a.recording, {**DEFAULT_SETTINGS, **(settings or {})}, failed.message,
                                      failed.fix or "")
            write_report(rep, a.out)
            emit(json.dumps({"verdict": rep["verdict"]}, indent=2))
            return 3
    if {**DEFAULT_SETTINGS, **(settings or {})}["figures"]:   # matplotlib in the project's style, for the figures
        _load_long_lived("calib.figures.diagnosis_plots")
    with output_set():   # the report, its figures and its detection limits: all of them or none
        rep = diagnose(a.recording, settings, out_dir=a.out, intervals=intervals, intervals_source=source)
        if a.limits:   # detection limits on this recording's own noise, added to the report
            from calib.diagnosis.limits import limits_into_report

            rep = limits_into_report(a.recording, a.out, rep, settings, reps=a.limits_reps, intervals=intervals,
                                     intervals_source=source)
    emit(json.dumps({k: rep[k] for k in ("verdict",) if k in rep}, indent=2))
    return {"adequate": 0, "missing_physics": 1}.get(rep["verdict"], 3)   # exit code: 3 inconclusive


def _has_segment_table(path) -> bool:
    """Whether the recording carries its own segment table (``segment_index``): a turntable session's or a labelled
    one's; without one the static poses must be detected."""
    import netCDF4

    with netCDF4.Dataset(path) as nc:
        return "segment_index" in nc.variables


def _field_calibration_intervals(a, h):
    """What ``calib fieldcal RECORDING`` does with its default settings, before any verdict of the diagnosis: the
    same unit, rate and plausibility checks (a refusal raises, exit 2, nothing written), the same default static
    detection, the same result checks. Returns ``(intervals, source, None)``, or ``(None, "", ResultCheckError)``
    when the field calibration's result fails its checks (``calib fieldcal`` exits 3 on it)."""
    from calib import fieldcal
    from calib.signal import plausibility

    try:
        res = fieldcal.fieldcal_recording(a.recording, None, force=a.force)
        plausibility.check_fieldcal_result(res, h.accel_units == "count", h.gyro_units == "count", a.recording)
    except ResultCheckError as exc:
        return None, "", exc
    return res.intervals, ("calib fieldcal's default static detection (the intervals 'calib fieldcal RECORDING' "
                           "uses; --fieldcal result.nc gives those of other settings)"), None


def _fieldcal_intervals(path):
    """``static_intervals`` of a ``calib fieldcal --out`` result (calib-fieldcal-1), refused by name otherwise."""
    import numpy as np
    import xarray as xr

    from calib.io.netcdf import conventions

    fix = "give the result.nc written by 'calib fieldcal RECORDING --out result.nc'"
    input_file(path, "field calibration")
    try:
        with xr.open_dataset(path, engine="netcdf4") as fc:
            kind = conventions(fc.attrs)
            iv = np.asarray(fc["static_intervals"].values) if "static_intervals" in fc else None
    except Exception as exc:  # noqa: BLE001 - whatever the netCDF library raises, it is not a fieldcal result
        raise InputError(f"not a netCDF field calibration ({type(exc).__name__})", file=path, fix=fix) from None
    if kind != "calib-fieldcal-1" or iv is None or iv.ndim != 2 or iv.shape[1] != 2:
        raise InputError("is not a field calibration with static_intervals(interval, bound)", file=path,
                         field="static_intervals", fix=fix)
    return iv


def register(sub) -> None:
    """Add the ``diagnose`` sub-command."""
    s = sub.add_parser("diagnose", help="locate and name the physics a model leaves out")
    s.add_argument("recording")
    s.add_argument("--out", required=True)
    s.add_argument("--settings", help="JSON or YAML file overriding calib.diagnosis.DEFAULT_SETTINGS")
    s.add_argument("--fieldcal", help="result.nc of 'calib fieldcal --out': diagnose on the static intervals that "
                                      "calibration used (recordings without a segment table)")
    s.add_argument("--noise-record", default=None,
                   help="long static record of the same unit: its Allan deviation measures the slow noise between "
                        "windows; without it a misfit within what slow noise could do is 'inconclusive'")
    s.add_argument("--limits", action="store_true",
                   help="also measure the detection limits on this recording (static-pose recordings): the smallest "
                        "magnitude of each library term and axis named in >= 95 %% of block-resampled repetitions of "
                        "its own noise, and the size at which a bias step, ramp or oscillation becomes visible; "
                        "written to report.json (detection_limits) and report.md")
    s.add_argument("--limits-reps", type=_at_least_two, default=20,
                   help="repetitions per magnitude for --limits (default 20)")
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.set_defaults(fn=cmd_diagnose)
