"""``calib navigate RECORDING.nc --out errors.nc``: pure-inertial navigation of a stationary recording.

The library modules the functions need (numpy, netCDF, scipy and more behind them) are imported inside them:
loaded only when a command runs, so that ``calib --help`` and a usage error answer at once."""
from __future__ import annotations

from calib.cli.shared import FORCE_HELP, checked_recording, emit, output_file, positive
from calib.core.errors import input_file


def cmd_navigate(a):
    from calib.io import recording
    from calib.studies import navigation_stage as navigation_study

    positive(a.nav_rate, "--nav-rate")
    positive(a.output_interval, "--output-interval")
    if a.calibration:
        input_file(a.calibration, "calibration file")
    output_file(a.out, "navigation output")
    input_file(a.recording, "recording")
    # the recording is checked sample by sample once (reuse_validation: the navigation's load does not read it again)
    with recording.reuse_validation():
        # what needs no sample first: a calibration file of the wrong kind, a wrong pairing of units and calibration
        # are named at once, not after the check of every sample of a long recording (4-5 s for 240 h at 100 Hz)
        inputs = navigation_study.check_navigation_inputs(a.recording, a.calibration)
        nav = {"nav_rate_hz": a.nav_rate, "output_interval_s": a.output_interval}
        checked_recording(a.recording, a.force)
        navigation_study.navigate_file(a.recording, a.calibration, a.out, nav, init="align" if a.align else "attrs",
                                       inputs=inputs)
    emit(f"wrote {a.out}")


def register(sub) -> None:
    """Add the ``navigate`` sub-command."""
    s = sub.add_parser("navigate", help="pure-inertial navigation of a stationary recording")
    s.add_argument("recording")
    s.add_argument("--out", required=True)
    s.add_argument("--calibration", help="default_calibration.nc of the calibrate stage (count recordings)")
    s.add_argument("--nav-rate", type=float, default=10.0)
    s.add_argument("--output-interval", type=float, default=60.0)
    s.add_argument("--align", action="store_true", help="self-align instead of using the recorded attitude")
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.set_defaults(fn=cmd_navigate)
