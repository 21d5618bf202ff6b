"""What the sub-commands share: the checks of inputs and outputs before any work, the study config, the
plausibility check of a recording (:func:`checked_recording`), and :func:`emit`, the one writer of a command's
promised output.

The library modules the functions need (numpy, netCDF, scipy and more behind them) are imported inside them:
loaded only when a command runs, so that ``calib --help`` and a usage error answer at once."""
from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import yaml

from calib import resources
from calib.core.errors import InputError, fill_schema_defaults, input_file, load_mapping, schema_error


#: the study configuration of the source tree calib runs from (not of the working directory)
DEFAULT_CONFIG = Path(__file__).resolve().parents[3] / "config" / "config.yaml"
FORCE_HELP = "run despite implausible magnitudes for the declared units (the refusals become warnings)"


def output_file(path, what="output") -> Path:
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


def output_dir(path) -> Path:
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError("exists and is not a folder", file=p, fix="give a folder for the outputs")
    return p


def study_config(path):
    """The study config (``--config``, default: the source tree's ``config/config.yaml``), checked against the
    packaged schema (:mod:`calib.resources`, the file the workflow validates with) with its defaults filled."""
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


def checked_recording(path, force=False, what="recording", need=BOTH):
    """Format check (calib.io.recording.validate) and physical plausibility of a recording before any fit;
    ``need``: the triads the command needs (a partial record without one of them is refused)."""
    h, pl = check_recording(path, force, what, need)
    for w in pl.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return h, pl


def check_recording(path, force, what, need=BOTH):
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


def positive(value, option):
    if value is not None and not (math.isfinite(value) and value > 0):
        raise InputError(f"{option} must be positive (got {value:g})")
    return value


def sha256(path) -> str:
    """SHA-256 of a file (:func:`calib.ingest.common.sha256`): the importers are loaded only by the commands that
    need them, not by every start of the command line."""
    from calib.ingest.common import sha256 as file_sha256

    return file_sha256(path)


def emit(text) -> None:
    """The promised output of a sub-command (a summary, a verdict, the path written): the only thing on
    standard output. Everything else a command prints while it works goes to standard error (or nowhere
    with ``--quiet``)."""
    try:
        print(text, file=COMMAND_STDOUT[0] or sys.stdout, flush=True)
    except BrokenPipeError:   # not an input error: the reader went away (exit 141, as a shell reports it)
        raise OutputClosed() from None


COMMAND_STDOUT = [None]


class OutputClosed(Exception):
    """Standard output's reader went away while :func:`emit` wrote to it (``calib ... | head -1``)."""
