"""``calib import SETTINGS.yaml OUT.nc`` and ``calib validate RECORDING.nc``: a logger's file made into a
calib-recording-1, and the check of one.

The library modules the functions need (numpy, netCDF, scipy and more behind them) are imported inside them:
loaded only when a command runs, so that ``calib --help`` and a usage error answer at once."""
from __future__ import annotations

import sys

from calib.cli.shared import FORCE_HELP, checked_recording, emit, output_file
from calib.core.errors import InputError, load_mapping


def cmd_import(a):
    from calib.ingest import importers
    from calib.io import recording

    load_mapping(a.settings, "import settings file")   # missing, folder, malformed YAML: refused with the line
    output_file(a.out, "recording")                     # an output folder is never created silently
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
    h, pl = checked_recording(a.recording, a.force, need=())
    triads = "; ".join(f"{s} {k} [{u}]" if k else f"no {s} (partial record: absent_sensors)"
                       for s, k, u in (("accel", h.accel_kind, h.accel_units), ("gyro", h.gyro_kind, h.gyro_units)))
    emit(f"{a.recording}: valid calib-recording-1, {h.n_samples} samples at {h.sample_rate_hz} Hz "
          f"({h.duration_s / 3600:.3f} h), latitude {h.latitude_deg} deg; {triads}")
    if h.clock_summary:   # the time coordinate's fitted clock: jitter, gaps, dropped samples
        emit(f"{a.recording}: clock: {h.clock_summary}")
    emit(f"{a.recording}: plausible: {pl.describe()}")


def register(sub) -> None:
    """Add the ``import`` and ``validate`` sub-commands."""
    s = sub.add_parser("import", help="import a real recording with a settings YAML (config/import/*.yaml)")
    s.add_argument("settings")
    s.add_argument("out")
    s.add_argument("--topic", help="ROS bags: the sensor_msgs/msg/Imu topic (overrides the settings' topic)")
    s.set_defaults(fn=cmd_import)
    s = sub.add_parser("validate", help="check a calib-recording-1 file")
    s.add_argument("recording")
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.set_defaults(fn=cmd_validate)
