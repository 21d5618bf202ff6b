#!/usr/bin/env python3
"""Where the study's time goes: one row per workflow rule from Snakemake's ``benchmark:`` files.

    python3 benchmarks/study_times.py results            # after `python3 run.py study`
    python3 benchmarks/study_times.py .test/results      # after the CI chain

Each rule with a ``benchmark:`` directive writes ``<results>/benchmarks/<rule>.tsv`` (wall seconds ``s``, CPU
seconds ``cpu_time``, peak resident memory ``max_rss`` in MB). The table lists them slowest first with their share
of the summed wall time; rules run two at a time on two cores, so the sum exceeds the study's wall time, which
Snakemake's log states (``Elapsed time`` is not written there: time the whole command, e.g. ``/usr/bin/time -v``).
If ``<results>/benchmarks/_study_wall.txt`` holds that wall time (one number, seconds), it is printed below the
table as the total wall of the study. The command that printed the table is printed above it.
"""
from __future__ import annotations

import csv
import shlex
import sys
from pathlib import Path

#: the study's whole wall time in seconds, one number (written by whoever timed the study)
STUDY_WALL = "_study_wall.txt"


def read(root: Path) -> list[dict]:
    rows = []
    for tsv in sorted((root / "benchmarks").glob("*.tsv")):
        with tsv.open() as fh:
            recs = list(csv.DictReader(fh, delimiter="\t"))
        if not recs:
            continue

        def num(key):
            try:
                return float(recs[-1].get(key) or "nan")
            except ValueError:
                return float("nan")

        rows.append({"rule": tsv.stem, "wall_s": num("s"), "cpu_s": num("cpu_time"), "max_rss_mb": num("max_rss")})
    return sorted(rows, key=lambda r: -r["wall_s"])


def study_wall(root: Path) -> float | None:
    """The study's total wall time [s] from ``<root>/benchmarks/_study_wall.txt``, or None (absent/unreadable)."""
    try:
        return float((root / "benchmarks" / STUDY_WALL).read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    root = Path(argv[0] if argv else "results")
    rows = read(root)
    if not rows:
        print(f"{root}/benchmarks/ holds no *.tsv: run the study first (python3 run.py study)", file=sys.stderr)
        return 2
    total = sum(r["wall_s"] for r in rows)
    print(f"$ python3 benchmarks/study_times.py {shlex.join(argv)}".rstrip())
    print(f"| rule | wall s | CPU s | share of summed wall | peak RSS MB |   ({root}/benchmarks/*.tsv)")
    print("|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['rule']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {100 * r['wall_s'] / total:.1f} % "
              f"| {r['max_rss_mb']:.0f} |")
    print(f"| **sum** | {total:.1f} | {sum(r['cpu_s'] for r in rows):.1f} | 100 % | |")
    wall = study_wall(root)
    if wall is not None:
        ratio = f"; summed rule wall / study wall = {total / wall:.2f}" if wall > 0 else ""
        print(f"total wall of the study: {wall:.1f} s ({root}/benchmarks/{STUDY_WALL}){ratio}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
