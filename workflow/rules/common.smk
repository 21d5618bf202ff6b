# Shared helpers for the per-stage files: result paths and the target list.
import glob
import json
import os

from snakemake.exceptions import WorkflowError

from calib.core.seeds import session_seed  # light: the Snakefile is parsed by every snakemake process

R = config["results"]
CAL = config["calibration"]
DIAG = config.get("diagnosis", {})


# How the long studies are split into jobs (config key `scatter`; their products do not depend on it): `unit`, a
# job per proof session, real recording and seed block, so that on a cluster more nodes mean less wait; an integer
# n, at most n jobs per study, each running its share of the units in turn; `auto` (the default), `unit` on a
# cluster and twice the cores on one machine, where every job's start-up (interpreter, imports, compiled kernels:
# about 1.7 s) is paid on the same cores. A job under a cluster executor (exec mode remote) decides as the
# submitting process did, so both see the same jobs.
def _scatter_jobs():
    s = config.get("scatter", "auto")
    if s != "auto":
        return None if s == "unit" else int(s)
    if workflow.remote_exec or workflow.non_local_exec:
        return None
    try:
        return 2 * int(workflow.cores)
    except WorkflowError:   # a dry run without --cores: no cores to size the jobs to
        return None


SCATTER_JOBS = _scatter_jobs()


def scatter(units):
    """The units of a study (names, in order) as its jobs: an ordered {job name: [units]}, a job per unit named by
    it; with at most n jobs (SCATTER_JOBS) fewer than the units, the units dealt round-robin over n jobs named
    ``j<i>of<n>`` (neighbours, often alike in cost, land in different jobs)."""
    units = list(units)
    k = SCATTER_JOBS
    if k is None or k >= len(units):
        return {u: [u] for u in units}
    return {f"j{i}of{k}": units[i::k] for i in range(k)}


def seed_blocks(n, per_job):
    """A seed study's seeds 0 .. n - 1 as [first, stop) blocks of near-equal size, in order, named "first_stop":
    at most ``per_job`` seeds a block in the `unit` mode, at most SCATTER_JOBS blocks otherwise, and at least two
    (both cores of a small machine). Every seed draws from its own streams (its index), so the gathered products do
    not depend on the blocks."""
    k = max(-(-n // per_job), min(n, 2))
    if SCATTER_JOBS is not None:
        k = max(min(k, SCATTER_JOBS), min(n, 2))
    return [f"{round(i * n / k)}_{round((i + 1) * n / k)}" for i in range(k)]


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
