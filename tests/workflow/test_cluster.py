"""Scale-out: the data and drift stages of the .test chain through the cluster-generic executor.

Every job is submitted by workflow/profiles/cluster-generic/submit.sh, which starts it as its own detached
process on this machine, and is followed by status.sh: a stage can only see what earlier stages wrote to
files. The run must succeed, each job must have run in a separate process, and the validation stage must have
compensated exactly the mean PSOBE estimate that the drift_pso job wrote. Then `snakemake --report` must build
one HTML report of those stages with their captions. Deselect with ``-m "not cluster"``.
"""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

ROOT = Path(__file__).resolve().parents[2]
PROFILE = ROOT / "workflow" / "profiles" / "cluster-generic"
pytestmark = pytest.mark.cluster


def _small_config(results: Path) -> dict:
    """The .test config, smaller: 0.5 h navigation session, 2 short PSO tests, a 0.1 h static check."""
    cfg = yaml.safe_load((ROOT / ".test" / "config.yaml").read_text())
    cfg["results"] = str(results)
    cfg["calibration_session"].update(dwell_s=5.0, rotation_rates_deg_s=[10.0])
    cfg["static_check"]["duration_h"] = 0.1
    cfg["navigation_session"]["duration_h"] = 0.5
    cfg["drift"].update(window_h=0.5, tests=2)
    cfg["drift"]["pso"].update(particles=8, generations=4)
    return cfg


def _snakemake(args, cwd, env, timeout):
    cmd = [sys.executable, "-m", "snakemake", "-s", str(ROOT / "Snakefile"), *args]
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def _cancel_leftovers(state: Path):
    """End any job still running (by the process-group id submit.sh recorded), e.g. after a timeout."""
    ids = [p.name[:-len(".pid")] for p in state.glob("*.pid") if not (state / (p.name[:-4] + ".exit")).exists()]
    if ids:
        subprocess.run([str(PROFILE / "cancel.sh"), *ids], env={**os.environ, "CALIB_CLUSTER_DIR": str(state)},
                       timeout=30, check=False)


def test_data_and_drift_stages_through_cluster_executor(tmp_path):
    work, results, state = tmp_path / "work", tmp_path / "results", tmp_path / "cluster"
    work.mkdir()
    cfgfile = tmp_path / "config.yaml"
    cfgfile.write_text(yaml.safe_dump(_small_config(results)))
    env = {**os.environ, "CALIB_TRACKING": "0", "CALIB_CLUSTER_DIR": str(state)}
    env.pop("SNAKEMAKE_PROFILE", None)
    targets = [str(results / "data" / "calibration_session.nc"), str(results / "data" / "static_check.nc"),
               str(results / "drift" / "validation_240h.nc")]
    try:
        r = _snakemake([*targets, "--profile", str(PROFILE), "--directory", str(work), "--configfile", str(cfgfile)],
                       cwd=tmp_path, env=env, timeout=600)
        assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]

        # five jobs, each submitted through submit.sh, each in its own process, all ended with exit code 0
        exits = sorted(state.glob("*.exit"))
        assert len(exits) == 5, (sorted(p.name for p in state.iterdir()), r.stderr[-3000:])
        assert all(p.read_text().strip() == "0" for p in exits)
        pids = {(state / (p.name[:-5] + ".pid")).read_text().strip() for p in exits}
        assert len(pids) == 5 and str(os.getpid()) not in pids
        assert "Submitted job" in r.stderr + r.stdout

        # the validation job read the drift_pso job's file: its compensation is that file's mean estimate
        with xr.open_dataset(results / "drift" / "pso_tests.nc", engine="netcdf4") as p, \
                xr.open_dataset(results / "drift" / "validation_240h.nc", engine="netcdf4") as v:
            mean_est = p["estimate"].values.mean(0)
            assert p.sizes["test"] == 2 and p.sizes["generation"] == 5
            np.testing.assert_allclose(v["compensation"].sel(stream="pso_mean").values, mean_est, rtol=1e-12)
            assert np.array_equal(v["compensation"].sel(stream="uncompensated").values, np.zeros(3))
            # the CF time coordinate is in seconds: the whole 0.5 h session of the config was navigated
            assert v["time"].attrs["units"] == "s"
            assert v["time"].values[-1] == pytest.approx(0.5 * 3600.0)
        for f in targets:
            assert Path(f).stat().st_size > 0

        # one HTML report of what ran, with the captions from workflow/report/
        report = tmp_path / "report.html"
        r = _snakemake([*targets, "--directory", str(work), "--report", str(report), "--configfile", str(cfgfile)],
                       cwd=tmp_path, env=env, timeout=300)
        assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
        html = report.read_text()
        caption = (ROOT / "workflow" / "report" / "fig4_drift.rst").read_text().split(".")[0]
        for needle in ("figure4_navigation.png", "table1_pso.csv", "figure2_estimates.png", "Gyro drift (He 2019)",
                       caption[:40]):
            assert needle in html, needle
    finally:
        _cancel_leftovers(state)
        shutil.rmtree(results, ignore_errors=True)
        shutil.rmtree(work, ignore_errors=True)
        (tmp_path / "report.html").unlink(missing_ok=True)
