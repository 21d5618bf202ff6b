"""``calib apply CALIBRATION RECORDING.nc OUT.nc``: a calibrated recording (specific force [m s-2] and angular
rate [rad s-1] rates, body frame of the calibration) with the source and calibration files and the calib version as
attributes.

The library modules the functions need (numpy, netCDF, scipy and more behind them) are imported inside them:
loaded only when a command runs, so that ``calib --help`` and a usage error answer at once."""
from __future__ import annotations

from pathlib import Path

from calib.cli.shared import FORCE_HELP, checked_recording, emit, output_file, sha256
from calib.core.errors import InputError, input_file


def cmd_apply(a):
    from calib.io import export_formats, recording
    from calib.io.netcdf import provenance

    input_file(a.calibration, "calibration file")
    cal = export_formats.load_calibration(a.calibration)
    h, _ = checked_recording(a.recording, a.force, need=("accel",))   # an accelerometer-only record: its accel
    output_file(a.out, "calibrated recording")
    if Path(a.out).resolve() == Path(a.recording).resolve():
        raise InputError("the output would replace the recording", file=a.out, fix="write to another file")
    cal.check_recording("accel", h.accel_units, h.accel_kind, a.recording)
    if cal.gyro is not None and "gyro" in h.sensors:
        cal.check_recording("gyro", h.gyro_units, h.gyro_kind, a.recording)
    prov = provenance("apply")
    prov.update({"source_file": str(a.recording), "source_file_sha256": sha256(a.recording),
                 "calibration_file": str(a.calibration), "calibration_file_sha256": sha256(a.calibration),
                 "calibration_kind": cal.kind, "calibration_applied": cal.how_to_apply()})
    fs = float(h.sample_rate_hz)
    if h.has_time:
        _apply_in_memory(a, cal, h, fs, prov)   # validated under its temporary name by recording.write
    else:
        _apply_chunked(a, cal, h, fs, prov)
        recording.validate(a.out)
    emit(f"wrote {a.out}")


def _rates(cal, h, fs, acc, gyr):
    ra = acc * (fs if h.accel_kind == "increment" else 1.0)
    if cal.gyro is None or gyr is None:
        return cal.apply(ra), None
    rg = gyr * (fs if h.gyro_kind == "increment" else 1.0)
    return cal.apply(ra, rg)


ACCEL_ATTRS = {"sample_kind": "rate", "units": "m s-2", "long_name": "calibrated specific force, body frame"}


GYRO_ATTRS = {"sample_kind": "rate", "units": "rad s-1", "long_name": "calibrated angular rate, body frame"}


def _apply_in_memory(a, cal, h, fs, prov):
    import numpy as np

    from calib.io import recording

    ds = recording.load(a.recording, validate_all=False)
    acc = np.asarray(ds["accel"].values, float)
    gyr = np.asarray(ds["gyro"].values, float) if "gyro" in ds else None   # (None: an accelerometer-only record)
    ca, cg = _rates(cal, h, fs, acc, gyr)
    out = ds.copy()
    out["accel"] = (("time", "axis"), ca, dict(ACCEL_ATTRS))
    if cg is not None:
        out["gyro"] = (("time", "axis"), cg, dict(GYRO_ATTRS))
    elif gyr is None:
        prov["calibration_note"] = "the recording holds no gyroscope (a partial record): the accelerometer calibrated"
    else:
        prov["calibration_note"] = "the calibration holds no gyro: gyro copied unchanged"
    out.attrs = {k: v for k, v in ds.attrs.items() if not k.startswith("_")}
    recording.write(out, a.out, prov)


def _apply_chunked(a, cal, h, fs, prov):
    """Long recordings without a time coordinate: chunk by chunk (memory flat)."""
    import netCDF4
    import numpy as np

    from calib.io import recording

    if cal.gyro is None:
        raise InputError("a long recording needs a calibration with a gyro", file=a.calibration, field="gyro")
    if "gyro" not in h.sensors:
        raise InputError("a long recording (no time coordinate) is calibrated chunk by chunk with both triads; this "
                         "one holds accelerometers only", file=a.recording, field="gyro",
                         fix="import it with a time coordinate (fewer than 2 000 000 samples per file)")
    with netCDF4.Dataset(a.recording) as nc:
        has_t = "temperature" in nc.variables
    attrs = {k: v for k, v in h.attrs.items() if k not in ("Conventions", "conventions", "latitude_deg", "height_m",
                                                            "sample_rate_hz", "t0_s", "source", "sensor")}
    attrs.update(prov)
    with recording.LongRecordingWriter(a.out, h.n_samples, fs, latitude_deg=h.latitude_deg, accel_units="m s-2",
                                       gyro_units="rad s-1", accel_kind="rate", gyro_kind="rate",
                                       height_m=h.height_m, t0_s=h.t0_s, source=str(h.attrs.get("source", "")),
                                       sensor=str(h.attrs.get("sensor", "")), extra_attrs=attrs,
                                       temperature=has_t) as w, netCDF4.Dataset(a.recording) as nc:
        for i0, acc, gyr in recording.iter_raw_chunks(a.recording, h):
            ca, cg = _rates(cal, h, fs, acc, gyr)
            temp = np.asarray(nc.variables["temperature"][i0:i0 + len(acc)], float) if has_t else None
            w.append(ca, cg, temp)


def register(sub) -> None:
    """Add the ``apply`` sub-command."""
    s = sub.add_parser("apply", help="write a calibrated recording (m s-2, rad s-1)")
    s.add_argument("calibration")
    s.add_argument("recording")
    s.add_argument("out")
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.set_defaults(fn=cmd_apply)
