#!/usr/bin/env python3
"""Hash every product of a workflow run, to prove a change of code left the results unchanged.

    python3 tools/hash_products.py .test/results > hashes.tsv
    python3 tools/hash_products.py --compare before.tsv after.tsv [--rename old=new ...]

One line per product (netCDF, CSV, JSON, PNG, SVG, PDF, Markdown, text tables): path relative to the results
folder, then the SHA-256 of its content. netCDF files are hashed by content (every variable's name, dims, dtype,
attributes and values; the global attributes), leaving out the attributes that name the code's commit
(``git_commit``), because a move of code changes the commit by definition; JSON files likewise leave out
``git_commit``, wall times (keys ending in ``_time_s`` or ``_s_wall``, ``wall_s``, ``timings``) and paths of
temporary files. Logs, ``timings.*`` files, benchmark timings, the MLflow store and its artefacts are not
products and are skipped.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

SKIP_DIRS = {"logs", "benchmarks", "mlartifacts", "mlruns", ".snakemake"}
SUFFIXES = {".nc", ".csv", ".json", ".png", ".svg", ".pdf", ".md", ".txt", ".tsv", ".yaml"}
VOLATILE = {"git_commit"}
TEMP_DIRS = ("/tmp/", "/var/tmp/")


def _volatile_key(k: str) -> bool:
    return (k in VOLATILE or k in {"wall_s", "timings", "wall_time_s", "elapsed_s"} or k.endswith("_s_wall")
            or k.endswith("_time_s"))


def _scrub(obj):
    if isinstance(obj, dict):
        return {k: _scrub(v) for k, v in obj.items() if not _volatile_key(k)}
    if isinstance(obj, list):
        return [_scrub(v) for v in obj]
    if isinstance(obj, str) and obj.startswith(tuple(TEMP_DIRS)):
        return "<temporary file>"
    return obj


def hash_netcdf(path: Path) -> str:
    import netCDF4
    import numpy as np

    h = hashlib.sha256()

    def group(g):
        for k in sorted(g.ncattrs()):
            if k in VOLATILE:
                continue
            h.update(f"attr {k}={g.getncattr(k)!r}\n".encode())
        for name in sorted(g.variables):
            v = g.variables[name]
            v.set_auto_maskandscale(False)
            h.update(f"var {name} {v.dimensions} {v.dtype}\n".encode())
            for k in sorted(v.ncattrs()):
                h.update(f"  {k}={v.getncattr(k)!r}\n".encode())
            data = v[...]
            h.update(np.ascontiguousarray(np.asarray(data)).tobytes() if v.dtype != str
                     else repr(list(np.asarray(data).ravel())).encode())
        for name in sorted(g.groups):
            h.update(f"group {name}\n".encode())
            group(g.groups[name])

    with netCDF4.Dataset(path) as nc:
        group(nc)
    return h.hexdigest()


def hash_file(path: Path) -> str:
    if path.suffix == ".nc":
        return hash_netcdf(path)
    if path.suffix == ".json":
        try:
            obj = json.loads(path.read_text())
        except ValueError:
            return hashlib.sha256(path.read_bytes()).hexdigest()
        return hashlib.sha256(json.dumps(_scrub(obj), sort_keys=True).encode()).hexdigest()
    return hashlib.sha256(path.read_bytes()).hexdigest()


def products(root: Path):
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if not p.is_file() or p.suffix not in SUFFIXES or set(rel.parts[:-1]) & SKIP_DIRS:
            continue
        if p.name.startswith(".") or p.stem == "timings":
            continue
        yield rel, p


def compare(a: Path, b: Path, renames: list[str]) -> int:
    def load(p):
        return dict(line.rstrip("\n").split("\t") for line in p.read_text().splitlines() if line)

    before, after = load(a), load(b)
    for r in renames:
        old, new = r.split("=", 1)
        before = {k.replace(old, new): v for k, v in before.items()}
    same = diff = 0
    print("product\tbefore\tafter\tverdict")
    for k in sorted(set(before) | set(after)):
        x, y = before.get(k, "-"), after.get(k, "-")
        verdict = "identical" if x == y else ("missing after" if y == "-" else "new" if x == "-" else "DIFFERS")
        same += verdict == "identical"
        diff += verdict != "identical"
        print(f"{k}\t{x[:12]}\t{y[:12]}\t{verdict}")
    print(f"# {same} identical, {diff} not", file=sys.stderr)
    return 0 if diff == 0 else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="+")
    ap.add_argument("--compare", action="store_true", help="compare two hash tables")
    ap.add_argument("--rename", action="append", default=[], help="OLD=NEW path fragment renamed on purpose")
    args = ap.parse_args(argv)
    if args.compare:
        return compare(Path(args.paths[0]), Path(args.paths[1]), args.rename)
    root = Path(args.paths[0])
    for rel, p in products(root):
        print(f"{rel}\t{hash_file(p)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
