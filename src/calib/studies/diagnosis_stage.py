"""Diagnosis stage of the workflow: the study's session, the concealed-effect proof, the real recordings.

Called by the rules of ``workflow/rules/diagnosis.smk`` (and ``real.smk`` for a real-recording study). The
science lives in :mod:`calib.diagnosis`; this module only runs it and writes the stage's products:

* ``diagnose_session``: ``report.json``, ``report.md``, residual and Allan figures of one recording, and a
  ``diagnosis.metrics.json`` (verdict, chi-square before/after, number of findings) for tracking.
* ``proof_stage``: :func:`calib.studies.diagnosis_proof.run_proof` over ``n_seeds`` noise seeds per session, then a labelled
  netCDF of every seed's outcome (dims ``session``, ``seed``), the detection-power table and figure
  (``power.csv``, ``power.png``: detection rate against the injected magnitude, the 80 % line), the proof
  table (``proof.csv``, ``proof.md``) and metrics. Wall times go to ``timings.json`` only. The workflow runs
  the same proof as one job per session with its power scan (``proof_session_stage``) and gathers them
  (``proof_gather_stage``) into the same files.
* ``real_stage``: :func:`calib.studies.diagnosis_real.run_real` on every shared recording plus the injection test.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import xarray as xr

from calib.core.errors import ResultCheckError
from calib.core.progress import Progress
from calib.diagnosis import diagnose_recording, is_shape_parameter
from calib.diagnosis.problem import settings_of
from calib.io.atomic import write_json, write_text
from calib.io.netcdf import write_netcdf
from calib.studies import diagnosis_proof as proof
from calib.studies import diagnosis_real as real

#: the verdicts, in the order used for integer codes in the netCDF
VERDICTS = ("adequate", "missing_physics", "inconclusive", "unexplained")


def check_settings(settings: dict | None, where: str = "diagnosis.settings") -> dict:
    """Overrides of :data:`calib.diagnosis.DEFAULT_SETTINGS`; an unknown name, a value of the wrong type or out of
    range is refused, naming ``where`` and the setting (:func:`calib.diagnosis.problem.settings_of`)."""
    settings = dict(settings or {})
    settings_of(settings, file=where)
    return settings


def diagnose_session(recording_path, out_dir, settings=None, metrics_path=None, fieldcal_path=None,
                     log=print) -> dict:
    """Diagnose one recording (synthetic or imported) into ``out_dir``; returns the report. ``fieldcal_path``:
    the field calibration of an imported recording without a segment table (``static_intervals`` of
    ``calib-fieldcal-1``): the diagnosis then tests the same static intervals the calibration used."""
    st = check_settings(settings)
    log(f"diagnosing {recording_path}")
    intervals = None
    if fieldcal_path:
        with xr.open_dataset(fieldcal_path) as fc:
            intervals = np.asarray(fc["static_intervals"].values)
        log(f"static intervals: the {len(intervals)} of the field calibration ({fieldcal_path})")
    rep = diagnose_recording(recording_path, out_dir, st, intervals=intervals,
                                intervals_source=str(fieldcal_path or ""))
    gof = rep.get("goodness_of_fit", {})
    log(f"verdict: {rep['verdict']} -- {rep.get('verdict_reason', '')}")
    for f in rep.get("found", []):
        log(f"  found {f['key']} (BIC gain {f['delta_bic']:.1f}); aliases: "
            + (", ".join(a["key"] for a in f["aliases"]) or "none"))
    metrics = {"verdict": rep["verdict"], "n_found": len(rep.get("found", [])),
               "found": [f["key"] for f in rep.get("found", [])],
               "chi2_before": gof.get("before", {}).get("chi2"), "chi2_after": gof.get("after", {}).get("chi2"),
               "p_before": gof.get("before", {}).get("p"), "p_after": gof.get("after", {}).get("p")}
    if metrics_path:
        write_json(metrics, metrics_path)
    return rep


# =====================================================================================================
# proof
# =====================================================================================================
def proof_dataset(out: dict) -> xr.Dataset:
    """Every seed's outcome of the proof as a labelled dataset (dims ``session``, ``seed``; ``power_point``)."""
    results = [r for r in out["_results"] if r["scale"] == 1.0]
    sessions = [r["name"] for r in results]
    seeds = list(dict.fromkeys(x["seed"] for r in results for x in r["rows"]))  # in draw order (k = 0, 1, ...)
    shape = (len(sessions), len(seeds))
    var = {k: np.full(shape, np.nan) for k in ("chi2_before", "chi2_after", "chi2_after_p", "coverage")}
    ints = {k: np.full(shape, -1, dtype=np.int8) for k in ("correct", "named_exactly", "false_discovery",
                                                             "n_found", "verdict")}
    for i, r in enumerate(results):
        for x in r["rows"]:
            j = seeds.index(x["seed"])
            for k in ("chi2_before", "chi2_after", "chi2_after_p"):
                var[k][i, j] = np.nan if x.get(k) is None else float(x[k])
            cov = x.get("coverage") or []
            var["coverage"][i, j] = float(np.mean([c["covered"] for c in cov])) if cov else np.nan
            ints["correct"][i, j] = int(bool(x["correct"]))
            ints["named_exactly"][i, j] = int(bool(x.get("named_exactly", False)))
            ints["false_discovery"][i, j] = int(bool(x["false_discoveries"]))
            ints["n_found"][i, j] = len(x["found"])
            ints["verdict"][i, j] = VERDICTS.index(x["verdict"]) if x.get("verdict") in VERDICTS else -1
    kinds = [proof.PROOF_SESSIONS[s][0] for s in sessions]
    yes_no = {"flag_values": np.array([0, 1], dtype=np.int8), "flag_meanings": "false true"}
    ds = xr.Dataset(
        {
            "chi2_before": (("session", "seed"), var["chi2_before"],
                            {"long_name": "chi-square of the base model", "units": "1"}),
            "chi2_after": (("session", "seed"), var["chi2_after"],
                           {"long_name": "chi-square with the selected terms", "units": "1"}),
            "chi2_after_p": (("session", "seed"), var["chi2_after_p"],
                             {"long_name": "p-value of chi2_after", "units": "1"}),
            "coverage": (("session", "seed"), var["coverage"],
                         {"long_name": "fraction of the named effect's parameters whose truth lies inside the "
                                       "reported 95 % interval", "units": "1"}),
            "correct": (("session", "seed"), ints["correct"],
                        {"long_name": "diagnosis correct (null: nothing found; single: the injected effect "
                                      "named, alone or in its alias group; confounded: never one effect)",
                         **yes_no}),
            "named_exactly": (("session", "seed"), ints["named_exactly"],
                              {"long_name": "the injected effect named exactly (not only its alias group)", **yes_no}),
            "false_discovery": (("session", "seed"), ints["false_discovery"],
                                {"long_name": "a finding whose alias group holds no injected effect", **yes_no}),
            "n_found": (("session", "seed"), ints["n_found"], {"long_name": "number of terms found"}),
            "verdict": (("session", "seed"), ints["verdict"],
                        {"long_name": "verdict of the diagnosis (-1: none)",
                         "flag_values": np.arange(len(VERDICTS), dtype=np.int8), "flag_meanings": " ".join(VERDICTS)}),
        },
        coords={"session": ("session", sessions, {"long_name": "proof session"}),
                "seed": ("seed", np.asarray(seeds, dtype=np.int64), {"long_name": "noise seed"}),
                "kind": ("session", kinds, {"long_name": "kind of proof session"})},
        attrs={"title": "calib mismatch diagnosis: concealed-effect proof, one row per noise seed",
               "method": out["method"]},
    )
    pts = [(nm, q) for nm, p in (out.get("power") or {}).items() for q in p["points"]]
    if pts:
        ds = ds.assign_coords(power_point=("power_point", np.arange(len(pts), dtype=np.int32),
                                           {"long_name": "point of the detection-power curves"}))
        ds["power_session"] = ("power_point", [nm for nm, _ in pts], {"long_name": "proof session"})
        ds["power_scale"] = ("power_point", np.array([q["scale"] for _, q in pts]),
                             {"long_name": "injected magnitude as a fraction of the proof magnitude"})
        ds["power_detected"] = ("power_point", np.array([q["detected"] for _, q in pts], dtype=np.int32),
                                {"long_name": "seeds in which the effect was detected"})
        ds["power_n"] = ("power_point", np.array([q["n"] for _, q in pts], dtype=np.int32),
                         {"long_name": "seeds run"})
    return ds


def _magnitude_text(eff: dict | None) -> str:
    if not eff:
        return ""
    parts = []
    for params in eff.values():
        for k, v in params.items():
            if is_shape_parameter(k):
                continue
            a = np.asarray(v, float)
            if a.size == 0 or not np.any(a):
                continue
            txt = np.array2string(np.round(a, 4), separator=" ", max_line_width=10**6) if a.ndim else f"{float(a):.4g}"
            parts.append(f"{k}={' '.join(txt.split())}")   # one line: a CSV field holds no newline
    return "; ".join(parts)


def power_csv(power: dict) -> str:
    """One row per effect: the smallest scale (fraction of the proof magnitude) detected in >= 80 % of seeds,
    that magnitude, and the measured points."""
    lines = ["effect,smallest_scale_80pct,smallest_magnitude_80pct,points(scale:detected/n)"]
    for nm, p in power.items():
        s80 = p["smallest_scale_detected_80pct"]
        pts = " ".join(f"{q['scale']:.4g}:{q['detected']}/{q['n']}" for q in p["points"])
        mag = _magnitude_text(p.get("smallest_magnitude_detected_80pct")) if s80 else "not reached"
        lines.append(f"{nm},{'' if s80 is None else f'{s80:.4g}'},\"{mag}\",{pts}")
    return "\n".join(lines) + "\n"


def proof_stage(out_dir, n_seeds: int, first_seed: int, settings=None, sessions=None, power_seeds: int = 0,
                workers: int = 2, base=None, site=None, prov=None, metrics_path=None, log=print,
                enforce: bool = True, injection: str = "physical") -> dict:
    """Run the concealed-effect proof and write its products into ``out_dir`` (see the module docstring).

    ``base``: the study's ``calibration_session`` config (path, noise, rate) and ``site``: its site; every proof
    session is that session with one effect hidden (``conceal: true``)."""
    st = check_settings(settings)
    names = _proof_names(sessions)
    out_dir = Path(out_dir)
    n_single = sum(proof.PROOF_SESSIONS[nm][0] == "single" for nm in names)
    prog = Progress(len(names) + (5 * n_single if power_seeds else 0), label="proof sessions", every_s=0.0)
    log(f"proof: {len(names)} sessions x {n_seeds} seeds (first seed {first_seed}), {workers} worker(s), "
        f"library effects made by the {injection} path"
        + (f"; detection power with {power_seeds} seeds per magnitude" if power_seeds else ""))
    out = proof.run_proof(out_dir, n_seeds=n_seeds, effects=names, seed=first_seed, workers=workers, settings=st,
                       power_scales="auto" if power_seeds else None, power_seeds=power_seeds,
                       base=_proof_base(base, site), progress=lambda i, n, nm: prog(extra=nm), injection=injection)
    return _proof_products(out, out_dir, n_seeds, names, prov, metrics_path, log, enforce)


def _proof_names(sessions) -> list[str]:
    """The proof's sessions (all of them when ``sessions`` is empty); an unknown name is refused."""
    names = list(sessions) if sessions else list(proof.PROOF_SESSIONS)
    unknown = sorted(set(names) - set(proof.PROOF_SESSIONS))
    if unknown:
        raise ValueError(f"diagnosis.proof.sessions: unknown session(s) {unknown}; known: {list(proof.PROOF_SESSIONS)}")
    return names


def _proof_base(base, site):
    """The study's calibration session with its site: what every proof session hides its effect in."""
    if base is None:
        return None
    return {**base, "site": dict(site or base.get("site") or proof.SESSION_BASE["site"])}


def proof_session_stage(name: str, part_dir, n_seeds: int, first_seed: int, settings=None, base=None, site=None,
                        power_seeds: int = 0, injection: str = "physical", noise_store=None, log=print) -> dict:
    """One session of the proof as a job of its own (the workflow scatters the proof by session): into
    ``part_dir`` its result (``result.json``, :func:`calib.studies.diagnosis_proof.write_part`), its end-to-end
    report (``end_to_end/<name>/``), its residual figure (``figures/``) and, for a single effect with
    ``power_seeds``, its detection-power scan (``power.json``; its magnitudes follow from the session's result),
    for :func:`proof_gather_stage`. ``noise_store``: a folder the sessions' jobs share their seeds' noise in
    (:func:`calib.studies.diagnosis_proof.noise_store`)."""
    st = check_settings(settings)
    _proof_names([name])
    part_dir = Path(part_dir)
    base = _proof_base(base, site)
    log(f"proof session {name}: {n_seeds} seeds (first seed {first_seed}), library effects made by the "
        f"{injection} path")
    r = proof.proof_session(name, part_dir, n_seeds, first_seed, settings=st, base=base, injection=injection,
                            store=noise_store)
    log(f"{name}: {sum(bool(x['correct']) for x in r['rows'])}/{len(r['rows'])} correct, {r['t_total_s']:.1f} s")
    scan = proof.power_scan(r, power_seeds, first_seed, settings=st, base=base, injection=injection,
                            power_scales="auto" if power_seeds else None, store=noise_store)
    for x in scan:
        log(f"  power scan, scale {x['scale']:.4g}: {sum(bool(y['correct']) for y in x['rows'])}/{len(x['rows'])} "
            f"detected, {x['t_total_s']:.1f} s")
    if scan:
        proof.write_part(scan, part_dir / "power.json")
    proof.write_part(r, part_dir / "result.json")   # last: a part with its result is complete
    return r


def proof_gather_stage(out_dir, session_parts, n_seeds: int, first_seed: int, sessions=None, power_seeds: int = 0,
                       prov=None, metrics_path=None, log=print, enforce: bool = True,
                       injection: str = "physical") -> dict:
    """The proof's products from its sessions run as separate jobs (:func:`proof_session_stage`): the same files
    as :func:`proof_stage` (the same code turns the sessions' results into them). ``session_parts``: the sessions'
    part folders, in any order."""
    names = _proof_names(sessions)
    out_dir = Path(out_dir)
    main, scans = {}, {}
    for part in map(Path, session_parts):
        r = proof.read_part(part / "result.json")
        main[r["name"]] = r
        if (part / "power.json").is_file():
            scans[r["name"]] = proof.read_part(part / "power.json")
        for sub in ("end_to_end", "figures"):   # the session's report and residual figure, byte for byte
            if (part / sub).is_dir():
                shutil.copytree(part / sub, out_dir / sub, dirs_exist_ok=True)
    missing = [nm for nm in names if nm not in main]
    if missing:
        raise ValueError(f"diagnosis.proof: no result for session(s) {missing}")
    log(f"proof: {len(names)} sessions x {n_seeds} seeds (first seed {first_seed}), gathered from "
        f"{len(main)} session jobs ({len(scans)} with a power scan), library effects made by the {injection} path")
    out = proof.assemble_proof(out_dir, names, main, scans, n_seeds, first_seed, injection,
                               "auto" if power_seeds else None, workers="one job per session")
    return _proof_products(out, out_dir, n_seeds, names, prov, metrics_path, log, enforce)


def _proof_products(out, out_dir, n_seeds, names, prov, metrics_path, log, enforce):
    """The stage's netCDF, power table and figure, metrics and acceptance check from the proof ``out``."""
    out_dir = Path(out_dir)
    write_netcdf(proof_dataset(out), out_dir / "proof.nc", prov)
    # written also without a scan (power_seeds: 0): an empty table and a figure that says so
    write_text(out_dir / "power.csv", power_csv(out.get("power") or {}))
    from calib.figures import power_plots   # matplotlib: imported only when drawing

    power_plots.detection_power(out.get("power") or {}, out_dir / "power.png")
    metrics = {"n_seeds": n_seeds, "sessions": len(names)}
    for s in out["sessions"]:
        m = {"rate": s["rate"], "false_discovery_rate": s["false_discovery_rate"]}
        if "coverage" in s:
            m["coverage"] = s["coverage"]
        if s.get("chi2_after_p_ge_0.01") is not None:
            m["chi2_after_p_ge_0.01"] = s["chi2_after_p_ge_0.01"]
        metrics[s["session"]] = m
    failed = rejected_claims(out["sessions"])
    metrics["all_acceptance_met"] = not failed
    metrics["rejected_claims"] = failed
    log(Path(out_dir / "proof.md").read_text())
    log(f"wall time {out['_timings']['total_s']:.1f} s")
    if metrics_path:
        write_json(metrics, metrics_path)
    if failed and enforce:
        more = f" (and {len(failed) - 1} more: proof.md, section Gate)" if len(failed) > 1 else ""
        raise ResultCheckError(f"the proof's seeds reject {len(failed)} of its claims: {failed[0]}{more}",
                               file=out_dir / "proof.md",
                               field="diagnosis.proof", fix="read proof.md; a claimed rate that does not hold is a "
                               "defect of the method, not of the proof (diagnosis.proof.enforce: false only to "
                               "inspect it)")
    return out


def rejected_claims(sessions) -> list[str]:
    """The proof's claims that its seeds reject (:func:`calib.studies.diagnosis_proof.gate`): every claim proof.md
    states -- named, named and explained, called adequate, not explained out of the library, the chi-square after
    the found terms, the false discoveries, the coverage of the 95 % intervals (pooled to >= 50 intervals, never
    skipped), standard errors against the Fisher bound, only determined parameters reported, efficiency, a
    confounded pair never attributed to one effect. One line per rejected claim; empty when every claim stands."""
    return proof.gate_failures(sessions)


def real_stage(out_dir, settings=None, config_dir=None, inject=None, metrics_path=None, log=print) -> dict:
    """Diagnose every shared real recording and the IMU-TK session with a known term injected."""
    st = check_settings(settings)
    out = real.run_real(out_dir, config_dir=config_dir, settings=st, inject=inject)
    for r in out["recordings"]:
        log(f"{r['recording']}: {r['verdict']} -- {r.get('reason', '')}")
    inj = out.get("injection")
    if inj:
        log(f"injection into {inj['recording']}: {inj['injected']} -> named: {inj['named']}; found {inj['found']}")
        for p in inj["recovered"]:
            log(f"  {p['name']}: injected {p['injected']:.4g}, found - uninjected {p['found_minus_uninjected']:.4g}"
                f" (inside 95 % CI: {p['injected_inside_ci95_of_difference']})")
    metrics = {r["recording"]: {"verdict": r["verdict"], "n_found": len(r.get("found") or [])}
               for r in out["recordings"]}
    if inj:
        metrics["injection_named"] = bool(inj["named"])
    if metrics_path:
        write_json(metrics, metrics_path)
    return out
