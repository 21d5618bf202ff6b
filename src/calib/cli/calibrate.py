"""The calibrations: ``calib calibrate RECORDING.nc --out DIR`` (Liu 2021's study on a session with a segment
table) and ``calib fieldcal RECORDING.nc`` (without a turntable record: real recordings).

The library modules the functions need (numpy, netCDF, scipy and more behind them) are imported inside them:
loaded only when a command runs, so that ``calib --help`` and a usage error answer at once."""
from __future__ import annotations

import json
from pathlib import Path

from calib.cli.shared import FORCE_HELP, checked_recording, emit, output_dir, output_file, study_config
from calib.core.errors import InputError, input_file, load_mapping


def cmd_calibrate(a):
    from calib.io.atomic import output_set
    from calib.signal import plausibility
    from calib.studies import calibration as calibration_study

    cfg = study_config(a.config)
    checked_recording(a.recording, a.force)
    if a.truth:
        input_file(a.truth, "truth file")
    if a.noise_record:
        checked_recording(a.noise_record, a.force, "noise record")
    output_dir(a.out)
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
    h, _ = checked_recording(a.recording, a.force, need=("accel",))   # accel-only: the gyro part is skipped with a note
    if imported is not None:
        _same_rate(imported, h, a.settings, a.recording)
    if a.out:
        output_file(a.out, "calibration")
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


def register(sub) -> None:
    """Add the ``calibrate`` and ``fieldcal`` sub-commands."""
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
