"""Scoring a diagnosis report against the truth sidecar of a synthetic session: the only place the truth is read
(the concealed-effect proof of :mod:`calib.studies.diagnosis_proof`)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calib.diagnosis import AXES
from calib.diagnosis.analysis import ASYMMETRY_FACTOR, ASYMMETRY_NAME
from calib.diagnosis.limits import alias_keys

def _truth_effects(truth) -> dict:
    """The ``effects`` of a truth sidecar (a path or its content)."""
    if isinstance(truth, (str, Path)):
        truth = json.loads(Path(truth).read_text())
    return dict(truth.get("effects") or {})


def truth_value(eff_params: dict, pname: str):
    """Truth value of a reported parameter name like 'k2_ug_per_g2[x]' or 'G_deg_h_per_g[x,y]'."""
    if "[" in pname:
        key, idx = pname[:-1].split("[")
        ii = tuple(AXES.index(a) for a in idx.split(","))
    else:
        key, ii = pname, ()
    factor = 1.0
    if key == ASYMMETRY_NAME:     # the standard scale factor asymmetry (K+ - K-) / Kbar: 2 x the registry's asym_ppm
        key, factor = "asym_ppm", ASYMMETRY_FACTOR
    if key not in eff_params:
        return None
    v = factor * np.asarray(eff_params[key], dtype=float)
    return float(v[ii]) if ii else float(v)


def registry_name(pname: str) -> str:
    """The simulator registry's name of a reported parameter (``scale_factor_asymmetry_ppm[x]`` -> ``asym_ppm[x]``;
    any other name as it is): what :mod:`calib.sim.fisher` names its bounds by."""
    return pname.replace(ASYMMETRY_NAME, "asym_ppm", 1) if pname.startswith(ASYMMETRY_NAME) else pname


def reported_bounds(bounds: dict) -> dict:
    """Fisher bounds keyed by registry name (:func:`calib.sim.fisher.bounds_from`) under the names the diagnosis
    reports: ``asym_ppm[x]`` becomes ``scale_factor_asymmetry_ppm[x]`` with twice its bound (the standard figure is
    2 asym_ppm)."""
    out = {}
    for nm, b in bounds.items():
        if nm.startswith("asym_ppm"):
            out[nm.replace("asym_ppm", ASYMMETRY_NAME, 1)] = None if b is None else ASYMMETRY_FACTOR * b
        else:
            out[nm] = b
    return out


#: effects acting on both triads: each half is a key of its own (``effect/accel``, ``effect/gyro``)
BOTH_TRIADS = ("bias_drift", "temperature_sensitivity")
SHAPE_KEYS = ("_tau_s", "T_ref_degC")


def injected_keys(eff_params: dict) -> set:
    """The library keys the truth holds: ``effect/sensor`` for the sensor effects (each triad of the effects of
    both triads only when one of its size parameters is non-zero), the effect id for the site and clock."""
    out = set()
    for eid, p in eff_params.items():
        if eid.startswith("accel_"):
            out.add(f"{eid}/accel")
        elif eid.startswith("gyro_"):
            out.add(f"{eid}/gyro")
        elif eid in BOTH_TRIADS:
            for sensor in ("accel", "gyro"):
                if any(np.any(np.asarray(v, float) != 0.0) for k, v in p.items()
                       if k.startswith(sensor + "_") and not k.endswith(SHAPE_KEYS)):
                    out.add(f"{eid}/{sensor}")
        else:
            out.add(eid)
    return out


def alias_group(entry):
    """Effect ids of a found term and of its reported aliases."""
    return {entry["effect"]} | {a["effect"] for a in entry.get("aliases", [])}


def score(report: dict, truth_sidecar, kind: str | None = None) -> dict:
    """Compare a diagnosis report with the truth sidecar of the session.

    ``kind``: 'null' | 'single' | 'confounded' | 'unmodelled' (default: 'null' without effects, else 'single').
    'unmodelled' (physics outside the library): correct when the report is not ``explained`` or discloses a rival
    form (``form_alternatives``).
    Returns: ``correct`` (null: nothing found; single: the injected effect named, alone or within the reported
    alias group; confounded: never attributed to one effect -- every finding names a group that holds the
    injected effect, or nothing is found and the effect is listed as untestable), ``named_exactly``,
    ``false_discoveries`` (findings whose group holds no injected effect), per-parameter ``coverage`` (truth
    inside the reported 95 % interval) for the exactly named effect, ``chi2_after_p``."""
    eff = _truth_effects(truth_sidecar)
    injected = set(eff)
    kind = kind or ("null" if not injected else "single")
    found = report.get("found", [])
    false_disc = [f["key"] for f in found if not (alias_group(f) & injected)]
    res = {"kind": kind, "injected": sorted(injected), "found": [f["key"] for f in found],
           "verdict": report.get("verdict"), "explained": bool(report.get("explained")),
           "false_discoveries": false_disc,
           "chi2_before": report.get("goodness_of_fit", {}).get("before", {}).get("chi2"),
           "chi2_after": report.get("goodness_of_fit", {}).get("after", {}).get("chi2"),
           "chi2_after_p": report.get("goodness_of_fit", {}).get("after", {}).get("p"), "coverage": []}
    if kind == "unmodelled":
        # physics outside the library: right when the data are not called explained, or when what was found
        # comes with its rival form disclosed (the experiment that separates them named)
        res["correct"] = (not res["explained"]) or bool(report.get("form_alternatives"))
        res["false_discoveries"] = []
        res["named_exactly"] = False
        res["unmodelled"] = [e.get("effect") for e in (truth_sidecar.get("unmodelled", []) if isinstance(
            truth_sidecar, dict) else [])]
        return res
    if kind == "null":
        res["correct"] = len(found) == 0
        res["named_exactly"] = res["correct"]
        return res
    if kind == "confounded":
        untest = {u["effect"] for u in report.get("untestable", [])}
        mine = [f for f in found if alias_group(f) & injected]
        # attributed to one effect: a finding that names an injected effect without naming its alias group
        res["attributed_to_one"] = any(len(alias_group(f)) == 1 for f in mine)
        res["correct"] = bool(not res["attributed_to_one"] and (mine or (injected & untest)))
        res["named_group"] = any(len(alias_group(f)) >= 2 and (alias_group(f) & injected) for f in found)
        res["listed_untestable"] = bool(injected & untest)
        res["named_exactly"] = False
        return res
    # exact per sensor: every injected key named (alone or in its reported alias group), and a finding on a triad
    # the truth leaves untouched is a false discovery
    keys = injected_keys(eff)
    res["injected_keys"] = sorted(keys)
    res["false_discoveries"] = [f["key"] for f in found if not (alias_keys(f) & keys)]
    named = set().union(*[alias_keys(f) for f in found]) if found else set()
    res["correct"] = keys <= named
    exact = [f for f in found if f["key"] in keys]
    res["named_exactly"] = {f["key"] for f in exact} == keys
    for f in exact:
        for p in f["parameters"]:
            tv = truth_value(eff[f["effect"]], p["name"])
            if tv is None:
                continue
            res["coverage"].append({"key": f["key"], "name": p["name"], "truth": tv, "value": p["value"],
                                    "ci95": p["ci95"], "covered": bool(p["ci95"][0] <= tv <= p["ci95"][1]),
                                    "se": p.get("se")})
    return res


# =====================================================================================================
