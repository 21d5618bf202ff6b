#!/usr/bin/env python3
"""The critical path of a workflow run: the longest chain of dependent jobs, by the job times of their benchmark files.

    python3 benchmarks/critical_path.py --profile workflow/profiles/default      # after `python3 run.py study`
    python3 benchmarks/critical_path.py --profile workflow/profiles/test         # after the .test chain

The arguments are passed to ``snakemake --dry-run --forceall`` (the same profile, config and ``--directory`` as
the run), which lists every job of the study with its input, output and ``benchmark:`` file. A job depends on the
jobs that write one of its inputs; its time is the wall time ``s`` of its benchmark file (the last row; written by
the run). The critical path is the chain whose times add up to the most: however many cores or cluster nodes run
the study, it cannot finish in less (plus the scheduler's own time between jobs). A job without a benchmark file
counts 0 s and is listed below the path, so that a gap is visible. ``--dry-run-output FILE`` reads a saved dry-run
instead of running Snakemake.
"""
from __future__ import annotations

import argparse
import csv
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

JOB_HEAD = re.compile(r"^(?:local)?(?:checkpoint|rule) (\S+):\s*$")
JOB_FIELD = re.compile(r"^\s+(input|output|benchmark|jobid|wildcards): (.*)$")


@dataclass
class Job:
    rule: str
    jobid: str = ""
    wildcards: str = ""
    inputs: list[str] = field(default_factory=list)
    outputs: list[str] = field(default_factory=list)
    benchmark: str = ""
    seconds: float | None = None

    @property
    def label(self) -> str:
        return f"{self.rule}[{self.wildcards}]" if self.wildcards else self.rule


def parse_dry_run(text: str) -> list[Job]:
    """The jobs of a ``snakemake --dry-run`` listing (one block per job: ``rule NAME:`` then indented fields)."""
    jobs, cur = [], None
    for line in text.splitlines():
        m = JOB_HEAD.match(line)
        if m:
            cur = Job(m.group(1))
            jobs.append(cur)
            continue
        if cur is None:
            continue
        f = JOB_FIELD.match(line)
        if f:
            key, val = f.groups()
            if key in ("input", "output"):
                setattr(cur, key + "s", [v.strip() for v in val.split(", ") if v.strip()])
            else:
                setattr(cur, key, val.strip())
        elif not line.startswith((" ", "\t")):
            cur = None
    return jobs


def job_seconds(path: Path) -> float | None:
    """Wall seconds of the last row of a Snakemake benchmark file, or None (missing or unreadable)."""
    try:
        with path.open() as fh:
            rows = list(csv.DictReader(fh, delimiter="\t"))
        return float(rows[-1]["s"])
    except (OSError, KeyError, IndexError, ValueError):
        return None


def critical_path(jobs: list[Job]) -> tuple[float, list[Job]]:
    """The longest chain of dependent jobs by their seconds (None counts 0): its total and its jobs, first first."""
    writer = {o: j for j in jobs for o in j.outputs}
    deps = {id(j): [writer[i] for i in j.inputs if i in writer and writer[i] is not j] for j in jobs}
    best: dict[int, tuple[float, list[Job]]] = {}

    def longest(j: Job, stack=()) -> tuple[float, list[Job]]:
        if id(j) in best:
            return best[id(j)]
        if id(j) in stack:
            raise ValueError(f"dependency cycle at {j.label}")
        t0, chain0 = 0.0, []
        for d in deps[id(j)]:
            t, chain = longest(d, stack + (id(j),))
            if t > t0 or not chain0:
                t0, chain0 = t, chain
        best[id(j)] = (t0 + (j.seconds or 0.0), chain0 + [j])
        return best[id(j)]

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(jobs) + 100))
    # ties: the longer chain (down to the final target, whose own time is 0)
    return max((longest(j) for j in jobs), key=lambda tc: (tc[0], len(tc[1])), default=(0.0, []))


def _workdir(args: list[str]) -> Path:
    for i, a in enumerate(args):
        if a in ("--directory", "-d") and i + 1 < len(args):
            return Path(args[i + 1])
        if a.startswith("--directory="):
            return Path(a.split("=", 1)[1])
    return Path(".")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    ap.add_argument("--dry-run-output", type=Path, help="a saved `snakemake --dry-run --forceall` listing")
    ap.add_argument("--workdir", type=Path, help="where the benchmark paths are relative to (default: --directory "
                                                 "of the Snakemake arguments, else here)")
    opts, smk = ap.parse_known_args(sys.argv[1:] if argv is None else argv)
    if opts.dry_run_output:
        try:
            text = opts.dry_run_output.read_text()
        except OSError as exc:
            print(f"{opts.dry_run_output}: cannot be read ({exc.strerror}); save one with `snakemake --dry-run "
                  "--forceall ... > FILE`", file=sys.stderr)
            return 2
    else:
        cmd = [sys.executable, "-m", "snakemake", "--dry-run", "--forceall", *smk]
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            print(f"`{shlex.join(cmd)}` failed (exit {res.returncode}):\n{res.stderr[-2000:]}", file=sys.stderr)
            return 2
        text = res.stdout + "\n" + res.stderr
    workdir = opts.workdir or _workdir(smk)
    jobs = parse_dry_run(text)
    if not jobs:
        print("the dry-run lists no job: check the Snakemake arguments (profile, --configfile)", file=sys.stderr)
        return 2
    for j in jobs:
        j.seconds = job_seconds(workdir / j.benchmark) if j.benchmark else None
    total, chain = critical_path(jobs)
    timed = [j for j in jobs if j.seconds is not None]
    if not timed:
        print(f"no benchmark file of this study's jobs under {workdir.resolve()}: run the study first",
              file=sys.stderr)
        return 2
    print(f"$ python3 benchmarks/critical_path.py {shlex.join(sys.argv[1:] if argv is None else argv)}".rstrip())
    print(f"critical path: {total:.1f} s of job time over {len(chain)} jobs "
          f"({len(jobs)} jobs in the study, {sum(j.seconds for j in timed):.1f} s of job time in all)")
    print("| # | job | job s | path s | benchmark |")
    print("|---|---|---|---|---|")
    acc = 0.0
    for i, j in enumerate(chain, 1):
        acc += j.seconds or 0.0
        s = "--" if j.seconds is None else f"{j.seconds:.1f}"
        print(f"| {i} | {j.label} | {s} | {acc:.1f} | {j.benchmark or '(none)'} |")
    missing = sorted({j.rule for j in jobs if j.seconds is None and j.rule != "all"})
    if missing:
        print(f"jobs without a benchmark file (counted 0 s): rules {', '.join(missing)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
