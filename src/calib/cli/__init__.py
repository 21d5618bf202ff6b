"""The ``calib`` command line: the same library functions as the workflow rules, for work on single files.

    calib simulate calibration OUT.nc [--config config/config.yaml] [--seed N]
    calib simulate navigation OUT.nc [--hours H] [--force]
    calib import SETTINGS.yaml OUT.nc [--topic /imu]
    calib noise RECORDING.nc [--out DIR] [--kalibr imu.yaml]      (calib.cli.formats)
    calib export CALIBRATION --format imutk|imucal|json --out PATH
    calib apply CALIBRATION RECORDING.nc OUT.nc
    calib validate RECORDING.nc [--force]
    calib calibrate RECORDING.nc --out DIR [--quick] [--noise-record LONG_STATIC.nc]
    calib fieldcal RECORDING.nc [--settings S.yaml] [--out result.nc]
    calib navigate RECORDING.nc --out errors.nc [--calibration DIR/default_calibration.nc]
    calib diagnose RECORDING.nc --out DIR [--settings FILE.yaml|json] [--noise-record LONG_STATIC.nc] [--limits]

Every recording is checked before any fit (format, time coordinate, masked samples, and the physical
plausibility of its magnitudes for the declared units: calib.signal.plausibility; --force turns the
plausibility refusals into warnings), and every result before it is reported as a success.
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import json
import math
import os
import shutil
import signal
import sys
import tempfile
import time
import traceback
from pathlib import Path

import yaml

from calib import __version__
from calib.core.errors import (EXIT_CODES, EXIT_INPUT, EXIT_INTERNAL, EXIT_SIGINT, EXIT_SIGPIPE, CalibError,
                               InputError, ResultCheckError, Terminated, fill_schema_defaults, input_file,
                               load_mapping, schema_error, yaml_problem)

#: the study configuration of the source tree calib runs from (not of the working directory)
DEFAULT_CONFIG = Path(__file__).resolve().parents[3] / "config" / "config.yaml"
MAX_HOURS = 240.0            # longest synthetic recording without --force (He 2019's 240 h)
BYTES_PER_SAMPLE = 6 * 8 + 4  # accel + gyro float64 + float32 temperature: the largest a simulated sample takes
FORCE_HELP = "run despite implausible magnitudes for the declared units (the refusals become warnings)"
EPILOG = "exit codes:\n" + "\n".join(f"  {code:3d}  {text}" for code, text in EXIT_CODES)


# --------------------------------------------------------------------------- inputs, outputs, settings


def _output_file(path, what="output") -> Path:
    """The parent folder of an output file must exist and be writable; the output must not be a folder; a netCDF
    output needs a name in valid UTF-8 (:func:`calib.io.atomic.utf8_name`), said before the work is done."""
    p = Path(path)
    if p.suffix.lower() == ".nc":
        from calib.io.atomic import utf8_name

        utf8_name(p, what)
    if p.is_dir():
        raise InputError(f"is a folder; the {what} needs a file name", file=p)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"folder of the {what} does not exist" if not parent.exists() else "is not a folder",
                         file=parent, fix=f"create it first (mkdir -p {parent}) or choose another path")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"folder not writable for the {what}", file=parent, fix="choose a writable folder")
    return p


def _output_dir(path) -> Path:
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError("exists and is not a folder", file=p, fix="give a folder for the outputs")
    return p


def _config(path):
    """The study config (``--config``, default: the source tree's ``config/config.yaml``), checked against the
    packaged schema (:mod:`calib.resources`, the file the workflow validates with) with its defaults filled."""
    from calib import resources

    path = DEFAULT_CONFIG if path is None else Path(path)
    if not path.exists():
        raise InputError("config file not found", file=path,
                         fix="pass --config PATH (a study config such as config/config.yaml of the repository)")
    cfg = load_mapping(path, "config file")
    schema = resources.schema_text()
    err = schema_error(cfg, yaml.safe_load(schema), path, path.read_text(), f"calib/resources/{resources.SCHEMA}")
    if err is not None:
        raise err
    try:
        fill_schema_defaults(cfg, yaml.safe_load(schema))  # the workflow's rule (snakemake's validate)
    except Exception as exc:  # noqa: BLE001 - any other refusal: its first line only, never the dump
        raise InputError(str(exc).strip().splitlines()[0][:200], file=path) from None
    return cfg


#: the triads a command needs unless it says otherwise: a partial record (one triad, declared absent_sensors) is
#: refused by name before any sample is read (calib.io.recording.require_sensors)
BOTH = ("accel", "gyro")


def _recording(path, force=False, what="recording", need=BOTH):
    """Format check (calib.io.recording.validate) and physical plausibility of a recording before any fit;
    ``need``: the triads the command needs (a partial record without one of them is refused)."""
    h, pl = _check_recording(path, force, what, need)
    for w in pl.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return h, pl


def _check_recording(path, force, what, need=BOTH):
    """``(header, plausibility)`` of a recording: its format and every sample checked (calib.io.recording.validate),
    its magnitudes judged (calib.signal.plausibility) on the samples of the same read; a refusal raises."""
    from calib.io import recording
    from calib.signal import plausibility

    f = input_file(path, what)
    header = recording.read_header(f)   # (read once: the time coordinate of a long recording is read whole)
    recording.require_sensors(header, need, f)
    check = plausibility.RecordingCheck(path, header, force=force)
    h = recording.validate(f, on_chunk=check.add, header=header)
    if check.n_seen != h.n_samples:   # known as validated already (no samples passed on): read for the judgement
        return h, plausibility.check_recording(path, h, force=force)
    return h, check.finish()


def _positive(value, option):
    if value is not None and not (math.isfinite(value) and value > 0):
        raise InputError(f"{option} must be positive (got {value:g})")
    return value


# --------------------------------------------------------------------------- sub-commands


def cmd_simulate(a):
    from calib.io.atomic import output_set
    from calib.studies import stages

    cfg = _config(a.config)
    if a.hours is not None:
        if a.kind == "calibration":
            raise InputError("--hours applies to 'navigation' and 'static_check'; the calibration session's length "
                             "follows from calibration_session in the config")
        _positive(a.hours, "--hours")
        if a.hours > MAX_HOURS and not a.force:
            raise InputError(f"--hours {a.hours:g} is above {MAX_HOURS:g} h", fix="pass --force for a longer recording")
    if a.seed is not None and a.seed < 0:
        raise InputError(f"--seed must be >= 0 (got {a.seed})")
    key = {"calibration": "calibration_session", "navigation": "navigation_session"}.get(a.kind, a.kind)
    seed = stages.session_seed(cfg["seeds"]["data"], key) if a.seed is None else a.seed
    truth = a.truth or str(Path(a.out).with_suffix(".truth.json"))
    _output_file(a.out, "recording")
    _output_file(truth, "truth file")
    if a.kind != "calibration":
        _check_disk(a.out, a.hours or cfg[key]["duration_h"],
                    cfg[key].get("sample_rate_hz", cfg["calibration_session"]["sample_rate_hz"]))
    with output_set():   # the recording and its truth sidecar: both or neither
        if a.kind == "calibration":
            stages.simulate_calibration(cfg["calibration_session"], cfg["site"], seed, a.out, truth)
        elif a.kind == "navigation":
            s = dict(cfg["navigation_session"])
            if a.hours is not None:
                s["duration_h"] = a.hours
            stages.simulate_navigation(s, cfg["site"], seed, a.out, truth)
        else:
            c = dict(cfg["static_check"])
            if a.hours is not None:
                c["duration_h"] = a.hours
            stages.simulate_static_check(c, cfg["calibration_session"], cfg["site"], seed, a.out, truth)
    emit(f"wrote {a.out} (truth in {truth})")


def _check_disk(out, hours, fs):
    """Refuse a long recording that would not fit on the disk of its folder."""
    need = float(hours) * 3600.0 * float(fs) * BYTES_PER_SAMPLE * 1.02 + 16e6
    folder = Path(out).parent if str(Path(out).parent) else Path(".")
    free = shutil.disk_usage(folder).free
    if need > free:
        raise InputError(f"{hours:g} h at {fs:g} Hz needs about {need / 1e9:.2f} GB but only {free / 1e9:.2f} GB "
                         "are free", file=folder, fix="free space, write elsewhere or shorten --hours")


def cmd_import(a):
    from calib.ingest import importers
    from calib.io import recording

    load_mapping(a.settings, "import settings file")   # missing, folder, malformed YAML: refused with the line
    _output_file(a.out, "recording")                     # an output folder is never created silently
    settings = importers.load_settings(a.settings)
    if a.topic:   # ROS bags: the sensor_msgs/msg/Imu topic, overriding the settings' topic
        if settings.get("format") != "rosbag":
            raise InputError(f"--topic applies to ROS bags (format: rosbag), the settings say format "
                             f"{settings.get('format')!r}", file=a.settings, field="format", fix="remove --topic")
        settings["topic"] = a.topic
    out = importers.import_recording(settings, a.out)
    summary = recording.read_header(out).attrs.get("import_summary")
    if summary:   # clock, jitter and dropped messages of a ROS bag: informational, on standard error
        print(f"calib import: {summary}", file=sys.stderr)
    emit(f"wrote {out}")


def cmd_validate(a):
    h, pl = _recording(a.recording, a.force, need=())
    triads = "; ".join(f"{s} {k} [{u}]" if k else f"no {s} (partial record: absent_sensors)"
                       for s, k, u in (("accel", h.accel_kind, h.accel_units), ("gyro", h.gyro_kind, h.gyro_units)))
    emit(f"{a.recording}: valid calib-recording-1, {h.n_samples} samples at {h.sample_rate_hz} Hz "
          f"({h.duration_s / 3600:.3f} h), latitude {h.latitude_deg} deg; {triads}")
    if h.clock_summary:   # the time coordinate's fitted clock: jitter, gaps, dropped samples
        emit(f"{a.recording}: clock: {h.clock_summary}")
    emit(f"{a.recording}: plausible: {pl.describe()}")


def cmd_calibrate(a):
    from calib.io.atomic import output_set
    from calib.signal import plausibility
    from calib.studies import calibration as calibration_study

    cfg = _config(a.config)
    _recording(a.recording, a.force)
    if a.truth:
        input_file(a.truth, "truth file")
    if a.noise_record:
        _recording(a.noise_record, a.force, "noise record")
    _output_dir(a.out)
    cc = dict(cfg["calibration"])
    if a.quick:
        cc.update(runs=3, methods=["ide", "ide_lsq", "lsq"])
    with output_set():   # the runs, tables, figures and the default calibration: all of them or none
        calibration_study.run_study(a.recording, a.truth, a.out, cc, cfg["seeds"]["calibration"],
                                    noise_record=a.noise_record)
    plausibility.check_calibration_result(Path(a.out) / "default_calibration.nc")
    emit(f"wrote {a.out}")


def cmd_fieldcal(a):
    from calib import fieldcal
    from calib.io.netcdf import write_netcdf
    from calib.signal import plausibility

    settings, imported = None, None
    if a.settings:
        settings = load_mapping(a.settings)
        if "format" in settings:  # an import-settings file: use its optional 'fieldcal:' section
            imported, settings = settings, settings.get("fieldcal")
    h, _ = _recording(a.recording, a.force, need=("accel",))   # accel-only: the gyro part is skipped with a note
    if imported is not None:
        _same_rate(imported, h, a.settings, a.recording)
    if a.out:
        _output_file(a.out, "calibration")
    res = fieldcal.fieldcal_recording(a.recording, settings, force=a.force)
    emit(json.dumps(res.summary(), indent=2, default=str))
    if a.out:
        write_netcdf(res.to_dataset(), a.out)
    plausibility.check_fieldcal_result(res, h.accel_units == "count", h.gyro_units == "count", a.out or a.recording)


def _same_rate(imported: dict, h, settings_path, recording_path) -> None:
    """An import-settings file given to ``calib fieldcal --settings`` declares the rate the recording was meant to be
    imported with; the recording's own ``sample_rate_hz`` is what every step uses. Two different rates are refused
    (exit 2) rather than one silently ignored. A recording whose rate the importer fitted to its timestamps
    (``clock_rate_hz``) agrees with the nominal rate it was declared with as the import checked it
    (:func:`calib.ingest.common.time_clock`)."""
    from calib.ingest.common import CLOCK_REL_FLOOR, CLOCK_SIGMAS

    rate = imported.get("sample_rate_hz")
    if rate is None:
        return
    try:
        rate = float(rate)
    except (TypeError, ValueError):
        raise InputError(f"sample_rate_hz {rate!r} is not a number", file=settings_path,
                         field="sample_rate_hz") from None
    fs = float(h.sample_rate_hz)
    tol = 1e-9 * fs
    if "clock_rate_hz" in h.attrs:
        tol = max(CLOCK_SIGMAS * float(h.attrs.get("clock_rate_std_hz", 0.0)), CLOCK_REL_FLOOR * fs)
    if not abs(rate - fs) <= tol:
        raise InputError(f"declares {rate:g} Hz but the recording {recording_path} declares {h.sample_rate_hz:g} Hz; "
                         "the recording's rate is the one every step would use", file=settings_path,
                         field="sample_rate_hz",
                         fix=f"re-import the recording with these settings (calib import {settings_path} OUT.nc), or "
                             f"correct sample_rate_hz in {settings_path}")


def cmd_navigate(a):
    from calib.io import recording
    from calib.studies import navigation as navigation_study

    _positive(a.nav_rate, "--nav-rate")
    _positive(a.output_interval, "--output-interval")
    if a.calibration:
        input_file(a.calibration, "calibration file")
    _output_file(a.out, "navigation output")
    input_file(a.recording, "recording")
    # the recording is checked sample by sample once (reuse_validation: the navigation's load does not read it again)
    with recording.reuse_validation():
        # what needs no sample first: a calibration file of the wrong kind, a wrong pairing of units and calibration
        # are named at once, not after the check of every sample of a long recording (4-5 s for 240 h at 100 Hz)
        inputs = navigation_study.check_navigation_inputs(a.recording, a.calibration)
        nav = {"nav_rate_hz": a.nav_rate, "output_interval_s": a.output_interval}
        _recording(a.recording, a.force)
        navigation_study.navigate_file(a.recording, a.calibration, a.out, nav, init="align" if a.align else "attrs",
                                       inputs=inputs)
    emit(f"wrote {a.out}")


def _at_least_two(text):
    """argparse type of --limits-reps: an integer >= 2 (argparse then exits 2 naming the option)."""
    import argparse

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
    with recording.reuse_validation():
        return _diagnose(a)


def _diagnose(a):
    settings = None
    if a.settings:   # overrides of calib.diagnosis.DEFAULT_SETTINGS
        settings = load_mapping(a.settings)
    _output_dir(a.out)
    from calib.diagnosis import diagnose
    from calib.diagnosis.problem import settings_of
    from calib.io.atomic import output_set

    if settings:   # names, types and ranges, refused naming the file and the setting
        settings_of(settings, file=a.settings)

    # a refused input (exit 2) writes nothing: no report beside or instead of an earlier one
    h, _ = _recording(a.recording, a.force)
    if a.noise_record:   # a long static record of the same unit: the measured slow noise of the adequacy tests
        _recording(a.noise_record, a.force, "noise record")
        settings = {**(settings or {}), "noise_record": str(a.noise_record)}
    intervals, source = None, ""
    if a.fieldcal:   # the static intervals the field calibration used: one answer per file
        intervals, source = _fieldcal_intervals(a.fieldcal), str(a.fieldcal)
    elif not _has_segment_table(a.recording):
        intervals, source, failed = _field_calibration_intervals(a, h)
        if failed is not None:   # the field calibration's own exit-3 outcome: the diagnosis cannot be run on it
            from calib.diagnosis import DEFAULT_SETTINGS, inconclusive_report
            from calib.diagnosis.run import write_report

            rep = inconclusive_report(a.recording, {**DEFAULT_SETTINGS, **(settings or {})}, failed.message,
                                      failed.fix or "")
            write_report(rep, a.out)
            emit(json.dumps({"verdict": rep["verdict"]}, indent=2))
            return 3
    with output_set():   # the report, its figures and its detection limits: all of them or none
        rep = diagnose(a.recording, settings, out_dir=a.out, intervals=intervals, intervals_source=source)
        if a.limits:   # detection limits on this recording's own noise, added to the report
            from calib.studies import real_proof

            rep = real_proof.limits_into_report(a.recording, a.out, rep, settings, reps=a.limits_reps,
                                                intervals=intervals, intervals_source=source)
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


# --------------------------------------------------------------------------- dispatch: one exit-code contract


@contextlib.contextmanager
def _signals(exiting: bool = False):
    """SIGINT and SIGTERM raise KeyboardInterrupt / Terminated (the same clean path: atomic writers delete their
    temporary files); a second signal during the clean-up is ignored. Once a signal was handled, whatever the
    interrupted code raised instead of the interruption (an extension module interrupted while it loads reports an
    ImportError, a library may wrap it) leaves as that interruption; an exception without a signal stays itself.

    An interruption raised where Python cannot pass it on -- inside a ``__del__`` or a weakref callback, e.g. while
    llvmlite frees its objects during numba's cache loading -- would be printed as "Exception ignored ... Traceback"
    and lost, the command running on to its end. It is caught by :data:`sys.unraisablehook` instead (nothing
    printed) and raised again 10 ms later from a SIGALRM timer, where it can propagate; should that be impossible,
    the end of the block raises it.

    ``exiting``: the process ends right after the block (the ``calib`` command): SIGINT and SIGTERM are then left
    ignored instead of restored. The outcome is decided and written; while Python shuts down it resets its
    handlers to the default, so a Ctrl-C arriving then would kill the process silently (exit -2, no line said)."""
    received = []

    def interruption():
        return KeyboardInterrupt() if received[0] == signal.SIGINT else Terminated(received[0])

    def handler(signum, frame):
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, signal.SIG_IGN)
        received.append(signum)
        raise interruption()

    def again(signum, frame):
        raise interruption()

    previous_hook = sys.unraisablehook
    rearm = hasattr(signal, "setitimer") and hasattr(signal, "SIGALRM")

    def unraisable(info):
        if received and isinstance(info.exc_value, KeyboardInterrupt):   # our interruption, swallowed
            if rearm:
                signal.setitimer(signal.ITIMER_REAL, 0.01)
            return
        previous_hook(info)

    old = {}
    with contextlib.suppress(ValueError):   # not the main thread: leave the handlers alone
        for s in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(s) is not signal.SIG_IGN:
                old[s] = signal.signal(s, handler)
        if old and rearm:
            old[signal.SIGALRM] = signal.signal(signal.SIGALRM, again)
    if old:
        sys.unraisablehook = unraisable
    try:
        yield
        if received:   # swallowed and not raised again: the work went on to its end, still it was interrupted
            raise interruption()
    except Exception as exc:  # noqa: BLE001 - what an interrupted library raised is the interruption
        if not received:
            raise
        raise interruption() from exc
    finally:
        if old:
            sys.unraisablehook = previous_hook
            if rearm:
                signal.setitimer(signal.ITIMER_REAL, 0)
        for s, h in old.items():
            signal.signal(s, signal.SIG_IGN if exiting and s in (signal.SIGINT, signal.SIGTERM) else h)


def _say(text):
    """One line on standard error; a file name that was not valid UTF-8 (lone surrogates) shows escaped, as
    Python's own stderr would show it, whatever the stream's error handler (a capture)."""
    text = str(text).encode("utf-8", "backslashreplace").decode("utf-8")
    print(" ".join(text.split()) if "\n" in text else text, file=sys.stderr)


def _not_started(sig: str = "SIGINT") -> None:
    """The one line of an interrupt that came before the command started (while the sub-commands load): nothing
    was written."""
    _say(f"calib: interrupted by {sig}; nothing written")


def _os_message(exc: OSError) -> str:
    where = f"{exc.filename}: " if exc.filename else ""
    return f"{where}{exc.strerror or exc}"


def _internal_error(name, exc) -> int:
    """One line on the terminal; the traceback in a log file in the system temporary folder."""
    text = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
    try:
        fd, log = tempfile.mkstemp(prefix="calib-error-", suffix=".log")
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{name} ({' '.join(sys.argv)}) at {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
            fh.write(traceback.format_exc())
        where = f"traceback in {log}"
    except OSError:
        where = "no log file could be written"
    _say(f"{name}: internal error: {text} ({where}; please report it)")
    return EXIT_INTERNAL


def emit(text) -> None:
    """The promised output of a sub-command (a summary, a verdict, the path written): the only thing on
    standard output. Everything else a command prints while it works goes to standard error (or nowhere
    with ``--quiet``)."""
    try:
        print(text, file=_STDOUT[0] or sys.stdout, flush=True)
    except BrokenPipeError:   # not an input error: the reader went away (exit 141, as a shell reports it)
        raise _OutputClosed() from None


_STDOUT = [None]


class _OutputClosed(Exception):
    """Standard output's reader went away while :func:`emit` wrote to it (``calib ... | head -1``)."""


def _output_closed() -> int:
    """Standard output from now on goes nowhere (Python's own flush at the exit would fail on the closed pipe
    again and print a message); the command stops silently with 141, as a shell reports a command killed by
    SIGPIPE -- not 2, which would blame the input."""
    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    return EXIT_SIGPIPE


def _one_line_warning(message, category, filename, lineno, line=None):
    return f"warning: {' '.join(str(message).split())}\n"


def _dispatch(a, exiting: bool = False) -> int:
    """Run the sub-command and map every outcome to the exit-code contract (calib.core.errors.EXIT_CODES)."""
    import warnings

    from calib.core import progress

    name = f"calib {a.cmd}"
    progress.set_quiet(getattr(a, "quiet", False))
    warnings.formatwarning = _one_line_warning
    _STDOUT[0] = sys.stdout
    chatter = open(os.devnull, "w") if getattr(a, "quiet", False) else sys.stderr
    try:
        with _signals(exiting), contextlib.redirect_stdout(chatter):
            code = a.fn(a)
        return code or 0
    except _OutputClosed:
        return _output_closed()
    except KeyboardInterrupt as exc:
        sig = "SIGTERM" if isinstance(exc, Terminated) else "SIGINT"
        _say(f"{name}: interrupted by {sig}; no partial output left, earlier outputs kept")
        return getattr(exc, "exit_code", EXIT_SIGINT)
    except ResultCheckError as exc:
        _say(f"{name}: result check failed: {exc}")
        return exc.exit_code
    except CalibError as exc:
        _say(f"{name}: error: {exc}")
        return exc.exit_code
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{mark.name}: line {mark.line + 1}: " if mark is not None else ""
        _say(f"{name}: error: {where}{yaml_problem(exc)}")
        return EXIT_INPUT
    except (ValueError, OSError, MemoryError) as exc:  # RecordingError and friends carry file, field and fix
        text = _os_message(exc) if isinstance(exc, OSError) else ("not enough memory" if isinstance(exc, MemoryError)
                                                                  else str(exc))
        _say(f"{name}: error: {text}")
        return EXIT_INPUT
    except Exception as exc:  # noqa: BLE001 - anything else is a bug: one line, the traceback in a log
        return _internal_error(name, exc)
    finally:
        _STDOUT[0] = None
        if chatter is not sys.stderr:
            chatter.close()


def main(argv=None, *, exiting: bool = False):
    p = argparse.ArgumentParser(prog="calib", description=__doc__, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"calib {__version__}")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress and no informational lines (errors, warnings and the result stay)")
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("simulate", help="synthetic sessions (data stage)")
    s.add_argument("kind", choices=["calibration", "navigation", "static_check"])
    s.add_argument("out")
    s.add_argument("--config", help="study config (default: config/config.yaml of the calib source tree)")
    s.add_argument("--seed", type=int)
    s.add_argument("--hours", type=float,
                   help=f"length of a navigation / static_check session, 0 < H <= {MAX_HOURS:g}")
    s.add_argument("--truth")
    s.add_argument("--force", action="store_true", help=f"allow --hours above {MAX_HOURS:g}")
    s.set_defaults(fn=cmd_simulate)
    s = sub.add_parser("import", help="import a real recording with a settings YAML (config/import/*.yaml)")
    s.add_argument("settings")
    s.add_argument("out")
    s.add_argument("--topic", help="ROS bags: the sensor_msgs/msg/Imu topic (overrides the settings' topic)")
    s.set_defaults(fn=cmd_import)
    s = sub.add_parser("validate", help="check a calib-recording-1 file")
    s.add_argument("recording")
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.set_defaults(fn=cmd_validate)
    s = sub.add_parser("calibrate", help="Liu 2021 calibration study on a session with a segment table")
    s.add_argument("recording")
    s.add_argument("--out", required=True)
    s.add_argument("--truth")
    s.add_argument("--config", help="study config (default: config/config.yaml of the calib source tree)")
    s.add_argument("--quick", action="store_true", help="3 runs of IDE, IDE+polish and least squares only")
    s.add_argument("--noise-record", default=None,
                   help="long static recording of the same unit: its Allan deviation gives the bias instability "
                        "(slow noise) of the default calibration's segment means")
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.set_defaults(fn=cmd_calibrate)
    s = sub.add_parser("fieldcal", help="calibration without a turntable record (real recordings)")
    s.add_argument("recording")
    s.add_argument("--settings")
    s.add_argument("--out")
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.set_defaults(fn=cmd_fieldcal)
    s = sub.add_parser("navigate", help="pure-inertial navigation of a stationary recording")
    s.add_argument("recording")
    s.add_argument("--out", required=True)
    s.add_argument("--calibration", help="default_calibration.nc of the calibrate stage (count recordings)")
    s.add_argument("--nav-rate", type=float, default=10.0)
    s.add_argument("--output-interval", type=float, default=60.0)
    s.add_argument("--align", action="store_true", help="self-align instead of using the recorded attitude")
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.set_defaults(fn=cmd_navigate)
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
    try:
        with _signals():   # an interrupt while the sub-commands load: the same one line as during a command
            from calib.cli import formats   # import --topic, noise, export, apply (ROS bags, Kalibr, ...)
            formats.register(sub)
            a = p.parse_args(argv)   # argparse's own usage errors exit 2
    except KeyboardInterrupt as exc:
        _not_started("SIGTERM" if isinstance(exc, Terminated) else "SIGINT")
        return getattr(exc, "exit_code", EXIT_SIGINT)
    return _dispatch(a, exiting)


def run():
    """The ``calib`` command (``python -m calib.cli`` too): :func:`main`, then the process ends with its exit code;
    an interrupt after the outcome is decided changes nothing (:func:`_signals`, ``exiting``)."""
    code = main(sys.argv[1:], exiting=True)
    # The interpreter shuts down as usual (exit handlers, module teardown); only the cyclic garbage collector is
    # told to leave the objects alive now alone. Its passes over the ~180 000 objects of numpy, scipy, numba and
    # matplotlib during the teardown cost 0.3-0.45 s of CPU after a cold `calib diagnose` (measured: the same run
    # with and without gc.freeze(), 2.9-3.1 against 2.6-2.8 s CPU); the memory goes back to the system either way.
    gc.freeze()
    sys.exit(code)
