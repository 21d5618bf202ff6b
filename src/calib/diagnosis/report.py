"""Report files of the diagnosis: ``report.json`` content, the plain-words ``report.md``, and the figures
(standardised residuals before/after, Allan deviation)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from calib.diagnosis.bound import attach_bounds
from calib.diagnosis.geometry import AXES, ROWS, SENSORS
from calib.diagnosis.problem import REPORT_FORMAT, Problem
from calib.sim import effects

def fmt(v, nd=4):
    """``v`` with ``nd`` significant digits; 'n/a' for None."""
    if v is None:
        return "n/a"
    try:
        return f"{v:.{nd}g}"
    except (TypeError, ValueError):
        return str(v)


def report_markdown(rep: dict) -> str:
    """Plain-words report."""
    L = [f"# Mismatch diagnosis: {Path(rep.get('recording', '')).name}", ""]
    L.append(f"**Verdict: {rep['verdict']}** -- {rep.get('verdict_reason', '')}")
    L.append("")
    if rep["verdict"] == "inconclusive" and "goodness_of_fit" not in rep:
        # refused before any fit (bad input): the reason and the fix are all there is to say
        if rep.get("fix"):
            L.append(f"What would fix it: {rep['fix']}")
        return "\n".join(L) + "\n"
    L.append(f"Model: {rep.get('model_description', rep.get('model'))}")
    L.append(f"Noise: {rep.get('noise', {}).get('method', '')}")
    if rep.get("segments_from"):
        L.append(f"Segments: {rep['segments_from']}")
    L.append("")
    g = rep["goodness_of_fit"]
    L.append("## Goodness of fit")
    L.append("")
    L.append("| model | chi2 | dof | p |")
    L.append("|---|---|---|---|")
    for k in ("before", "after"):
        L.append(f"| {k} | {fmt(g[k]['chi2'])} | {g[k]['dof']} | {fmt(g[k]['p'], 3)} |")
    L.append("")
    L.append("Per sensor axis (before): " + "; ".join(
        f"{b['sensor']} {b['axis']}: {fmt(b['chi2'])} on {b['n_obs']}" for b in g["before"]["by_sensor_axis"]))
    L.append("")
    adq = rep.get("adequacy", {}).get("after")
    if adq:
        L.append(f"## Adequacy of the final model (explained: {str(rep.get('explained')).lower()})")
        L.append("")
        L.append(f"{adq['method']}, family-wise level {adq['alpha']:g}.")
        L.append("")
        L.append("| subset | chi2 | dof | chi2/dof | p (Holm) | |")
        L.append("|---|---|---|---|---|---|")
        for t in adq["tests"]:
            L.append(f"| {t['name']} | {fmt(t['chi2'])} | {t['dof']:.3g} | {t['overdispersion']:.3g} | "
                     f"{fmt(t['p_holm'], 3)} | {'**fails**' if t['rejected'] else 'passes'} |")
        L.append("")
    sn = rep.get("adequacy", {}).get("slow_noise")
    if sn and sn.get("within_segment"):
        L.append("## Slow noise between the segments: what the verdict assumes")
        L.append("")
        L.append(f"The tests above add a slow noise between the segments taken from {sn['source']} "
                 f"({sn['source_kind']}). On the noise measured within the segments alone:")
        L.append("")
        L.append("| subset | chi2 | dof | p (Holm) | |")
        L.append("|---|---|---|---|---|")
        for t in sn["within_segment"]["tests"]:
            L.append(f"| {t['name']} | {fmt(t['chi2'])} | {t['dof']:.3g} | {fmt(t['p_holm'], 3)} | "
                     f"{'**fails**' if t['rejected'] else 'passes'} |")
        L.append("")
        for e in sn.get("levels", []):
            if e.get("not_computed"):
                L.append(f"- {e['sensor']} {e['axis']}: passes only with a bias instability above zero between the "
                         f"segments ({e['not_computed']})")
                continue
            conv = (f" ({fmt(e['minimum_for_adequacy_input_unit'], 3)} {e['input_unit']})"
                    if "input_unit" in e else "")
            shown = {True: "the record resolves it: measured", False: "the record does not resolve it: assumed",
                     None: "no record: assumed"}[e["record_resolves_it"]]
            L.append(f"- {e['sensor']} {e['axis']}: passes only with a bias instability of at least "
                     f"{fmt(e['minimum_for_adequacy'], 3)} {e['minimum_unit']}{conv}; a static record of "
                     f"{math.ceil(e['record_minutes_needed']) if e['record_minutes_needed'] is not None else 'n/a'}"
                     f" min decides ({shown})")
        if sn.get("levels"):
            L.append("")
    srch = rep.get("open_search")
    if srch and srch.get("tests"):
        L.append("## Open search beyond the library (generic bases)")
        L.append("")
        L.append(f"{srch['method']}, family-wise level {srch['alpha']:g}.")
        L.append("")
        L.append("| sensor | axis | family | chi2 | dof | p (Holm) | |")
        L.append("|---|---|---|---|---|---|---|")
        for t in srch["tests"]:
            L.append(f"| {t['sensor']} | {t['axis'] or '--'} | {t['family']} | {fmt(t['chi2'])} | {t['dof']:.3g} | "
                     f"{fmt(t['p_holm'], 3)} | {'**structure left**' if t['significant'] else 'none'} |")
        L.append("")
    for key, title, line in (
            ("degenerate_candidates", "Candidates refused as degenerate explanations",
             lambda d: f"{d['key']}: {d['why']}"),
            ("not_confirmed", "Selected on the estimated noise, not confirmed on the measured noise (dropped)",
             lambda d: f"{d['key']}: p = {fmt(d['p_measured_noise'], 3)} on the measured noise"),
            ("form_alternatives", "Forms this path cannot tell apart",
             lambda r: f"{', '.join(r['replaces'])} or {r['alternative']} (BIC difference {r['delta_bic']:.3g}); "
                       f"to separate them: {r['experiment']}")):
        if rep.get(key):
            L += [f"## {title}", ""] + [f"- {line(d)}" for d in rep[key]] + [""]
    if rep.get("unexplained"):
        L.append("## Unexplained: where the rest of the misfit sits")
        L.append("")
        for u in rep["unexplained"]:
            L.append(f"- {u['name']}: RMS residual {fmt(u['rms_residual'])} {u['unit']} against a noise of "
                     f"{fmt(u['rms_noise'])} (excess {fmt(u['excess_rms'])}); best generic shape in time: "
                     f"{u['shape']} ({100 * u.get('explained_fraction', 0):.0f} % of it)")
        L.append("")
    L.append("## Where the misfit lives (base model)")
    L.append("")
    summ = rep.get("locate", {}).get("summary", [])
    L += [f"- {t}" for t in summ] if summ else ["- nothing stands out above the noise"]
    L.append("")
    L.append("## Found")
    L.append("")
    if not rep["found"]:
        L.append("Nothing: no candidate term passes the BIC and likelihood-ratio tests.")
    elif rep.get("bounds", {}).get("computed"):
        L.append("σ_CRB: the Cramér–Rao bound of the window reductions the diagnosis observes, under the noise it "
                 "measured, with the base parameters free (report.json: bounds); se / σ_CRB near 1 is efficient on "
                 "these observations.")
        L.append("")
    for f in rep["found"]:
        al = ", ".join(f"{a['key']} (dBIC {a['delta_bic_vs_found']:.1f})" for a in f["aliases"]) or "none"
        L.append(f"### {f['effect']} ({f['sensor']}), BIC gain {fmt(f['delta_bic'])}, LRT p = {fmt(f['p_lrt'], 3)}")
        L.append("")
        L.append(f"Aliases (fit as well, within {rep['settings']['alias_delta_bic']:g} of BIC, or signature angle < "
                 f"{rep['settings']['alias_angle_deg']:g} deg, or not separable by this path at the estimated "
                 f"magnitude: discrimination non-centrality < {rep['settings'].get('alias_noncentrality', 13):g}): "
                 f"{al}")
        L.append("")
        crb = bool(f["parameters"]) and "sigma_crb" in f["parameters"][0]
        L.append("| parameter | value | 95 % interval |" + (" se | σ_CRB | se / σ_CRB |" if crb else "") + " unit |")
        L.append("|---|---|---|" + ("---|---|---|" if crb else "") + "---|")
        for p in f["parameters"]:
            name = p["name"] + (f" ({p['standard']}: {p['definition']})" if p.get("standard") else "")
            crb_txt = fmt(p["sigma_crb"], 3) if p.get("sigma_crb") is not None else "not determined"
            bound = f" {fmt(p['se'], 3)} | {crb_txt} | {fmt(p.get('se_over_crb'), 3)} |" if crb else ""
            L.append(f"| {name} | {fmt(p['value'], 5)} | [{fmt(p['ci95'][0], 5)}, {fmt(p['ci95'][1], 5)}] |{bound} "
                     f"{p['unit']} |")
        if f.get("tau_s"):
            L.append(f"| tau (profiled) | {f['tau_s']:g} | -- |" + (" -- | -- | -- |" if crb else "") + " s |")
        if f.get("bounds_not_estimated"):
            L.append("")
            L.append("Held at zero by the diagnosis; σ_CRB were each estimated beside the others: " + "; ".join(
                f"{b['name']} {fmt(b['sigma_crb'], 3) if b['sigma_crb'] is not None else 'not determined'}"
                for b in f["bounds_not_estimated"]))
        internal = [p["internal_model_parameter"] for p in f["parameters"] if p.get("internal_model_parameter")]
        if internal:
            L.append("")
            L.append(f"Internal model parameter ({internal[0]['meaning']}): " + "; ".join(
                f"{q['name']} = {fmt(q['value'], 5)} [{fmt(q['ci95'][0], 5)}, {fmt(q['ci95'][1], 5)}] {q['unit']}"
                for q in internal))
        if f.get("undetermined_parameters"):
            L.append("")
            L.append("Not determined by this path: " + ", ".join(f["undetermined_parameters"]))
        L.append("")
    L.append("## Tested and absent (95 % upper bounds)")
    L.append("")
    if rep["absent"] is None:
        L.append("- not computed (setting absent_bounds: false)")
    for a in rep["absent"] or []:
        b = "; ".join(f"|{x['name']}| < {fmt(x['upper_bound_abs'], 3)} {x['unit']}" for x in a["upper_bound_95"])
        L.append(f"- {a['key']}: {b}")
    L.append("")
    L.append("## Untestable on this recording")
    L.append("")
    for u in rep["untestable"]:
        L.append(f"- **{u['key']}**: {u['why']}. Experiment that would make it testable: {u['experiment']}")
    L.append("")
    sep = rep.get("identifiability", {}).get("separations", [])
    if sep:
        L.append("## Separating look-alikes")
        L.append("")
        for s_ in sep:
            segs = ", ".join(f"{x['segment']} ({100 * x['share']:.0f} %)" for x in s_["separating_segments_latitude"])
            L.append(f"- {s_['pair'][0]} vs {s_['pair'][1]}: signature angle "
                     f"{fmt(s_['angle_deg_all_segments'], 3)} deg with every segment, "
                     f"{fmt(s_['angle_deg_rotation_means_only'], 3)} deg on the rotation means alone. Segments "
                     f"that separate them: {segs}")
            L.append(f"  {s_['note']}")
        L.append("")
    L.append("## Residual RMS (output units)")
    L.append("")
    L.append("| observation | before | after | unit |")
    L.append("|---|---|---|---|")
    for k, v in rep["residual_rms"]["before"].items():
        a = rep["residual_rms"]["after"].get(k, {})
        L.append(f"| {k} | {fmt(v['rms'])} | {fmt(a.get('rms'))} | {v['unit']} |")
    L.append("")
    mv = [b for b in rep["base_parameters"] if abs(b["moved_by_se"]) > 2]
    L.append("## Base parameters that moved by more than 2 standard errors")
    L.append("")
    L += [f"- {b['name']}: {fmt(b['before'], 8)} -> {fmt(b['after'], 8)} ({b['moved_by_se']:+.1f} se)" for b in mv] \
        or ["- none"]
    L.append("")
    if rep.get("figures"):
        L.append("## Figures")
        L.append("")
        L += [f"![{Path(f).stem}]({Path(f).name})" for f in rep["figures"]]
    return "\n".join(L) + "\n"


def unexplained_masks(prob: Problem, unexplained) -> list:
    """Where the report's ``unexplained[]`` sits, for the residual figure: one ``(name, observation indices)``.
    The entries that name a sensor axis (the rejected sensor-axis test, a structure of the open search) say where
    most precisely; the others (a segment class, a part of the session) only where no entry names an axis. Empty
    when nothing is unexplained."""
    from calib.diagnosis.adequacy import subset_masks   # the subsets the adequacy test judged

    o = prob.geom.obs
    groups = subset_masks(prob)
    named, broad = {}, {}
    for u in unexplained or ():
        m = groups.get(u.get("name"))
        axis = u.get("axis")
        if m is None and u.get("sensor") in SENSORS:
            m = np.asarray(o["sensor"]) == SENSORS.index(u["sensor"])
            if axis in AXES:
                m = m & (np.asarray(o["axis"]) == AXES.index(axis))
        if m is None or not np.any(m):
            continue
        where = f"{u.get('sensor', '')} {axis}".strip() if axis else str(u.get("name"))
        (named if axis else broad).setdefault(where, np.zeros(prob.n, bool))
        (named if axis else broad)[where] |= m
    use = named or broad
    if not use:
        return []
    return [(", ".join(use), np.flatnonzero(np.logical_or.reduce(list(use.values()))))]


def residual_data(prob: Problem, fits, title="", unexplained=()) -> dict:
    """What the residual figure shows, as plain data (:func:`calib.figures.diagnosis_plots.residual`); with the
    report's ``unexplained[]``, where each unexplained misfit sits."""
    o = prob.geom.obs
    base, final = fits
    return {"sensor": np.asarray(o["sensor"]), "row": np.asarray(o["row"]), "axis": np.asarray(o["axis"]),
            "window": np.asarray(o["window"]), "before": np.asarray(base.resid, float),
            "after": np.asarray(final.resid, float), "sigma": np.asarray(prob.sigma(), float),
            "labels": [w.label for w in prob.geom.windows], "kind": prob.kind, "sensors": SENSORS,
            "row_names": ROWS, "title": title, "unexplained": unexplained_masks(prob, unexplained)}


def allan_data(prob: Problem) -> list:
    """What the Allan figure shows, as plain data: one ``(sensor, arrays)`` per sensor the diagnosis has."""
    out = []
    for s in SENSORS:
        A = (prob.noise.allan.get(s) if prob.noise is not None else (prob.norm_allan if s == "accel" else None))
        if A is not None:
            out.append((s, {"tau": np.asarray(A.tau, float), "adev": np.asarray(A.adev, float),
                            "lo": np.asarray(A.lo, float), "hi": np.asarray(A.hi, float),
                            "edf": np.asarray(A.edf, float), "unit": A.unit, "confidence": float(A.confidence)}))
    return out


def residual_figure(prob: Problem, fits, path, title=""):
    """Standardised residuals (residual / sigma) per segment before and after, per sensor axis and row."""
    from calib.figures import diagnosis_plots as figs, style   # matplotlib with the project's rc settings: only when drawing

    return style.save(figs.residual(residual_data(prob, fits, title)), path)


def allan_figure(prob: Problem, path):
    """Allan deviation of the static segments per sensor, with its confidence band; only the sensors the
    diagnosis has (no blank panel); taus with fewer than 2 equivalent degrees of freedom are left out (their
    interval is wider than the plot)."""
    from calib.figures import diagnosis_plots as figs, style   # matplotlib with the project's rc settings: only when drawing

    return style.save(figs.allan(allan_data(prob)), path)


#: the figures of a report: file name, kind (:data:`calib.figures.diagnosis_plots.FIGURES`), data
def _figure_jobs(prob: Problem, fits, unexplained=()):
    return [("residuals_before_after.png", "residual", residual_data(prob, fits, unexplained=unexplained)),
            ("allan_deviation.png", "allan", allan_data(prob))]


def write_figures(prob: Problem, fits, out_dir, unexplained=()) -> list:
    """The report's figures in ``out_dir``, in the order of :func:`_figure_jobs`."""
    from calib.figures import diagnosis_plots as figs, style   # matplotlib with the project's rc settings: only when drawing

    out_dir = Path(out_dir)
    return [str(style.save(figs.FIGURES[kind](data), out_dir / name)) for name, kind, data in
            _figure_jobs(prob, fits, unexplained)]


def _report_header(path, st):
    return {"format": REPORT_FORMAT, "recording": str(path), "settings": {k: v for k, v in st.items()},
            "library": sorted({eid for eid in effects.REGISTRY})}


def inconclusive_report(path, st, reason, fix="") -> dict:
    rep = _report_header(path, st)
    rep.update({"verdict": "inconclusive", "verdict_reason": reason, "fix": fix, "explained": False,
                "unexplained": [], "found": [], "absent": [],
                "untestable": [], "figures": []})
    return rep


def build_report(prob: Problem, res: dict, path, st, figures_dir=None) -> dict:
    rep = _report_header(path, st)
    g = prob.geom
    rep.update({
        "source": str(prob.source_kind),
        "model": prob.kind,
        "model_description": (
            "vector model N = M x + b per triad (M = K E, Liu 2021 eqs. 1-4) with the inputs known from the nominal "
            "attitudes and the table rate/angle; 24 parameters, all identified"
            if prob.kind == "vector" else
            "accelerometer norm model (Liu 2021 eq. 7) in the identified lower-triangular form (9 parameters); "
            "the recording has no nominal attitudes, so only what the gravity norm sees can be tested"),
        "site": {"latitude_deg": g.latitude_deg, "height_m": g.height_m, "gravity_m_s2": g.gravity_m_s2,
                 "gravity_source": g.gravity_source},
        "observations": {"n": prob.n, "static_segments": len(g.static), "rotation_segments": len(g.rotation),
                         "units_out": g.units_out, "units_in": g.units_in, "notes": g.notes},
        "noise": _noise_summary(prob),
    })
    rep.update({k: v for k, v in res.items() if not k.startswith("_")})
    if st.get("report_detail", True):
        # the Cramer-Rao bound beside every estimate (not in the proof's per-seed runs, which score the verdict and
        # the findings only)
        rep["bounds"] = attach_bounds(prob, res["_fits"][1], rep["found"], rep["base_parameters"])
    figs = []
    if figures_dir is not None and st.get("figures", True):
        figs = write_figures(prob, res["_fits"], figures_dir, res.get("unexplained") or ())
    rep["figures"] = figs
    return rep


def _noise_summary(prob: Problem) -> dict:
    nz = prob.noise
    if nz is None:
        return {"method": prob.noise_method,
                "reduced_chi2_base": prob.overdispersion}
    out = {"method": nz.method, "per_sensor_axis": []}
    for s in SENSORS:
        for a in range(3):
            tc, sig = nz.slow[s][a]
            out["per_sensor_axis"].append({
                "sensor": s, "axis": AXES[a], "unit": nz.allan[s].unit, "N_white": float(nz.N[s][a]),
                "Q_quantisation": float(nz.Q[s][a]), "level_scale_from_residuals": float(nz.scale[s][a]),
                "slow": nz.describe(s, a), "slow_tc_s": None if math.isinf(tc) else tc, "slow_sigma": sig,
                "sigma_of_60s_mean_white": float(nz.N[s][a] / math.sqrt(60.0))})
    return out
