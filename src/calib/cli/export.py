"""``calib export CALIBRATION --format imutk|imucal|json --out PATH``: a calibration of ``calib fieldcal --out`` or
``calib calibrate`` (``default_calibration.nc``) in IMU-TK's, imucal's or calib's JSON format
(:mod:`calib.io.export_formats`).

The library modules the functions need (numpy, netCDF, scipy and more behind them) are imported inside them:
loaded only when a command runs, so that ``calib --help`` and a usage error answer at once."""
from __future__ import annotations

from calib.cli.shared import emit, output_file
from calib.core.errors import input_file
from calib.io import EXPORT_FORMATS as FORMATS


def cmd_export(a):
    from calib.io import export_formats

    input_file(a.calibration, "calibration file")
    cal = export_formats.load_calibration(a.calibration)
    if a.format == "imutk":
        for p in export_formats.imutk_paths(a.out).values():
            output_file(p, "IMU-TK calibration")
    else:
        output_file(a.out, f"{a.format} calibration")
    paths = export_formats.export(cal, a.format, a.out)
    emit("wrote " + ", ".join(str(p) for p in paths))


def register(sub) -> None:
    """Add the ``export`` sub-command."""
    s = sub.add_parser("export", help="a calibration in IMU-TK, imucal or calib JSON format")
    s.add_argument("calibration", help="calib fieldcal --out result.nc, or calibrate's default_calibration.nc")
    s.add_argument("--format", required=True, choices=FORMATS)
    s.add_argument("--out", required=True, help="output file (imutk: a prefix or a folder: <prefix>_acc.calib, "
                                                "<prefix>_gyro.calib, <prefix>_calib.txt)")
    s.set_defaults(fn=cmd_export)
