#!/usr/bin/env python3
"""Hash every product of a workflow run, to prove a change of code left the results unchanged.

    python3 tools/hash_products.py .test/results > hashes.tsv
    python3 tools/hash_products.py --compare before.tsv after.tsv [--rename old=new ...]
    python3 tools/hash_products.py --numeric BEFORE_RESULTS AFTER_RESULTS [--rtol 1e-9]

One line per product (netCDF, CSV, JSON, PNG, SVG, PDF, Markdown, text tables): path relative to the results
folder, then the SHA-256 of its content. netCDF files are hashed by content (every variable's name, dims, dtype,
attributes and values; the global attributes), leaving out the attributes that name the code's commit
(``git_commit``), because a move of code changes the commit by definition; JSON files likewise leave out
``git_commit``, wall times (keys ending in ``_time_s`` or ``_s_wall``, ``wall_s``, ``timings``) and paths of
temporary files. Logs, ``timings.*`` files, benchmark timings, the MLflow store and its artefacts are not
products and are skipped.

``--numeric`` compares two results folders product by product when a change of code moves numbers at the
rounding level (a sum taken in another order): where the hashes differ it says by how much. Stored values (netCDF
variables, JSON numbers) by their largest relative difference ``|a - b| / max |b|`` (per variable; NaN where NaN);
printed numbers (CSV, Markdown, text, YAML, SVG) by the largest difference in units of their last printed digit,
the text around them compared exactly; PNG images by their pixels. A product is *within* when its stored values
agree to ``--rtol``, its printed numbers to one unit of their last digit and its pixels exactly; exit status 0 when
every product is identical or within, 1 otherwise (the lines marked DIFFERS say where).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import re
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


def _netcdf_walk(g, pre=""):
    """The parts of netCDF group ``g`` in a fixed order, each ``(kind, prefix, name, value)``: its attributes but
    the volatile ones (``"attr"``, the value), its variables by name (``"var"``, the variable, unscaled and
    unmasked), then each subgroup (``"group"``, None) followed by its own parts (prefix ``pre + name + "/"``)."""
    for k in sorted(g.ncattrs()):
        if k not in VOLATILE:
            yield "attr", pre, k, g.getncattr(k)
    for name in sorted(g.variables):
        v = g.variables[name]
        v.set_auto_maskandscale(False)
        yield "var", pre, name, v
    for name in sorted(g.groups):
        yield "group", pre, name, None
        yield from _netcdf_walk(g.groups[name], f"{pre}{name}/")


def hash_netcdf(path: Path) -> str:
    import netCDF4
    import numpy as np

    h = hashlib.sha256()
    with netCDF4.Dataset(path) as nc:
        for kind, _, name, x in _netcdf_walk(nc):
            if kind == "attr":
                h.update(f"attr {name}={x!r}\n".encode())
            elif kind == "group":
                h.update(f"group {name}\n".encode())
            else:
                h.update(f"var {name} {x.dimensions} {x.dtype}\n".encode())
                for k in sorted(x.ncattrs()):
                    h.update(f"  {k}={x.getncattr(k)!r}\n".encode())
                data = x[...]
                h.update(np.ascontiguousarray(np.asarray(data)).tobytes() if x.dtype != str
                         else repr(list(np.asarray(data).ravel())).encode())
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


# ----------------------------------------------------------------------------------------------- --numeric
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
TEXT_SUFFIXES = {".csv", ".tsv", ".md", ".txt", ".yaml", ".svg"}


def _rel(a, b) -> float:
    """Largest |a - b| / max |b| of two float arrays (NaN positions must agree: else inf)."""
    import numpy as np

    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or not np.array_equal(np.isnan(a), np.isnan(b)):
        return math.inf
    ok = ~np.isnan(b)
    if not ok.any():
        return 0.0
    d = np.abs(a[ok] - b[ok])
    if np.any(np.isinf(a[ok]) | np.isinf(b[ok])):
        return 0.0 if np.array_equal(a[ok], b[ok]) else math.inf
    scale = float(np.max(np.abs(b[ok])))
    return float(np.max(d)) / scale if scale > 0 else (0.0 if float(np.max(d)) == 0.0 else math.inf)


def _netcdf_values(path: Path) -> dict:
    """The parts :func:`hash_netcdf` hashes, as values to compare: ``prefix@attr``, ``prefix+name#meta`` (dims,
    dtype, attributes) and ``prefix+name`` (the values)."""
    import netCDF4
    import numpy as np

    out = {}
    with netCDF4.Dataset(path) as nc:
        for kind, pre, name, x in _netcdf_walk(nc):
            if kind == "attr":
                out[f"{pre}@{name}"] = x
            elif kind == "var":
                out[f"{pre}{name}#meta"] = (x.dimensions, str(x.dtype), {k: repr(x.getncattr(k)) for k in x.ncattrs()})
                out[f"{pre}{name}"] = np.asarray(x[...])
    return out


def _leaves(obj, pre=""):
    if isinstance(obj, dict):
        for k in sorted(obj):
            yield from _leaves(obj[k], f"{pre}/{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _leaves(v, f"{pre}[{i}]")
    else:
        yield pre, obj


def _compare_values(va: dict, vb: dict) -> tuple[float, str]:
    """(largest relative difference of the numeric leaves, the first non-numeric difference or '')."""
    import numpy as np

    if set(va) != set(vb):
        return math.inf, f"different entries: {sorted(set(va) ^ set(vb))[:3]}"
    worst = 0.0
    for k in sorted(va):
        x, y = va[k], vb[k]
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            x, y = np.asarray(x), np.asarray(y)
            if x.dtype.kind == "f" and y.dtype.kind == "f":
                r = _rel(x, y)
                worst = max(worst, r)
                if math.isinf(r):
                    return r, f"{k}: shapes, NaN or inf positions differ, or zero against non-zero"
                continue
            same = x.shape == y.shape and (x.tolist() == y.tolist() if x.dtype.kind == "O" or y.dtype.kind == "O"
                                           else x.dtype == y.dtype and x.tobytes() == y.tobytes())
            if not same:
                return math.inf, f"{k}: non-float values differ"
            continue
        if isinstance(x, float) and isinstance(y, float):   # (NaN against NaN: _rel gives 0)
            r = _rel([x], [y])
            worst = max(worst, r)
            if math.isinf(r):
                return r, f"{k}: {x!r} vs {y!r}"
            continue
        if x != y:
            return math.inf, f"{k}: {str(x)[:60]!r} vs {str(y)[:60]!r}"
    return worst, ""


def _last_digit_units(x: str, y: str) -> float:
    """|x - y| in units of the last printed digit of the coarser of the two numbers."""
    def unit(s):
        mant = s.lstrip("+-").split("e")[0].split("E")[0]
        exp = int(re.split("[eE]", s)[1]) if re.search("[eE]", s) else 0
        dec = len(mant.split(".")[1]) if "." in mant else 0
        return 10.0 ** (exp - dec)
    return abs(float(x) - float(y)) / max(unit(x), unit(y))


def _compare_text(a: str, b: str) -> tuple[float, str]:
    """(largest difference of the printed numbers in last-digit units, the first difference of the rest or '')."""
    ta, tb = _NUMBER.split(a), _NUMBER.split(b)
    na, nb = _NUMBER.findall(a), _NUMBER.findall(b)
    if ta != tb or len(na) != len(nb):
        for x, y in zip(ta, tb):
            if x != y:
                return math.inf, f"text differs near {x[:40]!r} / {y[:40]!r}"
        return math.inf, "text differs (length)"
    worst = 0.0
    for x, y in zip(na, nb):
        if x != y:
            worst = max(worst, _last_digit_units(x, y))
    return worst, ""


def _same_pixels(a: Path, b: Path) -> bool:
    from PIL import Image

    with Image.open(a) as ia, Image.open(b) as ib:
        return ia.size == ib.size and ia.mode == ib.mode and ia.tobytes() == ib.tobytes()


def numeric(a: Path, b: Path, rtol: float) -> int:
    """``--numeric``: module docstring."""
    pa, pb = dict(products(a)), dict(products(b))
    counts = {"identical": 0, "within": 0, "DIFFERS": 0, "missing/new": 0}
    print("product\tverdict\tlargest difference")
    for rel in sorted(set(pa) | set(pb)):
        if rel not in pa or rel not in pb:
            counts["missing/new"] += 1
            print(f"{rel}\t{'missing after' if rel not in pb else 'new'}\t")
            continue
        x, y = pa[rel], pb[rel]
        if hash_file(x) == hash_file(y):
            counts["identical"] += 1
            continue
        suffix, note = x.suffix, ""
        if suffix == ".nc":
            worst, why = _compare_values(_netcdf_values(x), _netcdf_values(y))
            ok, note = not why and worst <= rtol, why or f"relative {worst:.2g}"
        elif suffix == ".json":
            try:
                worst, why = _compare_values(dict(_leaves(_scrub(json.loads(x.read_text())))),
                                             dict(_leaves(_scrub(json.loads(y.read_text())))))
                ok, note = not why and worst <= rtol, why or f"relative {worst:.2g}"
            except ValueError:
                ok, note = False, "not JSON"
        elif suffix in TEXT_SUFFIXES:
            worst, why = _compare_text(x.read_text(errors="replace"), y.read_text(errors="replace"))
            worst = round(worst, 6)                  # (the division by a power of ten is inexact)
            ok, note = not why and worst <= 1.0, why or f"{worst:g} in the last printed digit"
        elif suffix == ".png":
            ok = _same_pixels(x, y)
            note = "same pixels" if ok else "pixels differ"
        else:
            ok, note = False, "bytes differ"
        counts["within" if ok else "DIFFERS"] += 1
        print(f"{rel}\t{'within' if ok else 'DIFFERS'}\t{note}")
    print("# " + ", ".join(f"{v} {k}" for k, v in counts.items()), file=sys.stderr)
    return 0 if counts["DIFFERS"] == 0 and counts["missing/new"] == 0 else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="+")
    ap.add_argument("--compare", action="store_true", help="compare two hash tables")
    ap.add_argument("--numeric", action="store_true", help="compare two results folders, saying by how much")
    ap.add_argument("--rtol", type=float, default=1e-9, help="--numeric: relative tolerance of stored values")
    ap.add_argument("--rename", action="append", default=[], help="OLD=NEW path fragment renamed on purpose")
    args = ap.parse_args(argv)
    if args.compare:
        return compare(Path(args.paths[0]), Path(args.paths[1]), args.rename)
    if args.numeric:
        return numeric(Path(args.paths[0]), Path(args.paths[1]), args.rtol)
    root = Path(args.paths[0])
    for rel, p in products(root):
        print(f"{rel}\t{hash_file(p)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
