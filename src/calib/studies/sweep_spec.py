"""Sweep files: reading and validating one, its grid of points (a :class:`snakemake.utils.Paramspace`), and the study
config of each point and of each synthetic session -- what the workflow needs when it parses its rules
(``workflow/rules/sweeps.smk``), so this module imports no numerical library: the Snakefile is parsed in every
``snakemake`` process (with a cluster executor, once per job). What a point computes is in
:mod:`calib.studies.sweeps`, which re-exports these names.
"""
from __future__ import annotations

import copy
import itertools
from dataclasses import dataclass, field
from pathlib import Path

import jsonschema
import yaml

from calib.core.seeds import session_seed

KINDS = ("calibration", "drift_pso")
PROBLEMS = ("accel", "gyro_static", "gyro_dynamic")


class SweepError(ValueError):
    """A sweep file that cannot be run; the message names the file, the field and the fix."""


# ---------------------------------------------------------------------------------------------------------
# sweep parameters: name -> how a value enters the study config
# ---------------------------------------------------------------------------------------------------------
def _set(*keys):
    def apply(cfg, v):
        d = cfg
        for k in keys[:-1]:
            d = d.setdefault(k, {})
        d[keys[-1]] = v
    return apply


def _scale_cal_noise(cfg, s):
    n = cfg["calibration_session"].setdefault("noise", {})
    for k in ("accel_vrw_ug_rthz", "accel_bias_instability_ug", "gyro_arw_deg_rth", "gyro_bias_instability_deg_h"):
        if k in n:
            n[k] = n[k] * s


def _scale_nav_noise(cfg, s):
    ns = cfg["navigation_session"]
    gn = ns.setdefault("gyro_noise", {})
    for k in ("arw_deg_rth", "white_deg_h"):
        if k in gn:
            gn[k] = gn[k] * s
    if "accel_vrw_ug_rthz" in ns:
        ns["accel_vrw_ug_rthz"] = ns["accel_vrw_ug_rthz"] * s


def _window(cfg, v):
    cfg["drift"]["window_h"] = v


@dataclass(frozen=True)
class Parameter:
    name: str
    data: bool  # True: changes the synthetic session
    apply: object  # (cfg, value) -> None
    doc: str


#: the sweep parameters of each kind, in path order (data parameters first). Keep in step with
#: workflow/schemas/sweep.schema.yaml (tests/studies/test_sweeps.py checks it).
PARAMETERS = {
    "calibration": [
        Parameter("noise_scale", True, _scale_cal_noise, "factor on the 4 noise sigmas of calibration_session.noise"),
        Parameter("seed", True, _set("seeds", "data"), "noise realisation of the session (root seeds.data)"),
        Parameter("dwell_s", True, _set("calibration_session", "dwell_s"), "dwell per static position [s]"),
        Parameter("method", False, _set("sweep", "method"), "optimiser (calibration.methods names); default ide"),
        Parameter("problem", False, _set("sweep", "problem"), "accel | gyro_static | gyro_dynamic; default accel"),
        Parameter("NP", False, _set("calibration", "NP"), "population size"),
        Parameter("EG", False, _set("calibration", "EG"), "generations"),
        Parameter("runs", False, _set("calibration", "runs"), "independent optimiser runs per point"),
    ],
    "drift_pso": [
        Parameter("noise_scale", True, _scale_nav_noise, "factor on navigation_session gyro (and accel) noise"),
        Parameter("seed", True, _set("seeds", "data"), "noise realisation of the session (root seeds.data)"),
        Parameter("window_h", True, _window, "estimation window = simulated session length [h]"),
        Parameter("variant", False, _set("drift", "pso", "variant"), "paper | standard"),
        Parameter("particles", False, _set("drift", "pso", "particles"), "swarm size"),
        Parameter("generations", False, _set("drift", "pso", "generations"), "PSO generations"),
        Parameter("tests", False, _set("drift", "tests"), "PSOBE runs per point"),
    ],
}
SWEEP_DEFAULTS = {"calibration": {"method": "ide", "problem": "accel"}, "drift_pso": {}}
#: study-config sections a point of each kind reads (what goes into its params, hence its rerun trigger)
SECTIONS = {"calibration": ("seeds", "site", "calibration_session", "calibration"),
            "drift_pso": ("seeds", "site", "navigation_session", "drift")}


def parameter_names(kind: str) -> list[str]:
    return [p.name for p in PARAMETERS[kind]]


def deep_merge(base: dict, over: dict) -> dict:
    """``base`` updated recursively by ``over`` (dicts merged, everything else replaced); copies."""
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _py(v):
    """numpy/pandas scalars -> plain Python (params must serialise and compare stably)."""
    return v.item() if hasattr(v, "item") else v


def _fmt_error(path: str, err) -> str:
    where = ".".join(str(p) for p in err.absolute_path)
    return f"{path}: {where or '(top level)'}: {err.message}"


# ---------------------------------------------------------------------------------------------------------
# the sweep
# ---------------------------------------------------------------------------------------------------------
@dataclass
class Sweep:
    """A validated sweep file, its points as a Paramspace, and the study config of each point."""

    path: str
    name: str
    kind: str
    description: str
    base: dict
    fixed: dict
    grid: dict
    study: dict  # study config with ``base`` merged (validated against the study schema)
    columns: list = field(default_factory=list)
    data_columns: list = field(default_factory=list)
    paramspace: object = None
    sessionspace: object = None
    _points: dict = field(default_factory=dict)
    _sessions: dict = field(default_factory=dict)

    def __post_init__(self):
        import pandas as pd
        from snakemake.utils import Paramspace

        self.columns = [p.name for p in PARAMETERS[self.kind] if p.name in self.grid]
        self.data_columns = [p.name for p in PARAMETERS[self.kind] if p.data and p.name in self.grid]
        rows = list(itertools.product(*(self.grid[c] for c in self.columns)))
        df = pd.DataFrame(rows, columns=self.columns)
        self.paramspace = Paramspace(df, filename_params="*", single_wildcard="point")
        self._points = {p: {c: _py(v) for c, v in zip(self.columns, row)}
                        for p, row in zip(self.paramspace.instance_patterns, rows)}
        if self.data_columns:
            sdf = df[self.data_columns].drop_duplicates().reset_index(drop=True)
        else:  # nothing about the data is swept: one session for all points
            sdf = pd.DataFrame({"session": ["base"]})
        self.sessionspace = Paramspace(sdf, filename_params="*", single_wildcard="session")
        self._sessions = {s: {c: _py(v) for c, v in zip(sdf.columns, row)}
                          for s, row in zip(self.sessionspace.instance_patterns, sdf.itertuples(index=False))}

    # ---- points ----
    @property
    def points(self) -> list[str]:
        """Point wildcards (Paramspace instance patterns), in grid order."""
        return list(self._points)

    @property
    def sessions(self) -> list[str]:
        return list(self._sessions)

    def values(self, point: str) -> dict:
        """Swept values of one point (by its wildcard)."""
        try:
            return dict(self._points[point])
        except KeyError:
            raise SweepError(f"{self.path}: {point!r} is not a point of sweep {self.name!r}") from None

    def session_of(self, point: str) -> str:
        v = self.values(point)
        if not self.data_columns:
            return self.sessions[0]
        key = {c: v[c] for c in self.data_columns}
        for s, sv in self._sessions.items():
            if sv == key:
                return s
        raise SweepError(f"{self.path}: no session for point {point!r}")  # pragma: no cover - by construction

    def point_config(self, point: str) -> dict:
        """Study sections read by a point (base, fixed and swept values applied) plus ``sweep`` settings."""
        vals = {**self.fixed, **self.values(point)}
        return self._config(vals)

    def session_config(self, session: str) -> dict:
        """What the session rule needs: the session section, the site and the data seed."""
        try:
            vals = {k: v for k, v in self._sessions[session].items() if k != "session"}
        except KeyError:
            raise SweepError(f"{self.path}: {session!r} is not a session of sweep {self.name!r}") from None
        cfg = self._config({**{k: v for k, v in self.fixed.items() if self._is_data(k)}, **vals})
        key = "calibration_session" if self.kind == "calibration" else "navigation_session"
        return {"kind": self.kind, "session": cfg[key], "site": cfg["site"],
                "seed": session_seed(cfg["seeds"]["data"], key)}

    def _is_data(self, name):
        return any(p.name == name and p.data for p in PARAMETERS[self.kind])

    def _config(self, vals: dict) -> dict:
        cfg = {k: copy.deepcopy(self.study[k]) for k in SECTIONS[self.kind] if k in self.study}
        cfg["sweep"] = dict(SWEEP_DEFAULTS[self.kind])
        for p in PARAMETERS[self.kind]:
            if p.name in vals:
                p.apply(cfg, vals[p.name])
        if self.kind == "drift_pso":  # simulate exactly the estimation window
            cfg["navigation_session"]["duration_h"] = cfg["drift"]["window_h"]
        return cfg


def load(path, study: dict, sweep_schema, study_schema=None) -> Sweep:
    """Read and validate a sweep file against ``sweep_schema`` (and the merged study config against
    ``study_schema`` when given). Raises :class:`SweepError` naming the file, the field and the fix."""
    path = str(path)
    p = Path(path)
    if not p.is_file():
        raise SweepError(f"sweep file {path!r} not found -- fix: check the `sweeps:` list of the study config")
    try:
        doc = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise SweepError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(doc, dict):
        raise SweepError(f"{path}: expected a mapping with name, kind and grid")
    kind = doc.get("kind")
    if kind in PARAMETERS:  # name unknown parameters first, with the list of known ones
        known = parameter_names(kind)
        for section in ("grid", "fixed"):
            sec = doc.get(section) or {}
            if isinstance(sec, dict):
                for k in sec:
                    if k not in known:
                        raise SweepError(f"{path}: {section}.{k}: unknown sweep parameter {k!r} for kind {kind!r} "
                                         f"-- fix: use one of {', '.join(known)}")
    schema = yaml.safe_load(Path(sweep_schema).read_text())
    errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(doc), key=lambda e: list(e.absolute_path))
    if errors:
        raise SweepError("; ".join(_fmt_error(path, e) for e in errors[:5]))
    grid, fixed = doc["grid"], doc.get("fixed") or {}
    both = sorted(set(grid) & set(fixed))
    if both:
        raise SweepError(f"{path}: {', '.join(both)} both swept (grid) and fixed -- fix: keep one")
    base = doc.get("base") or {}
    merged = deep_merge(study, base)
    merged.pop("sweeps", None)
    if study_schema is not None:
        sschema = yaml.safe_load(Path(study_schema).read_text())
        errs = list(jsonschema.Draft202012Validator(sschema).iter_errors(merged))
        if errs:
            raise SweepError("; ".join(f"{path}: base." + _fmt_error(path, e).split(": ", 1)[1] for e in errs[:5]))
    return Sweep(path, doc["name"], kind, doc.get("description", ""), base, fixed, grid, merged)


def load_all(paths, study: dict, sweep_schema, study_schema=None) -> dict:
    """name -> Sweep for the study's ``sweeps:`` list; refuses two sweeps of the same name."""
    out = {}
    for p in paths or []:
        s = load(p, study, sweep_schema, study_schema)
        if s.name in out:
            raise SweepError(f"{p}: sweep name {s.name!r} already used by {out[s.name].path} -- fix: rename one")
        out[s.name] = s
    return out
