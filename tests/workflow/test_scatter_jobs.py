"""The long studies' jobs under each `scatter` mode (workflow/rules/common.smk), on the plan of the default and
the .test configuration (``snakemake --dry-run``): `unit` gives a job per proof session, per real recording and per seed
block; an integer n, or `auto` on one machine (twice its cores), at most n jobs a study. In every mode each session,
recording and seed is run by exactly one job, and the gathering job reads every job's part. That the products do
not depend on the mode is shown where both run: CI's SLURM run (`unit`) against its local one (`auto`, 4 jobs a
study), every product compared (tools/slurm_cluster.sh, tools/hash_products.py)."""
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from calib.studies import proof_sessions

ROOT = Path(__file__).resolve().parents[2]
JOB_HEAD = re.compile(r"^(?:local)?rule (\S+):\s*$")
FIELD = re.compile(r"^\s+(input|output|wildcards|threads): (.*)$")
CONFIGS = {"default": ROOT / "config" / "config.yaml", "test": ROOT / ".test" / "config.yaml"}
#: the studies' job rules, the gathering rules and the wildcard naming a job
STUDIES = {"proof": ("diagnosis_proof_session", "diagnosis_proof", "proof_job"),
           "real": ("diagnosis_real_proof_recording", "diagnosis_real_proof", "real_proof_job"),
           "noise": ("drift_noise_seeds_block", "drift_noise_seeds", None),
           "z": ("calibration_z_seeds", "calibration_z", None)}
RECORDINGS = sorted(p.stem for p in (ROOT / "config" / "import").glob("*.yaml"))


def _plan(tmp_path, *args, config="default") -> tuple[list[dict], dict]:
    """The jobs of a dry run of the whole study of ``config`` (results under tmp_path) with ``args``."""
    cfg = yaml.safe_load(CONFIGS[config].read_text())
    cfg["results"] = str(tmp_path / "results")
    cfg["sweeps"] = [str(ROOT / s) for s in cfg.get("sweeps", [])]
    cfgfile = tmp_path / "config.yaml"
    cfgfile.write_text(yaml.safe_dump(cfg))
    env = {k: v for k, v in os.environ.items() if k != "SNAKEMAKE_PROFILE"}
    r = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(ROOT / "Snakefile"), "--dry-run", "--forceall",
                        "--directory", str(ROOT), "--configfile", str(cfgfile), *args],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    jobs, cur = [], None
    for line in r.stdout.splitlines():
        m = JOB_HEAD.match(line)
        if m:
            cur = {"rule": m.group(1), "threads": "1"}
            jobs.append(cur)
        elif cur is not None and (f := FIELD.match(line)):
            cur[f.group(1)] = f.group(2).strip()
    return jobs, cfg


def _study(jobs, key):
    rule, gather, _ = STUDIES[key]
    parts = [j for j in jobs if j["rule"] == rule]
    g = [j for j in jobs if j["rule"] == gather]
    assert len(g) == 1 and set(g[0]["input"].split(", ")) >= {j["output"] for j in parts}   # every part gathered
    return parts


def _spans(parts):
    return sorted(tuple(int(v.split("=")[1]) for v in j["wildcards"].split(", ")) for j in parts)


def _units_once(jobs, cfg):
    """Every proof session, real recording and seed in exactly one job."""
    for key, n in (("noise", cfg["drift"]["noise_seeds"]), ("z", cfg["calibration"]["z_seeds"])):
        spans = _spans(_study(jobs, key))
        assert spans[0][0] == 0 and spans[-1][1] == n and all(a[1] == b[0] for a, b in zip(spans, spans[1:]))


@pytest.mark.parametrize("config", list(CONFIGS))
def test_unit_mode_runs_a_job_per_session_recording_and_seed_block(tmp_path, config):
    jobs, cfg = _plan(tmp_path, "--cores", "2", "--config", "scatter=unit", config=config)
    _units_once(jobs, cfg)
    proof = _study(jobs, "proof")
    assert sorted(j["wildcards"] for j in proof) == sorted(f"proof_job={s}" for s in proof_sessions.session_names(
        cfg["diagnosis"]["proof"].get("sessions")))
    chosen = cfg["diagnosis"].get("real_proof", {}).get("recordings") or RECORDINGS
    assert sorted(j["wildcards"] for j in _study(jobs, "real")) == [f"real_proof_job={r}" for r in sorted(chosen)]
    noise = _study(jobs, "noise")
    assert all(b - a <= 15 for a, b in _spans(noise)) and len(noise) >= 2   # no job carries the whole study
    assert all(j["threads"] == "1" for j in noise)
    assert all(b - a <= 100 for a, b in _spans(_study(jobs, "z")))


@pytest.mark.parametrize("args, n", [(("--cores", "2"), 4), (("--cores", "1"), 2), (("--cores", "2", "--config",
                                                                                       "scatter=3"), 3)],
                         ids=["auto-2-cores", "auto-1-core", "three"])
def test_local_modes_run_at_most_n_jobs_a_study(tmp_path, args, n):
    jobs, cfg = _plan(tmp_path, *args)
    _units_once(jobs, cfg)
    for key in STUDIES:
        parts = _study(jobs, key)
        assert 2 <= len(parts) <= n, (key, len(parts))
    # the sessions and recordings dealt over the jobs: each once (the job names them in its log; its inputs list
    # the recordings' settings)
    real = _study(jobs, "real")
    got = sorted(Path(p).stem for j in real for p in j["input"].split(", "))
    assert got == RECORDINGS
    assert len(_study(jobs, "proof")) == n   # 23 sessions: n jobs
