"""Real recordings as proof bases of the mismatch diagnosis: the detection limits of each shared recording
(:mod:`calib.diagnosis.limits`: known effects injected into the recording's samples through the physical transfer
function, diagnosed blind over block-resampled noise of the recording itself), and the proof at twice those limits.

The proof on one recording (:func:`prove`): every detectable library term at ``factor`` x its detection limit,
``n_inject`` injections spread over its axes, each scored as :func:`calib.diagnosis.limits.score_injection` scores
it (*named* alone or in its reported alias group; *covered* when the injected value lies inside the reported 95 %
interval shifted by the baseline's estimate); and ``n_out`` injections of each out-of-library effect and axis at
``factor`` x the size at which its misfit is seen, which must never be explained without its rival form.
:func:`acceptance` states what the proof must show. Units: the registry's (ug/g^2, ug/g^3, ppm; biases in ug) for
the injections; the products (:func:`reported_result`) give an asymmetry as the field's scale factor asymmetry
``scale_factor_asymmetry_ppm`` (twice the internal ``asym_ppm``, which they keep labelled as the internal model
parameter).
"""
from __future__ import annotations

import json
from pathlib import Path

from scipy import stats

from calib.core import seeds
from calib.core.errors import ResultCheckError
from calib.core.progress import Progress
from calib.diagnosis import DEFAULT_SETTINGS
from calib.diagnosis.analysis import ASYMMETRY_FACTOR, ASYMMETRY_NAME, INTERNAL_ASYMMETRY, STANDARD_ASYMMETRY
from calib.diagnosis.limits import (AXES, IN_LIBRARY, ProofBase, detection_limits, limits_markdown,
                                    out_of_library_spec, reported_limit, score_injection)
from calib.figures.real_proof_plots import limits_figure
from calib.io.atomic import write_json as write_json_atomic, write_text as write_text_atomic
from calib.studies.diagnosis_real import import_real


def prove(base: ProofBase, limits: list[dict], n_inject: int = 100, seed: int = 1, factor: float = 2.0,
          n_out: int = 30, block_s: float = 1.0, progress=True) -> dict:
    """The proof on one recording: every detectable library term at ``factor`` x its detection limit, ``n_inject``
    injections spread over its axes (named rate, coverage), and ``n_out`` injections of each out-of-library effect
    and axis at ``factor`` x the size at which its misfit is seen (never explained without its rival form)."""
    det = [r for r in limits if r.get("detectable") and r.get("kind") == "library"]
    by_eff = {}
    for r in det:
        by_eff.setdefault(r["effect"], []).append(r)
    total = n_inject * len(by_eff) + n_out * sum(1 for r in limits if r.get("kind") == "out_of_library"
                                                 and r.get("detectable"))
    bar = Progress(total, f"proof on {base.name}", every_s=1.0) if progress else None
    done = 0
    res = {"recording": base.name, "baseline": {"verdict": base.baseline.get("verdict"),
                                                "found": [f["key"] for f in base.baseline.get("found", [])],
                                                "explained": bool(base.baseline.get("explained"))},
           "in_library": [], "out_of_library": [], "degenerate_accepted": []}
    for eff, rows in by_eff.items():
        named = exact = covered = n_cov = 0
        for k in range(n_inject):
            r = rows[k % len(rows)]
            v = factor * r["limit"]
            spec = {"effect": eff, "axis": r["axis"], "value": v}
            rng = seeds.stream(seed, "real_proof", "proof", eff, k)
            rep = base.diagnose(base.inject(base.resample(rng, block_s), spec), f"+ {r['parameter']} = {v:.4g}")
            sc = score_injection(base, rep, spec)
            named += sc["named"]
            exact += sc["named_exactly"]
            if sc["covered"] is not None:
                n_cov += 1
                covered += sc["covered"]
            res["degenerate_accepted"] += sc["degenerate_accepted"]
            done += 1
            if bar:
                bar(done)
        res["in_library"].append({"effect": eff, "axes": [r["axis"] for r in rows], "factor_of_limit": factor,
                                  "values": {r["axis"]: factor * r["limit"] for r in rows}, "n": n_inject,
                                  "named": named, "named_rate": named / n_inject, "named_exactly": exact,
                                  "coverage_n": n_cov,
                                  "coverage": covered / n_cov if n_cov else None})
    for r in [r for r in limits if r.get("kind") == "out_of_library"]:
        if not r.get("detectable"):
            res["out_of_library"].append({"effect": r["effect"], "axis": r["axis"], "n": 0, "explained": 0,
                                          "why": r.get("why")})
            continue
        expl = 0
        verdicts = {}
        v = factor * r["limit"]
        for k in range(n_out):
            spec = out_of_library_spec(base, r["effect"], r["axis"], v)
            rng = seeds.stream(seed, "real_proof", "proof", r["effect"], r["axis"], k)
            rep = base.diagnose(base.inject(base.resample(rng, block_s), spec), f"+ {r['effect']} {r['axis']}")
            sc = score_injection(base, rep, spec)
            # right: not explained, or explained with the rival form disclosed (as the simulated proof scores it)
            expl += sc["explained"] and not rep.get("form_alternatives")
            verdicts[sc["verdict"]] = verdicts.get(sc["verdict"], 0) + 1
            res["degenerate_accepted"] += sc["degenerate_accepted"]
            done += 1
            if bar:
                bar(done)
        res["out_of_library"].append({"effect": r["effect"], "axis": r["axis"], "size_ug": v, "factor_of_limit": factor,
                                      "n": n_out, "explained": int(expl), "verdicts": verdicts})
    return res


#: the fewest intervals a coverage test takes (as in the simulated proof's gate): a library term with fewer on a
#: recording is pooled with the other such terms of every recording, and a pool still below it fails -- coverage is
#: never left untested
MIN_COVERAGE_N = 50


def coverage_consistent(k: int, n: int) -> bool:
    """Whether ``k`` of ``n`` 95 % intervals holding the truth is consistent with 95 %: the 99 % Clopper-Pearson
    interval of the coverage holds 0.95 or lies above it (intervals too wide are conservative, not wrong)."""
    hi = 1.0 if k == n else float(stats.beta.ppf(0.995, k + 1, n - k))
    return hi >= 0.95


def _covered(r) -> tuple[int, int]:
    return round(r["coverage"] * r["coverage_n"]), r["coverage_n"]


def pooled_coverage(results) -> dict | None:
    """The coverage test of the library terms with fewer than :data:`MIN_COVERAGE_N` intervals on their recording
    (named exactly in few injections, or few injections), pooled over the usable recordings: ``{"where", "covered",
    "n", "passed"}`` (``passed`` False also when the pool holds fewer than MIN_COVERAGE_N intervals), or None when
    no term needs it."""
    small = [(rec["recording"], r) for rec in results if rec.get("usable") and rec.get("proof")
             for r in rec["proof"]["in_library"] if 0 < r.get("coverage_n", 0) < MIN_COVERAGE_N]
    if not small:
        return None
    k, n = map(sum, zip(*[_covered(r) for _, r in small]))
    return {"where": f"pooled over {len(small)} library term(s) of {', '.join(dict.fromkeys(nm for nm, _ in small))}",
            "covered": k, "n": n, "passed": n >= MIN_COVERAGE_N and coverage_consistent(k, n)}


def pooled_coverage_failure(results) -> str | None:
    """A message when the pooled coverage test (:func:`pooled_coverage`) fails or cannot be made, else None."""
    pc = pooled_coverage(results)
    if pc is None or pc["passed"]:
        return None
    if pc["n"] < MIN_COVERAGE_N:
        return (f"{pc['where']}: coverage_consistent_with_95pct untestable ({pc['n']} intervals, fewer than "
                f"{MIN_COVERAGE_N}: raise diagnosis.real_proof.n_inject)")
    return f"{pc['where']}: coverage_consistent_with_95pct ({pc['covered']}/{pc['n']} intervals hold the injected value)"


def acceptance(res: dict) -> dict:
    """The acceptance criteria of a real-recording proof base on one recording."""
    lib = res["in_library"]
    big = [r for r in lib if r.get("coverage_n", 0) >= MIN_COVERAGE_N]
    return {"named_ge_95pct": all(r["named_rate"] >= 0.95 for r in lib) if lib else None,
            # each term with MIN_COVERAGE_N intervals here; the others pooled over recordings (pooled_coverage_failure)
            "coverage_consistent_with_95pct": all(coverage_consistent(*_covered(r)) for r in big) if big else None,
            "out_of_library_never_explained": all(r["explained"] == 0 for r in res["out_of_library"]),
            "untouched_names_no_term": not res["baseline"]["found"],
            "no_degenerate_explanation": not res["degenerate_accepted"]}


# =============================================================================================================
# the workflow stage
# =============================================================================================================
def _one_recording(args):
    """Limits and proof on one recording (runs in a worker process)."""
    settings_path, settings, reps, n_inject, n_out, seed, factor, axes = args
    name = Path(settings_path).stem
    try:
        ds = import_real(settings_path)
    except Exception as exc:  # noqa: BLE001 - an import failure is reported, not a proof
        return {"recording": name, "usable": False, "why": f"import or static detection failed: {exc}"}
    base = ProofBase(ds, settings, name=name)
    n_static = len(base.segments)
    out = {"recording": name, "n_static_segments": n_static,
           "baseline": {"verdict": base.baseline.get("verdict"), "reason": base.baseline.get("verdict_reason"),
                        "found": [f["key"] for f in base.baseline.get("found", [])]}}
    limits = detection_limits(base, reps=reps, seed=seeds.child_seed(seed, "limits", name), axes=axes,
                              progress=False)
    out["limits"] = limits
    if n_static < MIN_POSES or base.gain is None:
        out["usable"] = False
        out["why"] = (f"{n_static} static segments (a proof base needs >= {MIN_POSES} poses): "
                      + str(base.baseline.get("verdict_reason", ""))[:200])
        return out
    out["usable"] = True
    res = prove(base, limits, n_inject=n_inject, n_out=n_out, seed=seeds.child_seed(seed, "proof", name),
                factor=factor, progress=False)
    out["proof"] = res
    out["acceptance"] = acceptance(res)
    return out


#: poses a recording needs to serve as a proof base (each shared real recording with >= 12 static poses)
MIN_POSES = 12


def real_proof_stage(out_dir, config_dir, settings=None, reps: int = 10, n_inject: int = 100, n_out: int = 10,
                     seed: int = 0, factor: float = 2.0, recordings=None, workers: int = 2, metrics_path=None,
                     enforce: bool = True, axes=AXES, log=print) -> dict:
    """Detection limits and the injection proof on every shared real recording (import settings in
    ``config_dir``; ``recordings``: a subset of their names). Writes ``real_proof.json``, ``limits.csv``,
    ``real_proof.md`` and ``limits.png`` into ``out_dir``; exit 3 (:class:`ResultCheckError`) when an acceptance
    point fails on a usable recording and ``enforce``."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    paths = recording_settings(config_dir, recordings)
    jobs = [_job(p, settings, reps, n_inject, n_out, seed, factor, axes) for p in paths]
    bar = Progress(len(jobs), "real recordings (limits + proof)", every_s=0.0)
    results = []
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("fork")) as ex:
            for r in ex.map(_one_recording, jobs):
                results.append(r)
                bar(len(results), extra=r["recording"])
    else:
        for j in jobs:
            results.append(_one_recording(j))
            bar(len(results), extra=results[-1]["recording"])
    return real_proof_products(out_dir, results, reps=reps, n_inject=n_inject, n_out=n_out, seed=seed, factor=factor,
                               metrics_path=metrics_path, enforce=enforce, log=log)


def recording_settings(config_dir, recordings=None) -> list[Path]:
    """The import settings (``config_dir/*.yaml``, sorted by name) the proof runs on: all, or the names in
    ``recordings`` (an unknown name is refused, naming the known ones)."""
    paths = sorted(Path(config_dir).glob("*.yaml"))
    if recordings:
        unknown = sorted(set(recordings) - {p.stem for p in paths})
        if unknown:
            raise ValueError(f"diagnosis.real_proof.recordings: unknown {unknown}; known: {[p.stem for p in paths]}")
        paths = [p for p in paths if p.stem in set(recordings)]
    return paths


def _job(settings_path, settings, reps, n_inject, n_out, seed, factor, axes) -> tuple:
    return (str(settings_path), {**DEFAULT_SETTINGS, **(settings or {})}, reps, n_inject, n_out, seed, factor,
            tuple(axes))


def real_proof_recording(settings_path, settings=None, reps: int = 10, n_inject: int = 100, n_out: int = 10,
                         seed: int = 0, factor: float = 2.0, axes=AXES) -> dict:
    """Limits and proof on one recording (import settings ``settings_path``) on its own: the workflow's job per
    recording, gathered by :func:`real_proof_products`; the recording seeds itself by its name, so the result is
    the one :func:`real_proof_stage` has for it."""
    return _one_recording(_job(settings_path, settings, reps, n_inject, n_out, seed, factor, axes))


def real_proof_products(out_dir, results: list, reps: int = 10, n_inject: int = 100, n_out: int = 10, seed: int = 0,
                        factor: float = 2.0, metrics_path=None, enforce: bool = True, log=print) -> dict:
    """The stage's files from every recording's result (in the order of :func:`recording_settings`):
    ``real_proof.json``, ``limits.csv``, ``real_proof.md``, ``limits.png`` and the metrics; exit 3
    (:class:`ResultCheckError`) when an acceptance point fails on a usable recording and ``enforce``."""
    out_dir = Path(out_dir)
    shown = [reported_result(r) for r in results]      # as the user reads them: the standard asymmetry
    out = {"format": "calib-real-proof-1", "seed": seed, "reps_per_magnitude": reps, "n_inject": n_inject,
           "n_out": n_out, "factor_of_limit": factor, "recordings": shown}
    write_json_atomic(out, out_dir / "real_proof.json")
    write_text_atomic(out_dir / "limits.csv", limits_csv(shown))
    write_text_atomic(out_dir / "real_proof.md", real_proof_md(out))
    limits_figure(shown, out_dir / "limits.png")
    log((out_dir / "real_proof.md").read_text())
    failed = [f"{r['recording']}: {k}" for r in results if r.get("usable")
              for k, v in r["acceptance"].items() if v is False]
    failed += [f for f in [pooled_coverage_failure(results)] if f]
    metrics = {"usable_recordings": sum(bool(r.get("usable")) for r in results), "failed": failed}
    if metrics_path:
        write_json_atomic(metrics, metrics_path)
    if failed and enforce:
        raise ResultCheckError(f"the real-recording proof does not hold: {'; '.join(failed)}",
                               file=out_dir / "real_proof.md", field="diagnosis.real_proof",
                               fix="read real_proof.md; a failed acceptance point is a defect of the method")
    return out


def real_proof_gather(out_dir, config_dir, parts, recordings=None, reps: int = 10, n_inject: int = 100,
                      n_out: int = 10, seed: int = 0, factor: float = 2.0, metrics_path=None, enforce: bool = True,
                      log=print) -> dict:
    """The stage's files from its recordings run as separate jobs (:func:`real_proof_recording`, one part file
    each, :func:`write_part`): the same files as :func:`real_proof_stage`, the recordings in its order."""
    names = [p.stem for p in recording_settings(config_dir, recordings)]
    got = {}
    for path in parts:
        r = read_part(path)
        got[r["recording"]] = r
    missing = [nm for nm in names if nm not in got]
    if missing:
        raise ValueError(f"diagnosis.real_proof: no result for recording(s) {missing}")
    log(f"real-recording proof: {len(names)} recordings gathered from their jobs")
    return real_proof_products(out_dir, [got[nm] for nm in names], reps=reps, n_inject=n_inject, n_out=n_out,
                               seed=seed, factor=factor, metrics_path=metrics_path, enforce=enforce, log=log)


def write_part(result: dict, path) -> Path:
    """One recording's result as JSON for the gathering job, every number as Python holds it (NaN kept)."""
    return write_json_atomic(result, path, strict=False)


def read_part(path) -> dict:
    """A result written by :func:`write_part`."""
    return json.loads(Path(path).read_text())


def reported_result(result: dict) -> dict:
    """One recording's result as the products give it: its limits as :func:`calib.diagnosis.limits.reported_limit`
    gives them, and each library term of its proof with the name of its size parameter (``parameter``) and its
    injected sizes (``values``) in it -- for an asymmetry the standard ``scale_factor_asymmetry_ppm``, twice the
    internal ``asym_ppm`` the injections use, kept under ``internal_model_parameter``. A result already reported is
    returned as it is."""
    out = {**result, "limits": [reported_limit(L) for L in result.get("limits", [])]}
    if result.get("proof"):
        lib = []
        for q in result["proof"]["in_library"]:
            eff = q["effect"]
            if "parameter" in q:            # already as reported
                pass
            elif eff in STANDARD_ASYMMETRY:
                q = {**q, "parameter": ASYMMETRY_NAME,
                     "values": {a: ASYMMETRY_FACTOR * v for a, v in q["values"].items()},
                     "internal_model_parameter": {"parameter": IN_LIBRARY[eff], "values": q["values"],
                                                  "meaning": INTERNAL_ASYMMETRY}}
            else:
                q = {**q, "parameter": IN_LIBRARY.get(eff, eff)}
            lib.append(q)
        out["proof"] = {**result["proof"], "in_library": lib}
    return out


def limits_csv(results) -> str:
    """The limits of every recording, one row per term or effect and axis, as :func:`reported_result` gives them."""
    results = [reported_result(r) for r in results]
    lines = ["recording,effect,axis,parameter,kind,baseline_value,baseline_se,detection_limit,detectable,why"]
    for r in results:
        for L in r.get("limits", []):
            why = str(L.get("why", "")).replace('"', "'")
            lines.append(",".join([r["recording"], L["effect"], L["axis"], L["parameter"], L["kind"],
                                   "" if L.get("baseline_value") is None else f"{L['baseline_value']:.6g}",
                                   "" if L.get("baseline_se") is None else f"{L['baseline_se']:.6g}",
                                   "" if L.get("limit") is None else f"{L['limit']:.6g}",
                                   str(bool(L.get("detectable"))), f'"{why}"']))
    return "\n".join(lines) + "\n"


def real_proof_md(out) -> str:
    """The proof's Markdown page from the products' JSON (``recordings`` as :func:`reported_result` gives them)."""
    out = {**out, "recordings": [reported_result(r) for r in out["recordings"]]}
    L = ["# The diagnosis proved on real recordings", "",
         f"Effects injected into each shared recording through the physical transfer function (calib.sim.physical) "
         f"on block-resampled noise of the recording itself; detection limits from {out['reps_per_magnitude']} "
         f"repetitions per magnitude; the proof at {out['factor_of_limit']:g}x each limit with {out['n_inject']} "
         f"injections per library term and {out['n_out']} per out-of-library effect and axis (seed {out['seed']}).",
         ""]
    for r in out["recordings"]:
        L.append(f"## {r['recording']}")
        L.append("")
        b = r.get("baseline", {})
        L.append(f"- untouched recording: {b.get('verdict')} (found: {', '.join(b.get('found') or []) or 'nothing'}) "
                 f"-- {str(b.get('reason', ''))[:300]}")
        if not r.get("usable"):
            L.append(f"- not a proof base: {r.get('why')}")
        L.append("")
        if r.get("limits"):
            L += limits_markdown(r["limits"], title=f"Detection limits: {r['recording']}")
        if r.get("proof"):
            p = r["proof"]
            L += ["| injected at 2x limit | n | named (alias group incl.) | named exactly | coverage of the 95 % "
                  "interval (n) |", "|---|---|---|---|---|"]
            for q in p["in_library"]:
                cov = "n/a" if q["coverage"] is None else f"{q['coverage']:.3f}"
                L.append(f"| {q['effect']}, {q['parameter']} ({', '.join(f'{a}: {v:.4g}' for a, v in q['values'].items())})"
                         f" | {q['n']} | "
                         f"{q['named_rate']:.3f} | {q['named_exactly']}/{q['n']} | {cov} ({q['coverage_n']}) |")
            L.append("")
            L += ["| out-of-library at 2x the size seen | n | explained | verdicts |", "|---|---|---|---|"]
            for q in p["out_of_library"]:
                size = f"{q['size_ug']:.4g} ug" if q.get("size_ug") is not None else str(q.get("why", ""))[:120]
                L.append(f"| {q['effect']} {q['axis']} ({size}) | {q['n']} | {q['explained']} | "
                         + ", ".join(f"{k} {v}" for k, v in q.get("verdicts", {}).items()) + " |")
            L.append("")
            L.append("Acceptance: " + ", ".join(f"{k} = {v}" for k, v in r["acceptance"].items()))
            if p["degenerate_accepted"]:
                L.append(f"Degenerate explanations accepted: {p['degenerate_accepted'][:10]}")
            L.append("")
    pc = pooled_coverage(out["recordings"])
    if pc is not None:   # the terms with too few intervals on their own recording (acceptance: None there)
        L.append(f"Coverage {pc['where']}: {pc['covered']}/{pc['n']} intervals hold the injected value; consistent "
                 f"with 95 % (>= {MIN_COVERAGE_N} intervals, 99 % Clopper-Pearson) = {pc['passed']}")
        L.append("")
    return "\n".join(L) + "\n"
