"""The SLURM profiles and the pre-flight check of tools/slurm_run.py.

The profiles must run on a cluster without editing: no placeholder account or partition, both read from the
environment variables sbatch itself reads (SBATCH_ACCOUNT, SBATCH_PARTITION) through Snakemake's own evaluation
of resource expressions, runtime and mem_mb in the same default-resources list, the status command that works
without accounting. The pre-flight check must refuse a run with a job no node can ever start, and pass one that
fits: here against a stand-in ``sbatch --test-only`` that answers as SLURM 22.05 does for one node of 2 CPUs and
24105 MB ("Requested node configuration is not available", exit 1). The real cluster: tools/slurm_cluster.sh.
"""
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from snakemake.resources import Resource

ROOT = Path(__file__).resolve().parents[2]
PROFILES = [ROOT / "workflow" / "profiles" / name / "config.yaml" for name in ("slurm", "slurm-small")]
sys.path.insert(0, str(ROOT / "tools"))
import slurm_run  # noqa: E402  (tools/ is not a package)

NEEDS_PLUGIN = pytest.mark.skipif(importlib.util.find_spec("snakemake_executor_plugin_slurm") is None,
                                  reason="snakemake-executor-plugin-slurm is not installed (python3 run.py setup "
                                         "--slurm)")


def _evaluate(expr: str):
    """A default-resources value as Snakemake evaluates it for a job."""
    return Resource.cli_evaluator("r", expr, wildcards=None, input=None, attempt=1, async_run=None)


@pytest.mark.parametrize("path", PROFILES, ids=lambda p: p.parent.name)
def test_profile_needs_no_editing(path, monkeypatch):
    text = path.read_text()
    assert "CHANGE_ME" not in text
    prof = yaml.safe_load(text)
    assert prof["executor"] == "slurm"
    assert prof["slurm-status-command"] == "squeue"   # sacct fails where the cluster keeps no accounting
    res = prof["default-resources"]
    assert res["runtime"] > 0 and res["mem_mb"] > 0   # in the list a user no longer needs to override
    for key, var in (("slurm_account", "SBATCH_ACCOUNT"), ("slurm_partition", "SBATCH_PARTITION")):
        monkeypatch.setenv(var, "proj-42")
        assert _evaluate(res[key]) == "proj-42"
        monkeypatch.delenv(var)
        assert _evaluate(res[key]) == ""     # the plugin then uses the default partition / no account


def test_small_profile_caps_threads_at_two():
    prof = yaml.safe_load(PROFILES[1].read_text())
    assert prof["max-threads"] == 2
    assert all(n <= 2 for n in prof.get("set-threads", {}).values())


DRY_RUN = """\
Building DAG of jobs...
Job stats:
job         count
--------  -------
[Sat Nov 28 07:05:49 2026]
rule calibrate:
    input: r/data/static_check.nc
    output: r/calibration/default_calibration.nc
    jobid: 1
    threads: 8
    resources: tmpdir=/tmp, disk_mb=<TBD>, mem_mb=8000, mem=8 GB, slurm_account=, slurm_partition=long, runtime=240
Shell command: None

[Sat Nov 28 07:05:49 2026]
localrule sweeps:
    jobid: 3
    threads: 4
    resources: tmpdir=/tmp, mem_mb=1000

[Sat Nov 28 07:05:49 2026]
rule diagnose:
    output: r/diagnosis/report.json
    jobid: 2
    resources: tmpdir=/tmp, mem_mb=2000, mem=2 GB, slurm_account=acc, slurm_partition=, runtime=30

[Sat Nov 28 07:05:49 2026]
rule all:
    jobid: 0
    resources: tmpdir=/tmp
This was a dry-run (flag -n). The order of jobs does not reflect the order of execution.
"""


def test_planned_jobs_are_the_submitted_rules_with_their_size():
    jobs = slurm_run.planned_jobs(DRY_RUN)
    assert [j["rule"] for j in jobs] == ["calibrate", "diagnose"]   # local rules and `all` are not submitted
    assert jobs[0]["threads"] == 8 and jobs[1]["threads"] == 1      # snakemake prints threads only when not 1
    assert slurm_run.test_only_args(jobs[0]) == ["--ntasks=1", "--cpus-per-task=8", "--mem=8000", "--time=240",
                                                 "--partition=long"]
    assert slurm_run.test_only_args(jobs[1]) == ["--ntasks=1", "--cpus-per-task=1", "--mem=2000", "--time=30",
                                                 "--account=acc"]


def _fake_sbatch(bindir: Path) -> None:
    """``sbatch --test-only`` of a cluster whose one node has 2 CPUs and 24105 MB, as SLURM 22.05 words it."""
    bindir.mkdir()
    script = bindir / "sbatch"
    script.write_text(
        "#!/usr/bin/env python3\n"
        "import sys\n"
        "a = dict(x.lstrip('-').split('=', 1) for x in sys.argv[1:] if x.startswith('--') and '=' in x)\n"
        "assert '--test-only' in sys.argv, sys.argv\n"
        "if int(a.get('cpus-per-task', 1)) > 2 or int(a.get('mem', 0)) > 24105:\n"
        "    sys.exit('allocation failure: Requested node configuration is not available')\n"
        "print('sbatch: Job 1 to start at 2026-11-28T07:04:46 using 2 processors on nodes vm in partition debug',"
        " file=sys.stderr)\n")
    script.chmod(0o755)


def _check(profile: str, tmp_path: Path):
    env = {**os.environ, "PATH": f"{tmp_path / 'bin'}{os.pathsep}{os.environ['PATH']}"}
    env.pop("SNAKEMAKE_PROFILE", None)
    return subprocess.run([sys.executable, str(ROOT / "tools" / "slurm_run.py"), "--check", "--profile",
                           f"workflow/profiles/{profile}", "--configfile", ".test/config.yaml", "--config",
                           f"results={tmp_path / 'results'}"], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=300)


@NEEDS_PLUGIN
def test_preflight_refuses_jobs_no_node_can_run_and_passes_the_small_profile(tmp_path):
    _fake_sbatch(tmp_path / "bin")
    big = _check("slurm", tmp_path)
    assert big.returncode == 2, big.stdout + big.stderr
    assert "SLURM can never start these jobs" in big.stderr
    assert "calibrate: --ntasks=1 --cpus-per-task=8" in big.stderr       # set-threads 8 on a 2-CPU node
    assert "Requested node configuration is not available" in big.stderr
    assert "workflow/profiles/slurm-small" in big.stderr                 # the fix
    small = _check("slurm-small", tmp_path)
    assert small.returncode == 0, small.stdout + small.stderr
    assert "each one SLURM could start" in small.stdout
    assert not (tmp_path / "results").exists()                          # a check, not a run
