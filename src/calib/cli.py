"""The ``calib`` command line: the same library functions as the workflow rules, for work on single files.

    calib simulate calibration OUT.nc [--config config/config.yaml] [--seed N]
    calib simulate navigation OUT.nc [--hours H]
    calib import SETTINGS.yaml OUT.nc
    calib validate RECORDING.nc
    calib calibrate RECORDING.nc --out DIR [--quick] [--noise-record LONG_STATIC.nc]
    calib fieldcal RECORDING.nc [--settings S.yaml] [--out result.nc]
    calib navigate RECORDING.nc --out errors.nc [--calibration DIR/default_calibration.nc]
    calib diagnose RECORDING.nc --out DIR [--settings FILE.yaml|json]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

DEFAULT_CONFIG = "config/config.yaml"


def _config(path):
    p = Path(path)
    if not p.exists():
        raise SystemExit(f"config file {p} not found -- pass --config")
    cfg = yaml.safe_load(p.read_text())
    schema = Path(__file__).resolve().parents[2] / "workflow" / "schemas" / "config.schema.yaml"
    if schema.exists():
        from snakemake.utils import validate

        validate(cfg, str(schema))
    return cfg


def cmd_simulate(a):
    from calib.studies import stages

    cfg = _config(a.config)
    key = {"calibration": "calibration_session", "navigation": "navigation_session"}.get(a.kind, a.kind)
    seed = stages.session_seed(cfg["seeds"]["data"], key) if a.seed is None else a.seed
    truth = a.truth or str(Path(a.out).with_suffix(".truth.json"))
    if a.kind == "calibration":
        stages.simulate_calibration(cfg["calibration_session"], cfg["site"], seed, a.out, truth)
    elif a.kind == "navigation":
        s = dict(cfg["navigation_session"])
        if a.hours:
            s["duration_h"] = a.hours
        stages.simulate_navigation(s, cfg["site"], seed, a.out, truth)
    else:
        c = dict(cfg["static_check"])
        if a.hours:
            c["duration_h"] = a.hours
        stages.simulate_static_check(c, cfg["calibration_session"], cfg["site"], seed, a.out, truth)
    print(f"wrote {a.out} (truth in {truth})")


def cmd_import(a):
    from calib.ingest import importers

    out = importers.import_recording(importers.load_settings(a.settings), a.out)
    print(f"wrote {out}")


def cmd_validate(a):
    from calib.io import recording

    h = recording.validate(a.recording)
    print(f"{a.recording}: valid calib-recording-1, {h.n_samples} samples at {h.sample_rate_hz} Hz "
          f"({h.duration_s / 3600:.3f} h), latitude {h.latitude_deg} deg; accel {h.accel_kind} [{h.accel_units}], "
          f"gyro {h.gyro_kind} [{h.gyro_units}]")


def cmd_calibrate(a):
    from calib.studies import calibration as calibration_study

    cfg = _config(a.config)
    cc = dict(cfg["calibration"])
    if a.quick:
        cc.update(runs=3, methods=["ide", "ide_lsq", "lsq"])
    calibration_study.run_study(a.recording, a.truth, a.out, cc, cfg["seeds"]["calibration"],
                                noise_record=a.noise_record)


def cmd_fieldcal(a):
    from calib import fieldcal
    from calib.io.netcdf import write_netcdf

    settings = None
    if a.settings:
        settings = yaml.safe_load(Path(a.settings).read_text())
        if "format" in settings:  # an import-settings file: use its optional 'fieldcal:' section
            settings = settings.get("fieldcal")
    res = fieldcal.fieldcal_recording(a.recording, settings)
    print(json.dumps(res.summary(), indent=2, default=str))
    if a.out:
        write_netcdf(res.to_dataset(), a.out)


def cmd_navigate(a):
    from calib.studies import navigation as navigation_study

    nav = {"nav_rate_hz": a.nav_rate, "output_interval_s": a.output_interval}
    navigation_study.navigate_file(a.recording, a.calibration, a.out, nav, init="align" if a.align else "attrs")
    print(f"wrote {a.out}")


def cmd_diagnose(a):
    from calib.diagnosis import diagnose

    settings = None
    if a.settings:   # overrides of calib.diagnosis.DEFAULT_SETTINGS
        txt = Path(a.settings).read_text()
        settings = yaml.safe_load(txt) if a.settings.endswith((".yaml", ".yml")) else json.loads(txt)
    rep = diagnose(a.recording, settings, out_dir=a.out)
    print(json.dumps({k: rep[k] for k in ("verdict",) if k in rep}, indent=2))
    return {"adequate": 0, "missing_physics": 1}.get(rep["verdict"], 2)   # exit code: 2 inconclusive


def main(argv=None):
    p = argparse.ArgumentParser(prog="calib", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("simulate", help="synthetic sessions (data stage)")
    s.add_argument("kind", choices=["calibration", "navigation", "static_check"])
    s.add_argument("out")
    s.add_argument("--config", default=DEFAULT_CONFIG)
    s.add_argument("--seed", type=int)
    s.add_argument("--hours", type=float)
    s.add_argument("--truth")
    s.set_defaults(fn=cmd_simulate)
    s = sub.add_parser("import", help="import a real recording with a settings YAML (config/import/*.yaml)")
    s.add_argument("settings")
    s.add_argument("out")
    s.set_defaults(fn=cmd_import)
    s = sub.add_parser("validate", help="check a calib-recording-1 file")
    s.add_argument("recording")
    s.set_defaults(fn=cmd_validate)
    s = sub.add_parser("calibrate", help="Liu 2021 calibration study on a session with a segment table")
    s.add_argument("recording")
    s.add_argument("--out", required=True)
    s.add_argument("--truth")
    s.add_argument("--config", default=DEFAULT_CONFIG)
    s.add_argument("--quick", action="store_true", help="3 runs of IDE, IDE+polish and least squares only")
    s.add_argument("--noise-record", default=None,
                   help="long static recording of the same unit: its Allan deviation gives the bias instability "
                        "(slow noise) of the default calibration's segment means")
    s.set_defaults(fn=cmd_calibrate)
    s = sub.add_parser("fieldcal", help="calibration without a turntable record (real recordings)")
    s.add_argument("recording")
    s.add_argument("--settings")
    s.add_argument("--out")
    s.set_defaults(fn=cmd_fieldcal)
    s = sub.add_parser("navigate", help="pure-inertial navigation of a stationary recording")
    s.add_argument("recording")
    s.add_argument("--out", required=True)
    s.add_argument("--calibration", help="default_calibration.nc of the calibrate stage (count recordings)")
    s.add_argument("--nav-rate", type=float, default=10.0)
    s.add_argument("--output-interval", type=float, default=60.0)
    s.add_argument("--align", action="store_true", help="self-align instead of using the recorded attitude")
    s.set_defaults(fn=cmd_navigate)
    s = sub.add_parser("diagnose", help="locate and name the physics a model leaves out")
    s.add_argument("recording")
    s.add_argument("--out", required=True)
    s.add_argument("--settings", help="JSON or YAML file overriding calib.diagnosis.DEFAULT_SETTINGS")
    s.set_defaults(fn=cmd_diagnose)
    a = p.parse_args(argv)
    try:
        code = a.fn(a)
    except (ValueError, FileNotFoundError) as exc:  # RecordingError and friends carry file, field and fix
        print(f"calib {a.cmd}: error: {exc}", file=sys.stderr)
        return 2
    return code or 0


if __name__ == "__main__":
    sys.exit(main())
