# Shared helpers for the per-stage files: result paths and the target list.
import glob
import json
import os

R = config["results"]
CAL = config["calibration"]
DIAG = config.get("diagnosis", {})


def sub(section):
    """A config section as params (values read straight from config would not trigger reruns)."""
    return json.loads(json.dumps(config[section]))


def import_settings():
    """Importer settings of a real-recording study (data_dir resolved against the settings file)."""
    from calib import importers

    return importers.load_settings(config["recording"]["import"])


def all_targets():
    if config.get("recording"):
        rec = config["recording"]
        t = [f"{R}/calibration/fieldcal.json"] if "fieldcal" in rec else []
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
    return t
