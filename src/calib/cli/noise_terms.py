"""``calib noise RECORDING.nc [--out DIR] [--kalibr imu.yaml]``: IEEE Std 952-1997 terms with intervals of a long
static record (:mod:`calib.signal.ieee952`): ``noise.json``, ``noise.md`` and the figure ``allan.svg`` /
``allan.png`` in DIR (default: ``<recording stem>_noise`` beside the recording), and with ``--kalibr`` Kalibr's
``imu.yaml``.

The library modules the functions need (numpy, netCDF, scipy and more behind them) are imported inside them:
loaded only when a command runs, so that ``calib --help`` and a usage error answer at once."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from calib import __version__
from calib.cli.shared import FORCE_HELP, checked_recording, emit, output_dir, output_file, sha256
from calib.core.errors import InputError
from calib.core.progress import Progress


NOISE_FILES = ("noise.json", "noise.md", "allan.svg", "allan.png")


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
    from calib.figures import allan_plots, style
    from calib.io import export_formats, recording
    from calib.io.atomic import output_set, write_json, write_text
    from calib.signal import ieee952
    from calib.signal.segments import rate_reading

    if a.bootstrap < 20:
        raise InputError(f"--bootstrap must be at least 20 (got {a.bootstrap})")
    if not 0.5 <= a.confidence < 1.0:
        raise InputError(f"--confidence must be in [0.5, 1) (got {a.confidence:g})")
    h, _ = checked_recording(a.recording, a.force, need=())   # a partial record: the terms of the triad it holds
    out = output_dir(a.out or Path(a.recording).with_name(Path(a.recording).stem + "_noise"))
    if a.kalibr:
        output_file(a.kalibr, "Kalibr imu.yaml")
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
    rep = {"source": str(a.recording), "source_sha256": sha256(a.recording), "calib_version": __version__,
           "model": "AVAR(tau) = 3 Q^2/tau^2 + N^2/tau + (2 ln 2/pi) B^2 + K^2 tau/3 (IEEE Std 952-1997 Annex C)",
           "definitions": ieee952.DEFINITIONS, "sensors": {s: r.to_dict() for s, r in results.items()},
           "kalibr": kal, "notes": notes}
    out.mkdir(parents=True, exist_ok=True)
    with output_set():   # the report, its figures and Kalibr's file: all of them or none
        write_json(rep, out / "noise.json")
        write_text(out / "noise.md", ieee952.report_markdown(results, src, kal, notes))
        panels = ieee952.figure_data(results)
        for suffix in (".svg", ".png"):
            style.save(allan_plots.noise_terms(panels, f"Allan deviation of {src} ({h.n_samples / fs / 3600.0:.3g} "
                                                       f"h at {fs:.6g} Hz)"), out / f"allan{suffix}")
        if a.kalibr:
            write_text(a.kalibr, export_formats.kalibr_yaml(kal, rostopic, fs, src))
    lines = {"out": str(out)}
    if kal:
        lines["kalibr"] = {k: v["value"] for k, v in kal.items()}
        if a.kalibr:
            lines["kalibr_file"] = str(a.kalibr)
    emit(json.dumps(lines, indent=2))


def register(sub) -> None:
    """Add the ``noise`` sub-command."""
    s = sub.add_parser("noise", help="IEEE-952 noise terms (Allan deviation) of a static record; Kalibr imu.yaml")
    s.add_argument("recording")
    s.add_argument("--out", help="folder for noise.json, noise.md, allan.svg/png (default: <stem>_noise beside "
                                 "the recording)")
    s.add_argument("--kalibr", help="write Kalibr's imu.yaml here")
    s.add_argument("--topic", help="rostopic for Kalibr (default: the recording's ros_topic attribute)")
    s.add_argument("--bootstrap", type=int, default=200, help="bootstrap replicates for the intervals (default 200)")
    s.add_argument("--seed", type=int, default=0, help="seed of the bootstrap (default 0)")
    s.add_argument("--confidence", type=float, default=0.95, help="confidence of the intervals (default 0.95)")
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.set_defaults(fn=cmd_noise)
