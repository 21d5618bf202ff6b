"""The drift stage's noise-seed study is planned as blocks of seeds, one job of one thread each, gathered by one job
(rule drift_noise_seeds_block, rule drift_noise_seeds in workflow/rules/drift.smk): the blocks hold every seed of
the configuration once, in order, at most 15 a block and at least two blocks, so that no single job carries the
whole study. Checked on the plan (``snakemake --dry-run``) of the default and the .test configuration in the
`unit` scatter mode (a cluster's; the jobs of the other modes: tests/workflow/test_scatter_jobs.py)."""
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
JOB_HEAD = re.compile(r"^(?:local)?rule (\S+):\s*$")
FIELD = re.compile(r"^\s+(input|output|wildcards|threads): (.*)$")


def _plan(tmp_path, config: Path) -> list[dict]:
    """The jobs of a dry run of the noise-seed products for ``config`` (results under tmp_path)."""
    cfg = yaml.safe_load(config.read_text())
    results = tmp_path / "results"
    cfg["results"] = str(results)
    cfg["sweeps"] = [str(ROOT / s) for s in cfg.get("sweeps", [])]   # named from the repository's root
    cfgfile = tmp_path / "config.yaml"
    cfgfile.write_text(yaml.safe_dump(cfg))
    (tmp_path / "work").mkdir()
    env = {k: v for k, v in os.environ.items() if k != "SNAKEMAKE_PROFILE"}
    r = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(ROOT / "Snakefile"),
                        str(results / "drift" / "noise_seeds.csv"), "--dry-run", "--forceall", "--cores", "2",
                        "--directory", str(tmp_path / "work"), "--configfile", str(cfgfile), "--config", "scatter=unit"],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    jobs, cur = [], None
    for line in r.stdout.splitlines():
        m = JOB_HEAD.match(line)
        if m:
            cur = {"rule": m.group(1), "threads": "1"}
            jobs.append(cur)
        elif cur is not None and (f := FIELD.match(line)):
            cur[f.group(1)] = f.group(2).strip()
    return jobs, int(cfg["drift"]["noise_seeds"])


@pytest.mark.parametrize("config", [ROOT / "config" / "config.yaml", ROOT / ".test" / "config.yaml"],
                         ids=["default", "test"])
def test_noise_seeds_are_planned_as_blocks_of_one_thread(tmp_path, config):
    jobs, n_seeds = _plan(tmp_path, config)
    blocks = [j for j in jobs if j["rule"] == "drift_noise_seeds_block"]
    gather = [j for j in jobs if j["rule"] == "drift_noise_seeds"]
    assert len(gather) == 1
    spans = sorted(tuple(int(v.split("=")[1]) for v in j["wildcards"].split(", ")) for j in blocks)
    assert spans[0][0] == 0 and spans[-1][1] == n_seeds
    assert all(a[1] == b[0] for a, b in zip(spans, spans[1:]))          # every seed once, in order
    assert all(0 < stop - first <= 15 for first, stop in spans)
    assert len(spans) >= 2
    assert all(j["threads"] == "1" for j in blocks)
    parts = {j["output"] for j in blocks}
    assert set(gather[0]["input"].split(", ")) == parts                  # the gathering job reads every block
