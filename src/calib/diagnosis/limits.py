"""Detection limits of the mismatch diagnosis on a recording's own noise (``calib diagnose FILE --limits``): known
effects injected into the recording's samples, diagnosed blind over block-resampled noise; the smallest magnitude
of each effect the diagnosis names.

A real recording has no truth sidecar: its true sensor model is unknown and may hold physics of its own. So the
untouched recording is diagnosed first (the *baseline*, :class:`ProofBase`); what it already holds is reported, and
a term it names is not counted against the injections. Then, for each repetition:

1. **noise resampled by blocks** (:meth:`ProofBase.resample`): in every static segment the samples are the segment
   mean plus the recording's own noise; the noise is replaced by a circular block bootstrap of itself (blocks of
   ``block_s`` seconds, so its autocorrelation within a block is kept). Samples outside the static segments are
   left as recorded. Each repetition is a new noise realisation around the recording's own segment means.
2. **an effect injected** (:meth:`ProofBase.inject`) through the physical transfer function of
   :mod:`calib.sim.physical` (a code path the diagnosis does not use): the accelerometer sensor-axis input is
   recovered with the model the recording's own norm calibration identifies (``y_i = (N_i - b_i) / K_i``,
   ``K_i = |row i of K E|``, :func:`norm_accel_model`), passed through ``h(y) = y + k2 y^2 + k3 y^3 + d |y|`` and
   mapped back (:func:`add_accel_term`). Out-of-library effects are added to the readings: a bias step at
   mid-session, a bias ramp over the session, a periodic bias.
3. **diagnosed blind** (:func:`calib.diagnosis.diagnose_dataset`), scored (:func:`score_injection`): an in-library
   effect is *named* when its key is found (alone or in its reported alias group); its injected axis is *covered*
   when the injected value lies inside the reported 95 % interval shifted by the baseline's estimate of the same
   parameter (the recording's own value of the term is unknown; the baseline estimates it).

Detection limit of an effect on one axis (:func:`detection_limits`): the smallest magnitude of a grid (multiples of
the baseline's standard error of that parameter) at which the effect is named in at least ``power`` of
``reps`` repetitions, and at every larger grid magnitude. An effect the recording cannot test (the baseline lists it
untestable, or the parameter is undetermined) is "not detectable at any magnitude", with the reason and the
experiment that would make it testable. Units: the registry's (ug/g^2, ug/g^3, ppm; biases in ug) inside, as
the injections use them. What a user reads (:func:`reported_limit`: the report, ``limits.csv``, the tables) gives
an asymmetry as the field's scale factor asymmetry ``scale_factor_asymmetry_ppm`` = (K+ - K-) / Kbar (IEEE Std 528 /
1293), twice the internal ``asym_ppm``, which is kept labelled as the internal model parameter.

The injection proof at twice these limits on the shared recordings is a study
(:mod:`calib.studies.real_proof`).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from calib.calibration import objectives as ob
from calib.core import seeds
from calib.core.progress import Progress
from calib.diagnosis.analysis import ASYMMETRY_FACTOR, ASYMMETRY_NAME, INTERNAL_ASYMMETRY, STANDARD_ASYMMETRY
from calib.diagnosis.geometry import TO_MODEL, rate_readings
from calib.diagnosis.problem import DEFAULT_SETTINGS, Problem
from calib.diagnosis.report import report_markdown
from calib.diagnosis.run import diagnose_dataset, load_for_diagnosis
from calib.io.atomic import write_json as write_json_atomic, write_text as write_text_atomic
from calib.sim import physical

AXES = ("x", "y", "z")
#: the accelerometer terms that can be injected into a recording (the physical transfer function of
#: :mod:`calib.sim.physical`) and a static-pose recording can test, and their size parameter (registry units)
ACCEL_TERMS = {"accel_quadratic_nonlinearity": "k2_ug_per_g2", "accel_cubic_nonlinearity": "k3_ug_per_g3",
               "accel_scale_asymmetry": "asym_ppm"}
IN_LIBRARY = ACCEL_TERMS
OUT_OF_LIBRARY = ("bias_step", "bias_ramp", "periodic_bias")
#: magnitudes tried for a detection limit, in baseline standard errors of the parameter
MULTIPLES = (2.0, 3.0, 4.0, 5.5, 7.5, 10.0, 14.0, 20.0)
#: sizes tried for an out-of-library effect, in standard errors of a static segment's mean
MULTIPLES_OUT = (5.0, 10.0, 20.0, 40.0, 80.0, 160.0, 320.0)
#: the consequences a diagnosis must never accept as an explanation
MAX_ABS_DELTA_G = 0.05          # m/s^2: more than geodesy allows for a surveyed site
MIN_CHI2_OVER_DOF = 0.01        # a chi-square collapsing toward 0 is a degenerate fit


def norm_accel_model(prob: Problem):
    """The accelerometer model the norm calibration ``prob`` identifies: ``(gain, b)`` per axis, gain = K_i conv
    (reading units per g of sensor-axis input; K_i = |row i of K E|), b the bias (reading units)."""
    M, b = ob.Form("tri9").KE_b(prob.base_theta)
    return np.linalg.norm(M, axis=1) * TO_MODEL[prob.geom.units_in["accel"]], b


def add_accel_term(y, gain, b, eid: str, values):
    """Rate readings ``y`` (n, 3) with the term ``eid`` of sizes ``values`` (3,) (registry units) added through
    the physical transfer function on the sensor-axis input u = (y - b) / gain: y + gain (h(u) - u)."""
    if eid not in ACCEL_TERMS:
        raise ValueError(f"inject: {eid!r} cannot be injected into a real recording; one of {sorted(ACCEL_TERMS)}")
    u = (y - b) / gain                                      # sensor-axis input [g]
    v = np.asarray(values, dtype=float) * 1e-6
    h = physical.transfer(u, *(v if eid == k else None for k in ACCEL_TERMS))
    return y + gain * (h - u)


def alias_keys(entry):
    """Library keys of a found term and of its reported aliases."""
    return {entry["key"]} | {a["key"] for a in entry.get("aliases", []) if "key" in a}


def _static_segments(ds):
    seg = np.asarray(ds["segment_index"].values)
    kinds = [str(k) for k in ds["segment_kind"].values]
    out = []
    for s, k in enumerate(kinds):
        if k != "static":
            continue
        idx = np.flatnonzero(seg == s)
        if idx.size >= 4:
            out.append(idx)
    return out


class ProofBase:
    """One recording prepared as a proof base: its baseline diagnosis, the accelerometer model its norm
    calibration identifies, and its static segments."""

    def __init__(self, ds, settings=None, name: str = ""):
        self.ds = ds
        self.name = name or str(ds.attrs.get("_path", "recording"))
        self.settings = {**DEFAULT_SETTINGS, **(settings or {}), "figures": False}
        self.baseline, self.prob = diagnose_dataset(ds, None, self.settings, path=f"{self.name} (untouched)")
        self.fs = float(ds.attrs["sample_rate_hz"])
        self.y = np.asarray(rate_readings(ds, "accel")[0], dtype=float)
        self.segments = _static_segments(ds)
        # reading units per g of sensor-axis input and bias, from the recording's own norm calibration
        self.gain, self.b = (norm_accel_model(self.prob) if self.prob is not None and self.prob.kind == "norm"
                             else (None, None))

    # ---------------------------------------------------------------------------------------------------------
    def baseline_value(self, effect: str, pname: str):
        """The baseline's estimate of a parameter (found or absent), 0 when it has none."""
        for f in self.baseline.get("found", []) + self.baseline.get("absent", []):
            if f["effect"] == effect:
                for p in (f.get("parameters") or f.get("upper_bound_95") or []):
                    p = p.get("internal_model_parameter", p)     # the registry's parameter (asym_ppm, not 2x)
                    if p["name"] == pname:
                        return float(p.get("value") or 0.0), p.get("se")
        return 0.0, None

    def untestable_reason(self, effect: str):
        """Why the baseline cannot test ``effect`` (None when it can), and the experiment that would."""
        key = f"{effect}/accel"
        for u in self.baseline.get("untestable", []):
            if u.get("key") == key:
                return u.get("why") or "untestable", u.get("experiment") or ""
        if self.gain is None and self.prob is not None and self.prob.kind == "vector":
            return ("detection limits are measured on static-pose recordings (norm model); a turntable session "
                    "with nominal attitudes has them from the proof's power scan"), \
                "run the diagnosis_proof rule with power_seeds > 0 on this session's configuration"
        if self.gain is None:
            return ("the recording gives no norm calibration to inject into: "
                    + str(self.baseline.get("verdict_reason", ""))[:300]), "record at least 12 static poses"
        return None

    # ---------------------------------------------------------------------------------------------------------
    def _blocks(self, block_s: float) -> list:
        """Per static segment: where it lies (a slice when its samples are contiguous), its length m, the block
        length L, the number of blocks, the offsets 0..L-1, the segment mean and the noise about it -- what every
        repetition of :meth:`resample` starts from (the untouched readings' own, computed once per block length)."""
        cache = self.__dict__.setdefault("_block_cache", {})
        if block_s not in cache:
            L0 = max(1, int(round(block_s * self.fs)))
            out = []
            for idx in self.segments:
                m = idx.size
                L = max(1, min(L0, m // 4))
                seg = self.y[idx]
                mean = seg.mean(axis=0)
                where = slice(int(idx[0]), int(idx[-1]) + 1) if idx[-1] - idx[0] == m - 1 else idx
                out.append((where, m, L, -(-m // L), np.arange(L)[None, :], mean, seg - mean))
            cache[block_s] = out
        return cache[block_s]

    def resample(self, rng, block_s: float = 1.0) -> np.ndarray:
        """Readings (n, 3) with every static segment's noise replaced by a circular block bootstrap of itself."""
        y = self.y.copy()
        for where, m, L, nb, offsets, mean, e in self._blocks(block_s):
            starts = rng.integers(0, m, size=nb)
            take = ((starts[:, None] + offsets) % m).reshape(-1)[:m]
            y[where] = mean + e[take]
        return y

    def inject(self, y: np.ndarray, spec: dict) -> np.ndarray:
        """Readings ``y`` with one effect added. ``spec``: ``{"effect": id, "axis": a, "value": v}`` for the library
        terms (registry units), or ``{"effect": "bias_step" | "bias_ramp" | "periodic_bias", "axis": a,
        "ug": size, "period_s": P}`` (size in ug of input)."""
        i = AXES.index(spec.get("axis", "x"))
        eff = spec["effect"]
        if eff in IN_LIBRARY:
            values = np.zeros(3)
            values[i] = float(spec["value"])
            return add_accel_term(np.asarray(y, dtype=float), self.gain, self.b, eff, values)
        out = np.array(y, dtype=float, copy=True)
        n = len(out)
        t = np.arange(n) / self.fs
        T = n / self.fs
        a = float(spec["ug"]) * 1e-6 * self.gain[i]
        if eff == "bias_step":
            out[:, i] += a * (t >= 0.5 * T)
        elif eff == "bias_ramp":
            out[:, i] += a * (t / T - 0.5)
        elif eff == "periodic_bias":
            out[:, i] += a * np.sin(2.0 * math.pi * t / float(spec.get("period_s", T / 3.0)))
        else:
            raise ValueError(f"real proof: unknown effect {eff!r}; one of {list(IN_LIBRARY) + list(OUT_OF_LIBRARY)}")
        return out

    def dataset(self, y: np.ndarray):
        """The recording with accelerometer readings ``y`` (rate readings; written back in the file's kind)."""
        ds = self.ds.copy()
        v = ds["accel"]
        vals = y / self.fs if v.attrs.get("sample_kind") == "increment" else y
        # the copy's own variable takes the samples (its dimensions and attributes kept; the recording's variable is
        # another object, untouched)
        v.data = np.asarray(vals, dtype=float)
        return ds

    def diagnose(self, y: np.ndarray, label: str):
        # the upper bounds of absent terms are read from the baseline only (baseline_value), not from a repetition;
        # the geometry is the baseline's (only the accelerometer samples differ: :meth:`dataset`)
        shared = self.prob if self.prob is not None and self.prob.kind == "norm" else None
        rep, _ = diagnose_dataset(self.dataset(y), None, {**self.settings, "absent_bounds": False},
                                  path=f"{self.name} {label}", library_from=None, geometry_from=shared)
        return rep


# =============================================================================================================
def score_injection(base: ProofBase, rep: dict, spec: dict) -> dict:
    """Named / covered / explained of one injected report (module docstring)."""
    eff = spec["effect"]
    found = rep.get("found", [])
    keys = set().union(*map(alias_keys, found))
    out = {"verdict": rep.get("verdict"), "explained": bool(rep.get("explained")),
           "found": [f["key"] for f in found], "degenerate_accepted": degenerate_accepted(rep)}
    if eff in IN_LIBRARY:
        out["named"] = f"{eff}/accel" in keys                       # alone or in its reported alias group
        out["named_exactly"] = any(f["key"] == f"{eff}/accel" for f in found)
        pname = f"{IN_LIBRARY[eff]}[{spec['axis']}]"
        b0, _ = base.baseline_value(eff, pname)
        out["covered"] = None
        for f in found:
            if f["effect"] == eff:
                for p in f["parameters"]:
                    p = p.get("internal_model_parameter", p)     # the registry's parameter (asym_ppm, not 2x)
                    if p["name"] == pname:
                        lo, hi = p["ci95"]
                        out["covered"] = bool(lo - b0 <= float(spec["value"]) <= hi - b0)
                        out["estimate_minus_baseline"] = float(p["value"]) - b0
    return out


def degenerate_accepted(rep: dict) -> list[str]:
    """What a report accepts as an explanation that no engineer would: a |delta g| above
    :data:`MAX_ABS_DELTA_G`, a chi-square after the fit below :data:`MIN_CHI2_OVER_DOF` of its degrees of
    freedom, a parameter reported on a bound."""
    bad = []
    for f in rep.get("found", []):
        for p in f.get("parameters", []):
            if f["effect"] == "gravity_error" and abs(float(p.get("value") or 0.0)) > MAX_ABS_DELTA_G:
                bad.append(f"{f['key']}: {p['name']} = {p['value']:.4g} m/s^2")
            if p.get("on_bound"):
                bad.append(f"{f['key']}: {p['name']} on a bound")
    after = (rep.get("goodness_of_fit") or {}).get("after") or {}
    if rep.get("found") and after.get("dof") and after.get("chi2") is not None:
        if float(after["chi2"]) < MIN_CHI2_OVER_DOF * float(after["dof"]):
            bad.append(f"chi2 {after['chi2']:.3g} on {after['dof']} dof")
    return bad


def _limit_of(points, power):
    """The smallest grid magnitude whose rate, and every larger one's, reaches ``power`` (None if none)."""
    ok = [p["rate"] >= power for p in points]
    for j in range(len(ok)):
        if all(ok[j:]):
            return points[j]["value"]
    return None


def detection_limits(base: ProofBase, reps: int = 20, power: float = 0.95, seed: int = 0, effects=None, axes=AXES,
                     block_s: float = 1.0, progress=True, out_of_library: bool = True) -> list[dict]:
    """Detection limits on ``base`` (module docstring): one row per library term and axis (``limit`` in registry
    units, the smallest magnitude *named* in >= ``power`` of ``reps`` repetitions, or None with ``why``), and, with
    ``out_of_library``, one row per out-of-library effect on each axis (``limit`` in ug: the smallest size whose
    misfit is *seen*, a verdict other than 'adequate', in >= ``power`` of the repetitions). Each row has its power
    curve ``points``."""
    rows = []
    effects = list(effects or IN_LIBRARY)
    todo = [(e, a) for e in effects for a in axes]
    # a baseline that already leaves misfit cannot show when an added one becomes visible
    todo_out = ([(e, a) for e in OUT_OF_LIBRARY for a in axes]
                if out_of_library and base.gain is not None and base.baseline.get("verdict") == "adequate" else [])
    if out_of_library and base.gain is not None and not todo_out:
        rows += [{"effect": e, "axis": a, "parameter": f"{e}[{a}] (ug)", "kind": "out_of_library", "points": [],
                  "limit": None, "detectable": False,
                  "why": f"not measurable here: the untouched recording is already '{base.baseline.get('verdict')}' "
                         f"({str(base.baseline.get('verdict_reason', ''))[:160]})"} for e in OUT_OF_LIBRARY for a in axes]
    bar = Progress((len(todo) * len(MULTIPLES) + len(todo_out) * len(MULTIPLES_OUT)) * reps, "detection limits",
                   every_s=1.0) if progress else None
    done = 0

    def tick():
        nonlocal done
        done += 1
        if bar:
            bar(done)

    for eff, ax in todo:
        pname = f"{IN_LIBRARY[eff]}[{ax}]"
        why = base.untestable_reason(eff)
        b0, se = base.baseline_value(eff, pname)
        row = {"effect": eff, "axis": ax, "parameter": pname, "kind": "library", "baseline_value": b0,
               "baseline_se": se, "points": []}
        if why is not None or se is None or not np.isfinite(se) or se <= 0:
            row.update(limit=None, detectable=False, why=(why[0] if why else "the parameter is not determined by "
                                                          "this recording's poses"),
                       experiment=(why[1] if why else "add static poses that turn this axis through +-1 g and 45 deg"))
            rows.append(row)
            for _ in range(len(MULTIPLES) * reps):
                tick()
            continue
        sign = 1.0 if b0 >= 0 else -1.0      # inject along the baseline's own sign: never cancel what is there
        for m in MULTIPLES:
            v = sign * m * float(se)
            named = 0
            for k in range(reps):
                rng = seeds.stream(seed, "real_proof", "limits", eff, ax, f"{m:g}", k)
                y = base.inject(base.resample(rng, block_s), {"effect": eff, "axis": ax, "value": v})
                named += score_injection(base, base.diagnose(y, f"+ {pname} = {v:.4g}"),
                                         {"effect": eff, "axis": ax, "value": v})["named"]
                tick()
            row["points"].append({"multiple_of_se": m, "value": v, "named": named, "n": reps, "rate": named / reps})
        row["limit"] = _limit_of(row["points"], power)
        row["detectable"] = row["limit"] is not None
        if row["limit"] is None:     # the largest magnitude tried as the user reads it (reported_limit)
            top = abs(row["points"][-1]["value"]) * (ASYMMETRY_FACTOR if eff in STANDARD_ASYMMETRY else 1.0)
            row["why"] = (f"not named in >= {power:.0%} of {reps} repetitions up to {MULTIPLES[-1]:g} standard errors "
                          f"({top:.4g})")
        rows.append(row)
    seg_se = _segment_mean_se(base) if todo_out else None
    for eff, ax in todo_out:
        row = {"effect": eff, "axis": ax, "parameter": f"{eff}[{ax}] (ug)", "kind": "out_of_library", "points": []}
        for m in MULTIPLES_OUT:
            v = m * seg_se[AXES.index(ax)]
            seen = 0
            for k in range(reps):
                rng = seeds.stream(seed, "real_proof", "limits", eff, ax, f"{m:g}", k)
                spec = out_of_library_spec(base, eff, ax, v)
                seen += base.diagnose(base.inject(base.resample(rng, block_s), spec),
                                      f"+ {eff} {ax} {v:.4g} ug").get("verdict") != "adequate"
                tick()
            row["points"].append({"multiple_of_segment_se": m, "value": v, "seen": seen, "n": reps,
                                  "rate": seen / reps})
        row["limit"] = _limit_of(row["points"], power)
        row["detectable"] = row["limit"] is not None
        if row["limit"] is None:
            row["why"] = f"its misfit is not seen up to {MULTIPLES_OUT[-1]:g} segment-mean standard errors"
        rows.append(row)
    return rows


def out_of_library_spec(base, eff, ax, size_ug):
    """The injection of an out-of-library effect of ``size_ug`` (ug of input) on axis ``ax``; a periodic bias has a
    third of the session as its period."""
    return {"effect": eff, "axis": ax, "ug": size_ug, "period_s": len(base.y) / base.fs / 3.0}


def _segment_mean_se(base: ProofBase) -> list[float]:
    """Median standard error of a static segment's mean per axis, in ug of input (white-noise estimate)."""
    out = []
    for i in range(3):
        s = [np.std(base.y[idx, i], ddof=1) / math.sqrt(idx.size) for idx in base.segments]
        out.append(float(np.median(s)) / base.gain[i] * 1e6)
    return out


def reported_limit(row: dict) -> dict:
    """One row of :func:`detection_limits` as a user reads it. An asymmetry term's row gives the field's scale factor
    asymmetry (K+ - K-) / Kbar (:data:`calib.diagnosis.analysis.STANDARD_ASYMMETRY`): parameter
    ``scale_factor_asymmetry_ppm[axis]``, and limit, baseline estimate, standard error and power-curve magnitudes
    twice the internal ``asym_ppm``'s, which are kept under ``internal_model_parameter``. Any other row, and a row
    already reported, is returned as it is."""
    eff = row.get("effect")
    if eff not in STANDARD_ASYMMETRY or eff not in IN_LIBRARY or row.get("kind") != "library" \
            or not str(row.get("parameter", "")).startswith(IN_LIBRARY[eff]):
        return row
    k = ASYMMETRY_FACTOR

    def std(v):
        return None if v is None else k * v

    return {**row, "parameter": row["parameter"].replace(IN_LIBRARY[eff], ASYMMETRY_NAME, 1),
            "limit": std(row.get("limit")), "baseline_value": std(row.get("baseline_value")),
            "baseline_se": std(row.get("baseline_se")),
            "points": [{**p, "value": k * p["value"]} for p in row.get("points", [])],
            "unit": "ppm", "quantity": "scale factor asymmetry", "standard": STANDARD_ASYMMETRY[eff],
            "internal_model_parameter": {"parameter": row["parameter"], "limit": row.get("limit"),
                                         "baseline_value": row.get("baseline_value"),
                                         "baseline_se": row.get("baseline_se"), "unit": "ppm",
                                         "meaning": INTERNAL_ASYMMETRY}}


def limits_markdown(limits, title="Detection limits on this recording") -> list[str]:
    """The limits table (also used by ``calib diagnose --limits``), each row as :func:`reported_limit` gives it."""
    L = [f"## {title}", "",
         "Smallest magnitude named in >= 95 % of block-resampled repetitions of this recording's own noise (library "
         "terms), or whose misfit is seen (out-of-library effects; ug of input). An asymmetry is the scale factor "
         f"asymmetry (K+ - K-) / Kbar of IEEE Std 528 / 1293 ({ASYMMETRY_NAME}, ppm). 'not detectable at any "
         "magnitude': why, and the experiment that would make it detectable.", "",
         "| effect | axis | parameter | limit | baseline estimate (se) | power curve (magnitude: detected/n) |",
         "|---|---|---|---|---|---|"]
    for r in map(reported_limit, limits):
        if r.get("limit") is not None:
            lim = f"{abs(r['limit']):.4g}"
        else:
            lim = "not detectable at any magnitude: " + str(r.get("why", "")) + (
                f" (experiment: {r['experiment']})" if r.get("experiment") else "")
        base = "" if r.get("baseline_se") is None else f"{r['baseline_value']:.4g} ({r['baseline_se']:.3g})"
        pts = ", ".join(f"{abs(p['value']):.3g}: {p.get('named', p.get('seen'))}/{p['n']}" for p in r["points"])
        L.append(f"| {r['effect']} | {r['axis']} | {r['parameter']} | {lim} | {base} | {pts} |")
    return L + [""]



def limits_into_report(path, out_dir, report: dict, settings=None, reps: int = 20, seed: int = 0, intervals=None,
                       intervals_source: str = "") -> dict:
    """``calib diagnose FILE --limits``: the detection limits of the recording at ``path`` (loaded as the diagnosis
    loads it) added to ``report`` as ``detection_limits`` and to ``out_dir``'s report.json / report.md (written
    atomically). A recording the diagnosis refused gets no limits; the report says why."""
    ds, refusal = load_for_diagnosis(path, settings, intervals, intervals_source, dataset=True)
    if refusal is not None:
        report = {**report, "detection_limits": {"rows": [], "why": refusal.get("verdict_reason")}}
    else:
        base = ProofBase(ds, settings, name=str(path))
        rows = detection_limits(base, reps=reps, seed=seed, progress=True)
        report = {**report, "detection_limits": {
            "rows": [reported_limit(r) for r in rows], "reps_per_magnitude": reps, "power": 0.95, "seed": seed,
            "method": "effects injected through calib.sim.physical's transfer function into block-resampled noise "
                      "of this recording (calib.diagnosis.limits)"}}
    if out_dir is not None:
        out_dir = Path(out_dir)
        write_json_atomic({k: v for k, v in report.items() if k != "elapsed_s"}, out_dir / "report.json")
        md = report_markdown(report)
        rows = report["detection_limits"]["rows"]
        md += "\n" + ("\n".join(limits_markdown(rows)) if rows else
                      f"## Detection limits\n\nnot measured: {report['detection_limits']['why']}\n")
        write_text_atomic(out_dir / "report.md", md)
    return report
