#!/usr/bin/env python3
"""A ``calib`` command timed on two revisions of this repository, run for run in turn (A B, B A, A B, ...), so a
change of the machine's speed falls on both alike; prints each side's median wall and CPU time and the paired
differences.

    .venv/bin/python benchmarks/compare_revisions.py bacde97 HEAD --pairs 8 -- \\
        diagnose template.nc --out /tmp/d --force --noise-record static_2h.nc
    .venv/bin/python benchmarks/compare_revisions.py bacde97 HEAD --pairs 6 --cwd /path/to/study -- \\
        navigate results/data/navigation_session.nc --out /tmp/nav.nc

Each revision is checked out once into a temporary ``git worktree`` (removed at the end) and run with this
environment's interpreter and packages, its own ``src`` first on ``PYTHONPATH`` (``python -m calib.cli ARGS``), its
byte code compiled first and one run of each not counted (so neither side pays for compiling calib's modules or
numba's kernels, cached per worktree). Every run is a new process (with ``CALIB_SERVER=off`` for a revision whose
``calib diagnose`` would start a background server), and gets its own output folder or file when ``{rev}`` appears in
an argument (``--out /tmp/d_{rev}``). Wall time from start to reaping, CPU time the user + system time of the command
and of any child process it waited for. A run that exits with a code outside 0, 1 and 3 stops the
comparison (its error is printed).
"""
from __future__ import annotations

import argparse
import os
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def worktree(rev: str, where: Path) -> Path:
    path = where / rev.replace("/", "_")
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-f", str(path), rev], check=True,
                   capture_output=True)
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(path / "src")], check=True, capture_output=True)
    return path


def one_run(tree: Path, rev: str, args: list, cwd: Path) -> tuple[float, float]:
    env = {**os.environ, "CALIB_SERVER": "off", "PYTHONPATH": str(tree / "src")}
    argv = [a.replace("{rev}", rev) for a in args]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "calib.cli", *argv], cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode not in (0, 1, 3):
        raise SystemExit(f"{rev}: calib {shlex.join(argv)} exited {r.returncode}:\n{r.stderr[-2000:]}")
    return wall, (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("rev_a", help="the revision before (e.g. the first commit of a change)")
    ap.add_argument("rev_b", help="the revision after (e.g. HEAD)")
    ap.add_argument("--pairs", type=int, default=6, help="runs of each revision, in turn (default 6)")
    ap.add_argument("--cwd", default=".", help="the folder the command runs in (default: the current one)")
    ap.epilog = "after the options: -- then the calib sub-command and its arguments"
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" not in argv:
        ap.error("give, after --, a calib sub-command")
    cut = argv.index("--")
    a = ap.parse_args(argv[:cut])
    args = argv[cut + 1:]
    if not args or a.pairs < 1:
        ap.error("give --pairs >= 1 and, after --, a calib sub-command")
    revs = {}
    for r in (a.rev_a, a.rev_b):
        revs[r] = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", r], check=True, capture_output=True,
                                 text=True).stdout.strip()
    with tempfile.TemporaryDirectory(prefix="calib-revs-") as tmp:
        trees = {}
        try:
            for r in revs:
                trees[r] = worktree(revs[r], Path(tmp))
            cwd = Path(a.cwd).resolve()
            res = {r: [] for r in revs}
            order = [a.rev_a, a.rev_b]
            print(f"$ python benchmarks/{Path(__file__).name} {shlex.join(argv)}", flush=True)
            for r in order:   # not counted: numba compiles each worktree's kernels into its own cache on first use
                one_run(trees[r], revs[r], args, cwd)
            for i in range(a.pairs):
                for r in (order if i % 2 == 0 else order[::-1]):
                    res[r].append(one_run(trees[r], revs[r], args, cwd))
                print(f"pair {i + 1}/{a.pairs}: " + ", ".join(f"{revs[r]} {res[r][-1][0]:.2f} s" for r in order),
                      file=sys.stderr, flush=True)
        finally:
            for path in trees.values():
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(path)],
                               capture_output=True)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\n| revision | wall median [s] | wall min-max [s] | CPU median [s] |   (load average {load:.2f} at the end)")
    print("|---|---|---|---|")
    for r in order:
        w = [x[0] for x in res[r]]
        c = [x[1] for x in res[r]]
        print(f"| {r} ({revs[r]}) | {statistics.median(w):.2f} | {min(w):.2f}-{max(w):.2f} | {statistics.median(c):.2f} |")
    dw = [x[0] - y[0] for x, y in zip(res[a.rev_a], res[a.rev_b])]
    dc = [x[1] - y[1] for x, y in zip(res[a.rev_a], res[a.rev_b])]
    print(f"\npaired median ({a.rev_a} - {a.rev_b}): wall {statistics.median(dw):+.2f} s, CPU {statistics.median(dc):+.2f} s "
          f"over {a.pairs} pairs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
