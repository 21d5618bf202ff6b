"""Real recordings as proof bases of the mismatch diagnosis: known effects injected into a real sensor's samples,
diagnosed blind over block-resampled noise; detection limits per recording; the proof at twice those limits.

A real recording has no truth sidecar: its true sensor model is unknown and may hold physics of its own. So the
untouched recording is diagnosed first (the *baseline*); what it already holds is reported, and a term it names is
not counted against the injections. Then, for each repetition:

1. **noise resampled by blocks** (:meth:`ProofBase.resample`): in every static segment the samples are the segment
   mean plus the recording's own noise; the noise is replaced by a circular block bootstrap of itself (blocks of
   ``block_s`` seconds, so its autocorrelation within a block is kept). Samples outside the static segments are
   left as recorded. Each repetition is a new noise realisation around the recording's own segment means.
2. **an effect injected** (:meth:`ProofBase.inject`) through the physical transfer function of
   :mod:`calib.sim.physical` (a code path the diagnosis does not use): the accelerometer sensor-axis input is
   recovered with the model the recording's own norm calibration identifies (``y_i = (N_i - b_i) / K_i``,
   ``K_i = |row i of K E|``), passed through ``h(y) = y + k2 y^2 + k3 y^3 + d |y|`` and mapped back. Out-of-library
   effects are added to the readings: a bias step at mid-session, a bias ramp over the session, a periodic bias.
3. **diagnosed blind** (:func:`calib.diagnosis.diagnose_dataset`), scored: an in-library effect is *named* when
   its key is found (alone or in its reported alias group); its injected axis is *covered* when the injected value
   lies inside the reported 95 % interval shifted by the baseline's estimate of the same parameter (the recording's
   own value of the term is unknown; the baseline estimates it).

Detection limit of an effect on one axis (:func:`detection_limits`): the smallest magnitude of a grid (multiples of
the baseline's standard error of that parameter) at which the effect is named in at least ``power`` of
``reps`` repetitions, and at every larger grid magnitude. An effect the recording cannot test (the baseline lists it
untestable, or the parameter is undetermined) is "not detectable at any magnitude", with the reason and the
experiment that would make it testable. Units: the registry's (ug/g^2, ug/g^3, ppm; biases in ug).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy import stats

from calib.core import seeds
from calib.core.errors import ResultCheckError
from calib.core.progress import Progress
from calib.diagnosis import DEFAULT_SETTINGS, diagnose_dataset, rate_readings
from calib.io.atomic import write_json as write_json_atomic, write_text as write_text_atomic
from calib.studies.diagnosis_real import ACCEL_TERMS, add_accel_term, import_real, norm_accel_model
from calib.studies.diagnosis_score import alias_keys

AXES = ("x", "y", "z")
#: the library's accelerometer terms a static-pose recording can test, and their size parameter
IN_LIBRARY = ACCEL_TERMS
OUT_OF_LIBRARY = ("bias_step", "bias_ramp", "periodic_bias")
#: magnitudes tried for a detection limit, in baseline standard errors of the parameter
MULTIPLES = (2.0, 3.0, 4.0, 5.5, 7.5, 10.0, 14.0, 20.0)
#: sizes tried for an out-of-library effect, in standard errors of a static segment's mean
MULTIPLES_OUT = (5.0, 10.0, 20.0, 40.0, 80.0, 160.0, 320.0)
#: the consequences a diagnosis must never accept as an explanation
MAX_ABS_DELTA_G = 0.05          # m/s^2: more than geodesy allows for a surveyed site
MIN_CHI2_OVER_DOF = 0.01        # a chi-square collapsing toward 0 is a degenerate fit


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
    def resample(self, rng, block_s: float = 1.0) -> np.ndarray:
        """Readings (n, 3) with every static segment's noise replaced by a circular block bootstrap of itself."""
        y = self.y.copy()
        L0 = max(1, int(round(block_s * self.fs)))
        for idx in self.segments:
            m = idx.size
            L = max(1, min(L0, m // 4))
            seg = self.y[idx]
            mean = seg.mean(axis=0)
            e = seg - mean
            nb = -(-m // L)
            starts = rng.integers(0, m, size=nb)
            take = ((starts[:, None] + np.arange(L)[None, :]) % m).reshape(-1)[:m]
            y[idx] = mean + e[take]
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
        ds["accel"] = (v.dims, np.asarray(vals, dtype=float), v.attrs)
        return ds

    def diagnose(self, y: np.ndarray, label: str):
        # the upper bounds of absent terms are read from the baseline only (baseline_value), not from a repetition
        rep, _ = diagnose_dataset(self.dataset(y), None, {**self.settings, "absent_bounds": False},
                                  path=f"{self.name} {label}", library_from=None)
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
        if row["limit"] is None:
            row["why"] = (f"not named in >= {power:.0%} of {reps} repetitions up to {MULTIPLES[-1]:g} standard errors "
                          f"({abs(row['points'][-1]['value']):.4g})")
        rows.append(row)
    seg_se = _segment_mean_se(base) if todo_out else None
    for eff, ax in todo_out:
        row = {"effect": eff, "axis": ax, "parameter": f"{eff}[{ax}] (ug)", "kind": "out_of_library", "points": []}
        for m in MULTIPLES_OUT:
            v = m * seg_se[AXES.index(ax)]
            seen = 0
            for k in range(reps):
                rng = seeds.stream(seed, "real_proof", "limits", eff, ax, f"{m:g}", k)
                spec = _out_spec(base, eff, ax, v)
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


def _out_spec(base, eff, ax, size_ug):
    return {"effect": eff, "axis": ax, "ug": size_ug, "period_s": len(base.y) / base.fs / 3.0}


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
            spec = _out_spec(base, r["effect"], r["axis"], v)
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


def _segment_mean_se(base: ProofBase) -> list[float]:
    """Median standard error of a static segment's mean per axis, in ug of input (white-noise estimate)."""
    out = []
    for i in range(3):
        s = [np.std(base.y[idx, i], ddof=1) / math.sqrt(idx.size) for idx in base.segments]
        out.append(float(np.median(s)) / base.gain[i] * 1e6)
    return out


def acceptance(res: dict) -> dict:
    """The acceptance criteria of a real-recording proof base on one recording."""
    lib = res["in_library"]

    def consistent(r):   # the 99 % Clopper-Pearson interval of the coverage holds 0.95 (or it is above)
        if r["coverage_n"] < 20:   # named mostly through its alias group: too few intervals to test
            return True
        k, n = round(r["coverage"] * r["coverage_n"]), r["coverage_n"]
        hi = 1.0 if k == n else float(stats.beta.ppf(0.995, k + 1, n - k))
        return hi >= 0.95

    return {"named_ge_95pct": all(r["named_rate"] >= 0.95 for r in lib) if lib else None,
            "coverage_consistent_with_95pct": all(consistent(r) for r in lib) if lib else None,
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
    out = {"format": "calib-real-proof-1", "seed": seed, "reps_per_magnitude": reps, "n_inject": n_inject,
           "n_out": n_out, "factor_of_limit": factor, "recordings": results}
    write_json_atomic(out, out_dir / "real_proof.json")
    write_text_atomic(out_dir / "limits.csv", limits_csv(results))
    write_text_atomic(out_dir / "real_proof.md", real_proof_md(out))
    limits_figure(results, out_dir / "limits.png")
    log((out_dir / "real_proof.md").read_text())
    failed = [f"{r['recording']}: {k}" for r in results if r.get("usable")
              for k, v in r["acceptance"].items() if v is False]
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


def limits_csv(results) -> str:
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


def limits_markdown(limits, title="Detection limits on this recording") -> list[str]:
    """The limits table (also used by ``calib diagnose --limits``)."""
    L = [f"## {title}", "",
         "Smallest magnitude named in >= 95 % of block-resampled repetitions of this recording's own noise (library "
         "terms), or whose misfit is seen (out-of-library effects; ug of input). 'not detectable at any magnitude': "
         "why, and the experiment that would make it detectable.", "",
         "| effect | axis | limit | baseline estimate (se) | power curve (magnitude: detected/n) |", "|---|---|---|---|---|"]
    for r in limits:
        if r.get("limit") is not None:
            lim = f"{abs(r['limit']):.4g}"
        else:
            lim = "not detectable at any magnitude: " + str(r.get("why", "")) + (
                f" (experiment: {r['experiment']})" if r.get("experiment") else "")
        base = "" if r.get("baseline_se") is None else f"{r['baseline_value']:.4g} ({r['baseline_se']:.3g})"
        pts = ", ".join(f"{abs(p['value']):.3g}: {p.get('named', p.get('seen'))}/{p['n']}" for p in r["points"])
        L.append(f"| {r['effect']} | {r['axis']} | {lim} | {base} | {pts} |")
    return L + [""]


def real_proof_md(out) -> str:
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
                L.append(f"| {q['effect']} ({', '.join(f'{a}: {v:.4g}' for a, v in q['values'].items())}) | {q['n']} | "
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
    return "\n".join(L) + "\n"


def limits_figure(results, path):
    """Power curves of the library terms on each usable recording: fraction named against the injected magnitude
    in baseline standard errors."""
    import matplotlib.pyplot as plt

    from calib.figures import style as figures

    use = [r for r in results if any(L.get("points") and L["kind"] == "library" for L in r.get("limits", []))]
    n = max(1, len(use))
    fig, axes = plt.subplots(1, n, figsize=(3.2 * n + 0.6, 3.0), squeeze=False, sharey=True)
    for ax, r in zip(axes[0], use):
        for j, L in enumerate(q for q in r["limits"] if q["kind"] == "library" and q.get("points")):
            x = [p["multiple_of_se"] for p in L["points"]]
            y = [p["rate"] for p in L["points"]]
            ax.plot(x, y, marker="o", ms=3, lw=1, color=f"C{j % 10}",
                    label=f"{L['parameter'].split('_')[0]} {L['axis']}" if ax is axes[0][0] else None)
        ax.axhline(0.95, color="k", lw=0.8, ls=":")
        ax.set_xscale("log")
        figures.plain_log_ticks(ax, "x")
        ax.set_title(r["recording"], fontsize=9)
        ax.set_xlabel("injected / baseline se")
    axes[0][0].set_ylabel("fraction named")
    if use:
        axes[0][0].legend(fontsize=6, loc="lower right")
    fig.tight_layout()
    return figures.save(fig, path)


def limits_into_report(path, out_dir, report: dict, settings=None, reps: int = 20, seed: int = 0, intervals=None,
                       intervals_source: str = "") -> dict:
    """``calib diagnose FILE --limits``: the detection limits of the recording at ``path`` (loaded as the diagnosis
    loads it) added to ``report`` as ``detection_limits`` and to ``out_dir``'s report.json / report.md (written
    atomically). A recording the diagnosis refused gets no limits; the report says why."""
    from calib.diagnosis import load_for_diagnosis, report_markdown

    ds, refusal = load_for_diagnosis(path, settings, intervals, intervals_source, dataset=True)
    if refusal is not None:
        report = {**report, "detection_limits": {"rows": [], "why": refusal.get("verdict_reason")}}
    else:
        base = ProofBase(ds, settings, name=str(path))
        rows = detection_limits(base, reps=reps, seed=seed, progress=True)
        report = {**report, "detection_limits": {
            "rows": rows, "reps_per_magnitude": reps, "power": 0.95, "seed": seed,
            "method": "effects injected through calib.sim.physical's transfer function into block-resampled noise "
                      "of this recording (calib.studies.real_proof)"}}
    if out_dir is not None:
        out_dir = Path(out_dir)
        write_json_atomic({k: v for k, v in report.items() if k != "elapsed_s"}, out_dir / "report.json")
        md = report_markdown(report)
        rows = report["detection_limits"]["rows"]
        md += "\n" + ("\n".join(limits_markdown(rows)) if rows else
                      f"## Detection limits\n\nnot measured: {report['detection_limits']['why']}\n")
        write_text_atomic(out_dir / "report.md", md)
    return report
