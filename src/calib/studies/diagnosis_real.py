"""The mismatch diagnosis on the shared real recordings, and an injection test on one of them: a known
accelerometer term added to the IMU-TK Xsens session in the sensor model its own norm calibration identifies
must be named, and its estimate must bracket the injected value."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calib.diagnosis import (DEFAULT_SETTINGS, Problem, diagnose_dataset, inconclusive_report,
                             rate_readings, report_markdown)
from calib.diagnosis.limits import ACCEL_TERMS, add_accel_term, norm_accel_model
from calib.ingest import importers
from calib.io.atomic import write_json as write_json_atomic, write_text as write_text_atomic
from calib.signal import detect
from calib.sim import effects
from calib.studies.diagnosis_score import truth_value

def import_real(settings_path):
    """Import one shared real recording in memory; add detected static segments when it has no segment table."""
    s = importers.load_settings(settings_path)
    ds = importers.import_dataset(s)
    ds.attrs["_path"] = f"{Path(settings_path).name} ({s.get('sensor', '')})"
    if "segment_index" not in ds:
        det = detect.detect_in_recording(ds)
        ds = detect.add_segment_table(ds, det)
    return ds


def inject_accel_term(ds, prob: Problem, eid: str, params: dict):
    """Add an accelerometer term to a recording's accel samples, in the sensor model identified by the norm
    calibration ``prob`` (:func:`norm_accel_model`), through the physical transfer function of
    :mod:`calib.sim.physical` (not the registry formulas the diagnosis fits; :func:`add_accel_term`). ``eid``: a
    quadratic or cubic nonlinearity or a scale asymmetry (registry units). Returns the modified dataset (rate
    samples; counts stay counts)."""
    if eid not in ACCEL_TERMS:
        raise ValueError(f"inject: {eid!r} cannot be injected into a real recording; one of {sorted(ACCEL_TERMS)}")
    gain, b = norm_accel_model(prob)
    y, _ = rate_readings(ds, "accel")
    add = add_accel_term(y, gain, b, eid, effects.resolve({eid: params})[eid][ACCEL_TERMS[eid]]) - y
    out = ds.copy()
    var = out["accel"]
    if var.attrs.get("sample_kind") == "increment":
        add = add / float(ds.attrs["sample_rate_hz"])
    out["accel"] = (var.dims, np.asarray(var.values, float) + add, var.attrs)
    return out


def run_real(out_dir, config_dir=None, settings=None, inject=None) -> dict:
    """Diagnose every imported recording of ../shared/data (import settings in ``config/import``), and, on the
    IMU-TK Xsens session, the same recording with a known accelerometer term added (``inject``: {id: params},
    default a quadratic nonlinearity). Writes ``out_dir/<name>/report.*`` and ``out_dir/real.json``."""
    out_dir = Path(out_dir)
    config_dir = Path(config_dir) if config_dir else Path(__file__).resolve().parents[3] / "config" / "import"
    st = {**DEFAULT_SETTINGS, **(settings or {})}
    rows = []
    probs = {}
    for cfg in sorted(config_dir.glob("*.yaml")):
        name = cfg.stem
        try:
            ds = import_real(cfg)
        except Exception as exc:  # noqa: BLE001 - record any import/detection failure as inconclusive
            rep = inconclusive_report(cfg, st, f"import or static detection failed: {exc}")
            write_json_atomic(rep, out_dir / name / "report.json")
            write_text_atomic(out_dir / name / "report.md", report_markdown(rep))
            rows.append({"recording": name, "verdict": "inconclusive", "reason": rep["verdict_reason"]})
            continue
        rep, prob = diagnose_dataset(ds, out_dir / name, st, path=str(cfg))
        probs[name] = (ds, prob)
        rows.append({"recording": name, "verdict": rep["verdict"], "reason": rep.get("verdict_reason"),
                     "model": rep.get("model"), "found": [{"key": f["key"], "delta_bic": f["delta_bic"],
                                                           "aliases": [a["key"] for a in f["aliases"]]}
                                                          for f in rep.get("found", [])],
                     "chi2_before": rep.get("goodness_of_fit", {}).get("before"),
                     "noise": rep.get("noise", {}).get("method")})
    injection = None
    key = next((k for k in probs if k.startswith("imu_tk")), None)
    if key is not None and probs[key][1] is not None:
        ds, prob = probs[key]
        inject = inject or {"accel_quadratic_nonlinearity": {"k2_ug_per_g2": [4000.0, -3000.0, 2500.0]}}
        eid, params = next(iter(inject.items()))
        ds2 = inject_accel_term(ds, prob, eid, params)
        rep2, _ = diagnose_dataset(ds2, out_dir / f"{key}_injected", st, path=f"{key} + injected {eid}")
        rep0 = json.loads((out_dir / key / "report.json").read_text())
        base_vals = {}
        for f in rep0.get("found", []) + rep0.get("absent", []):
            if f["effect"] == eid:
                for p in (f.get("parameters") or f.get("upper_bound_95", [])):
                    base_vals[p["name"]] = p.get("value")
        rec = []
        for f in rep2.get("found", []):
            if f["effect"] == eid:
                for p in f["parameters"]:
                    tv = truth_value(effects_resolve(eid, params), p["name"])
                    b0 = base_vals.get(p["name"]) or 0.0
                    rec.append({"name": p["name"], "injected": tv, "found": p["value"], "ci95": p["ci95"],
                                "found_minus_uninjected": p["value"] - b0,
                                "injected_inside_ci95_of_difference": bool(
                                    p["ci95"][0] - b0 <= tv <= p["ci95"][1] - b0)})
        injection = {"recording": key, "injected": inject, "verdict": rep2["verdict"],
                     "found": [f["key"] for f in rep2.get("found", [])], "recovered": rec,
                     "named": any(f["effect"] == eid for f in rep2.get("found", []))}
    out = {"recordings": rows, "injection": injection}
    write_json_atomic(out, out_dir / "real.json")
    return out


def effects_resolve(eid, params):
    """The full parameters (registry defaults filled in) of effect ``eid`` given ``params``."""
    return effects.resolve({eid: params})[eid]

