# Shared helpers for the per-stage files: result paths and the target list.
import glob
import json
import os

from calib.core.seeds import session_seed  # light: the Snakefile is parsed by every snakemake process

R = config["results"]
CAL = config["calibration"]
DIAG = config.get("diagnosis", {})


def sub(section):
    """A config section as params (values read straight from config would not trigger reruns)."""
    return json.loads(json.dumps(config[section]))


def import_settings():
    """Importer settings of a real-recording study (data_dir resolved against the settings file; without it the
    files are under the config's optional data_root, else $CALIB_DATA, else ../shared/data)."""
    from calib.ingest import importers

    return importers.load_settings(config["recording"]["import"], data_root=config.get("data_root"))


def calibrates(rec) -> bool:
    """A real recording is field-calibrated unless its config says ``fieldcal: false`` (a record without static
    poses, e.g. a long static one for the drift study); no ``fieldcal:`` key means the default settings."""
    return rec.get("fieldcal", {}) is not False


def all_targets():
    if config.get("recording"):
        rec = config["recording"]
        t = [f"{R}/calibration/fieldcal.json"] if calibrates(rec) else []
        t += [f"{R}/drift/real_drift.json"] if "drift" in rec else []
        return t + ([f"{R}/diagnosis/report.json"] if rec.get("diagnose", True) else [])
    t = [
        f"{R}/calibration/tables/table5_methods.csv",
        f"{R}/navigation/figure10_static_check.png",
        f"{R}/navigation/static_check_errors.nc",
        f"{R}/drift/table1_pso.csv",
        f"{R}/drift/validation_240h.nc",
        f"{R}/drift/noise_seeds.csv",
    ]
    if config["calibration"].get("z_seeds", 0) > 0:
        t.append(f"{R}/calibration/zscores.csv")
    if DIAG:
        t.append(f"{R}/diagnosis/report.json")
        if DIAG.get("proof", {}).get("n_seeds", 0) > 0:
            t.append(f"{R}/proof/proof.json")
        if DIAG.get("real", False):
            t.append(f"{R}/diagnosis/real/real.json")
        if DIAG.get("real_proof", {}).get("enabled", False):
            t.append(f"{R}/diagnosis/real_proof/real_proof.json")
    return t


def noise_record_input(wildcards):
    """The long static record of the same unit (the slow noise of the default calibration's segment means),
    when calibration.noise_record = static_check."""
    return {"noise_record": f"{R}/data/static_check.nc"} if CAL.get("noise_record") == "static_check" else {}


def z_noise_record_input(wildcards):
    """calibration_z reads static_check.nc only in the 'shared' mode; 'per_seed' simulates one per seed."""
    if CAL.get("noise_record") == "static_check" and CAL.get("z_noise_record", "per_seed") == "shared":
        return {"noise_record": f"{R}/data/static_check.nc"}
    return {}


def diagnosis_input(wildcards):
    """The study's recording; for an imported one also its field calibration, whose static intervals the
    diagnosis tests (calibration -> diagnosis)."""
    rec = config.get("recording")
    if rec:
        out = {"recording": f"{R}/data/recording.nc"}
        if calibrates(rec):
            out["fieldcal"] = f"{R}/calibration/fieldcal.nc"
        return out
    # the synthetic unit's long static record: the measured slow noise of the adequacy tests
    return {"recording": f"{R}/data/calibration_session.nc", "noise_record": f"{R}/data/static_check.nc"}
