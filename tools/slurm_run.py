#!/usr/bin/env python3
"""Run the workflow on SLURM after checking that the cluster can ever run every job it would submit.

    python3 tools/slurm_run.py --profile workflow/profiles/slurm [snakemake arguments ...]
    python3 tools/slurm_run.py --check --profile workflow/profiles/slurm-small --configfile .test/config.yaml

SLURM accepts a job that asks for more CPUs, memory or time than any node of its partition offers and leaves it
PENDING for ever (``Reason=PartitionConfig``); snakemake-executor-plugin-slurm then waits on it without end. So
this tool first asks snakemake for the jobs of the run (a dry run with the same arguments), then asks SLURM itself
(``sbatch --test-only``, which submits nothing) whether a job of each distinct size -- CPUs (the job's threads),
memory (mem_mb), time limit (runtime) in the partition and account the profile gives it -- could ever start. Only
when every size can does it run snakemake with the given arguments (without ``--check``).

Exit status: 0 (every job fits; without ``--check``: snakemake's own status), 2 (a job can never run, or SLURM
or snakemake is not reachable; the message names the rule, its size, SLURM's answer and a fix), or snakemake's
status when the dry run fails.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXIT_INPUT = 2          # calib.core.errors.EXIT_INPUT: bad configuration or environment
UNCAPPED = "100000"     # --cores of the dry run: a remote job's threads are capped by max-threads only, not by cores


def snakemake_cmd() -> list[str]:
    """snakemake of the Python running this tool (the project's venv), else the one on PATH."""
    here = Path(sys.executable).parent / "snakemake"
    return [str(here)] if here.exists() else ["snakemake"]


def planned_jobs(dry_run_output: str) -> list[dict]:
    """Jobs of a snakemake dry run, each ``{"rule", "threads", "resources"}``; local rules (run on the submitting
    host) are left out. Threads are printed only when they are not 1."""
    jobs, job = [], None
    for line in dry_run_output.splitlines():
        m = re.match(r"^(local)?rule (\w+):$", line)
        if m:
            job = None if m.group(1) else {"rule": m.group(2), "threads": 1, "resources": {}}
            if job:
                jobs.append(job)
            continue
        if job is None:
            continue
        m = re.match(r"^\s+threads: (\d+)$", line)
        if m:
            job["threads"] = int(m.group(1))
        m = re.match(r"^\s+resources: (.*)$", line)
        if m:
            for item in m.group(1).split(", "):
                k, _, v = item.partition("=")
                job["resources"][k.strip()] = v.strip()
    return [j for j in jobs if j["rule"] != "all"]


def test_only_args(job: dict) -> list[str]:
    """The size of ``job`` as the plugin gives it to sbatch: one task of ``threads`` CPUs, ``--mem``, ``-t``,
    ``-p`` and ``-A`` when set (unset, sbatch reads SBATCH_PARTITION / SBATCH_ACCOUNT itself)."""
    r = job["resources"]
    args = ["--ntasks=1", f"--cpus-per-task={job['threads']}"]
    if r.get("mem_mb", "").isdigit():
        args.append(f"--mem={r['mem_mb']}")
    if r.get("runtime", "").isdigit():
        args.append(f"--time={r['runtime']}")
    if r.get("slurm_partition"):
        args.append(f"--partition={r['slurm_partition']}")
    if r.get("slurm_account"):
        args.append(f"--account={r['slurm_account']}")
    return args


def main(argv: list[str]) -> int:
    check_only = "--check" in argv
    args = [a for a in argv if a != "--check"]
    if not any(a == "--profile" or a.startswith("--profile=") for a in args):
        args = ["--profile", "workflow/profiles/slurm", *args]
    if shutil.which("sbatch") is None:
        print("slurm_run: sbatch is not on PATH: run this on a host that submits SLURM jobs (the login node)",
              file=sys.stderr)
        return EXIT_INPUT
    dry = subprocess.run([*snakemake_cmd(), *args, "--dry-run", "--cores", UNCAPPED], cwd=Path.cwd(),
                         capture_output=True, text=True, env={**os.environ, "CALIB_TRACKING": "0"})
    if dry.returncode != 0:
        print(dry.stdout[-3000:] + dry.stderr[-3000:], file=sys.stderr)
        print(f"slurm_run: the dry run of snakemake {' '.join(args)} failed (exit {dry.returncode})", file=sys.stderr)
        return dry.returncode
    jobs = planned_jobs(dry.stdout + dry.stderr)
    sizes: dict[tuple, list[str]] = {}
    for job in jobs:
        sizes.setdefault(tuple(test_only_args(job)), []).append(job["rule"])
    refused = []
    for size, rules in sizes.items():
        r = subprocess.run(["sbatch", "--test-only", *size, "--wrap", "true"], capture_output=True, text=True)
        if r.returncode != 0:
            answer = " ".join((r.stderr or r.stdout).split()) or f"exit {r.returncode}"
            refused.append(f"  {', '.join(sorted(set(rules)))}: {' '.join(size)}\n    SLURM: {answer}")
    if refused:
        print("slurm_run: SLURM can never start these jobs (no node of the partition has what they ask for):\n"
              + "\n".join(refused) + "\n"
              "Fix: on nodes of fewer than 8 CPUs use --profile workflow/profiles/slurm-small, or cap the threads "
              "with --max-threads N (N = the CPUs of one node; `sinfo -o '%P %c %m %l'` lists them); lower a rule's "
              "mem_mb or runtime in the profile's set-resources; or choose a partition with SBATCH_PARTITION.",
              file=sys.stderr)
        return EXIT_INPUT
    print(f"slurm_run: {len(jobs)} planned jobs in {len(sizes)} sizes, each one SLURM could start "
          f"(sbatch --test-only; a dry run also lists the local rules)", flush=True)
    if check_only:
        return 0
    sys.stdout.flush()
    cmd = [*snakemake_cmd(), *args]
    os.execvp(cmd[0], cmd)   # snakemake in this process: Ctrl-C reaches it alone, and it cancels its SLURM jobs


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
