"""Sub-commands that meet users where their data live: ROS bags in, Kalibr / IMU-TK / imucal out.

    calib noise RECORDING.nc [--out DIR] [--kalibr imu.yaml] [--topic /imu] [--bootstrap N] [--seed S]
    calib export CALIBRATION --format imutk|imucal|json --out PATH
    calib apply CALIBRATION RECORDING.nc OUT.nc

``noise``: IEEE Std 952-1997 terms with intervals of a long static record (:mod:`calib.signal.ieee952`):
``noise.json``, ``noise.md`` and the figure ``allan.svg`` / ``allan.png`` in DIR (default: ``<recording
stem>_noise`` beside the recording), and with ``--kalibr`` Kalibr's ``imu.yaml``. ``export``: a calibration of
``calib fieldcal --out`` or ``calib calibrate`` (``default_calibration.nc``) in IMU-TK's, imucal's or calib's
JSON format (:mod:`calib.io.export_formats`). ``apply``: a calibrated recording (specific force [m s-2] and
angular rate [rad s-1] rates, body frame of the calibration) with the source and calibration files and the calib
version as attributes.

Registered in :func:`calib.cli.main` by :func:`register` (one call), so the parser entries live here.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from calib.core.errors import InputError, input_file, load_mapping

NOISE_FILES = ("noise.json", "noise.md", "allan.svg", "allan.png")


def sha256(path) -> str:
    """SHA-256 of a file (:func:`calib.ingest.common.sha256`): the importers are loaded only by the commands that
    need them, not by every start of the command line."""
    from calib.ingest.common import sha256 as file_sha256

    return file_sha256(path)


def _cli():
    import calib.cli as cli  # the package's helpers (emit, output checks, recording checks); imported late

    return cli


# --------------------------------------------------------------------------- noise


def _static_check(acc_si, fs) -> str | None:
    """A warning when the record does not look static: the 1 s means of the specific force turn by more than 2
    degrees, or their norm changes by more than 2 %."""
    import numpy as np

    w = max(1, int(round(fs)))
    nb = len(acc_si) // w
    if nb < 2:
        return None
    m = acc_si[: nb * w].reshape(nb, w, 3).mean(axis=1)
    norm = np.linalg.norm(m, axis=1)
    ref = np.median(m, axis=0)
    cos = (m @ ref) / np.maximum(norm * np.linalg.norm(ref), 1e-300)
    turn = float(np.degrees(np.arccos(np.clip(cos.min(), -1.0, 1.0))))
    spread = float((norm.max() - norm.min()) / max(np.median(norm), 1e-300))
    if turn > 2.0 or spread > 0.02:
        return (f"the record does not look static (1 s means of the specific force turn by up to {turn:.3g} deg, "
                f"their norm varies by {100 * spread:.2g} %): the noise terms assume the unit at rest")
    return None


def cmd_noise(a):
    from calib.core.progress import Progress
    from calib.figures import style
    from calib.io import export_formats, recording
    from calib.io.atomic import output_set, write_json, write_text
    from calib.signal import ieee952
    from calib.signal.segments import rate_reading

    cli = _cli()
    if a.bootstrap < 20:
        raise InputError(f"--bootstrap must be at least 20 (got {a.bootstrap})")
    if not 0.5 <= a.confidence < 1.0:
        raise InputError(f"--confidence must be in [0.5, 1) (got {a.confidence:g})")
    h, _ = cli._recording(a.recording, a.force, need=())   # a partial record: the terms of the triad it holds
    out = cli._output_dir(a.out or Path(a.recording).with_name(Path(a.recording).stem + "_noise"))
    if a.kalibr:
        cli._output_file(a.kalibr, "Kalibr imu.yaml")
    ds = recording.load(a.recording, validate_all=False)
    fs = float(h.sample_rate_hz)
    notes = []
    drops = int(ds.attrs.get("clock_dropped_samples", 0) or 0)
    if drops:
        notes.append(f"{drops} dropped sample(s) in {h.n_samples}: the Allan deviation takes the samples as "
                     "uniform (each drop shifts later samples by one period)")
    data, units = {}, {}
    sensors = [s for s in ("gyro", "accel") if s in h.sensors]
    for s in h.absent:
        notes.append(f"no {s} in the record (a partial record, absent_sensors): its noise terms are not estimated")
    for sensor in sensors:
        y, unit = rate_reading(ds, sensor)
        f = recording.unit_factor(unit)   # None for counts: the terms stay in the record's unit
        if f is None:
            data[sensor], units[sensor] = y, unit
        else:
            si = "m s-2" if sensor == "accel" else "rad s-1"
            data[sensor], units[sensor] = y * f, si
    if units.get("accel") == "m s-2":
        w = _static_check(data["accel"], fs)
        if w:
            notes.append(w)
            print(f"warning: {w}", file=sys.stderr)
    if a.kalibr and h.absent:
        raise InputError(f"Kalibr's imu.yaml needs the noise of both triads and the record holds no "
                         f"{' or '.join(h.absent)} (a partial record)", file=a.recording, field="--kalibr",
                         fix="drop --kalibr (noise.json and noise.md hold the terms of the triad recorded), or give "
                             "a static record of both triads")
    if a.kalibr and (units["accel"] != "m s-2" or units["gyro"] != "rad s-1"):
        raise InputError(f"Kalibr needs SI rates, the record is accel [{units['accel']}], gyro [{units['gyro']}]",
                         file=a.recording, field="--kalibr",
                         fix="calibrate it first: calib apply CALIBRATION RECORDING OUT.nc, then calib noise OUT.nc")
    rostopic = a.topic or ds.attrs.get("ros_topic")
    if a.kalibr and not rostopic:
        raise InputError("Kalibr's imu.yaml needs the IMU topic and the recording names none", file=a.recording,
                         field="--topic", fix="pass --topic /imu (the topic Kalibr will read)")
    results = {}
    for k, sensor in enumerate(("gyro", "accel")):
        if sensor not in data:
            continue
        bar = Progress(a.bootstrap, f"bootstrap {sensor}")
        try:
            results[sensor] = ieee952.noise_terms(data[sensor], fs, confidence=a.confidence, n_boot=a.bootstrap,
                                                  seed=a.seed + k, unit=units[sensor],
                                                  progress=lambda d, n: bar(d))
        except ieee952.NoiseTermsError as exc:
            raise InputError(str(exc), file=a.recording, field=sensor, fix=exc.fix) from None
        for s in results[sensor].short_record_notes():   # the tau range, the terms not estimated, a misfit
            notes.append(f"{sensor}: {s}")
            print(f"calib noise: {sensor}: {s}", file=sys.stderr)
    kal = ieee952.kalibr_parameters(results["gyro"], results["accel"]) \
        if units.get("accel") == "m s-2" and units.get("gyro") == "rad s-1" else None
    src = Path(a.recording).name
    rep = {"source": str(a.recording), "source_sha256": sha256(a.recording), "calib_version": _version(),
           "model": "AVAR(tau) = 3 Q^2/tau^2 + N^2/tau + (2 ln 2/pi) B^2 + K^2 tau/3 (IEEE Std 952-1997 Annex C)",
           "definitions": ieee952.DEFINITIONS, "sensors": {s: r.to_dict() for s, r in results.items()},
           "kalibr": kal, "notes": notes}
    out.mkdir(parents=True, exist_ok=True)
    with output_set():   # the report, its figures and Kalibr's file: all of them or none
        write_json(rep, out / "noise.json")
        write_text(out / "noise.md", ieee952.report_markdown(results, src, kal, notes))
        for suffix in (".svg", ".png"):
            style.save(ieee952.plot(results, f"Allan deviation of {src} ({h.n_samples / fs / 3600.0:.3g} h at "
                                             f"{fs:.6g} Hz)"), out / f"allan{suffix}")
        if a.kalibr:
            write_text(a.kalibr, export_formats.kalibr_yaml(kal, rostopic, fs, src))
    lines = {"out": str(out)}
    if kal:
        lines["kalibr"] = {k: v["value"] for k, v in kal.items()}
        if a.kalibr:
            lines["kalibr_file"] = str(a.kalibr)
    cli.emit(json.dumps(lines, indent=2))


def _version():
    from calib import __version__

    return __version__


# --------------------------------------------------------------------------- export


def cmd_export(a):
    from calib.io import export_formats

    cli = _cli()
    input_file(a.calibration, "calibration file")
    cal = export_formats.load_calibration(a.calibration)
    if a.format == "imutk":
        for p in export_formats.imutk_paths(a.out).values():
            cli._output_file(p, "IMU-TK calibration")
    else:
        cli._output_file(a.out, f"{a.format} calibration")
    paths = export_formats.export(cal, a.format, a.out)
    cli.emit("wrote " + ", ".join(str(p) for p in paths))


# --------------------------------------------------------------------------- apply


def cmd_apply(a):
    from calib.io import export_formats, recording
    from calib.io.netcdf import provenance

    cli = _cli()
    input_file(a.calibration, "calibration file")
    cal = export_formats.load_calibration(a.calibration)
    h, _ = cli._recording(a.recording, a.force, need=("accel",))   # an accelerometer-only record: its accel
    cli._output_file(a.out, "calibrated recording")
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
    cli.emit(f"wrote {a.out}")


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


# --------------------------------------------------------------------------- registration


def register(sub) -> None:
    """Add the ``noise``, ``export`` and ``apply`` sub-commands."""
    from calib.io import EXPORT_FORMATS as FORMATS   # (the export module loads netCDF: not for every start)

    cli = _cli()
    s = sub.add_parser("noise", help="IEEE-952 noise terms (Allan deviation) of a static record; Kalibr imu.yaml")
    s.add_argument("recording")
    s.add_argument("--out", help="folder for noise.json, noise.md, allan.svg/png (default: <stem>_noise beside "
                                 "the recording)")
    s.add_argument("--kalibr", help="write Kalibr's imu.yaml here")
    s.add_argument("--topic", help="rostopic for Kalibr (default: the recording's ros_topic attribute)")
    s.add_argument("--bootstrap", type=int, default=200, help="bootstrap replicates for the intervals (default 200)")
    s.add_argument("--seed", type=int, default=0, help="seed of the bootstrap (default 0)")
    s.add_argument("--confidence", type=float, default=0.95, help="confidence of the intervals (default 0.95)")
    s.add_argument("--force", action="store_true", help=cli.FORCE_HELP)
    s.set_defaults(fn=cmd_noise)
    s = sub.add_parser("export", help="a calibration in IMU-TK, imucal or calib JSON format")
    s.add_argument("calibration", help="calib fieldcal --out result.nc, or calibrate's default_calibration.nc")
    s.add_argument("--format", required=True, choices=FORMATS)
    s.add_argument("--out", required=True, help="output file (imutk: a prefix or a folder: <prefix>_acc.calib, "
                                                "<prefix>_gyro.calib, <prefix>_calib.txt)")
    s.set_defaults(fn=cmd_export)
    s = sub.add_parser("apply", help="write a calibrated recording (m s-2, rad s-1)")
    s.add_argument("calibration")
    s.add_argument("recording")
    s.add_argument("out")
    s.add_argument("--force", action="store_true", help=cli.FORCE_HELP)
    s.set_defaults(fn=cmd_apply)

