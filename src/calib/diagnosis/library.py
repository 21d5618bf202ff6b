"""The effect library of the mismatch diagnosis: candidate terms and their signatures.

Each candidate is a term of :mod:`calib.sim.effects` (ids verbatim) with its own parameters in the registry's
units. Its *signature* is the derivative of the predicted observations with respect to those parameters at
the base solution: the registry's own term evaluated at the window samples with unit parameters, times the
scale factor K_i, reduced like the data (:mod:`calib.diagnosis.geometry`). Truth effects: ``latitude_error``
and ``gravity_error`` by central differences of the base prediction; ``time_offset`` exactly as a function
of the offset (the IMU sample at t measures the table motion at t + offset: the table angle is re-evaluated
on a spline of the recorded angle, including the neighbouring spin-up / spin-down) on a grid, interpolated
by cubic splines (:class:`OffsetModel`).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from calib.diagnosis.geometry import (AXES, SENSORS, TO_MODEL, Geometry, Window, offset_grid_inputs, reduced_inputs,
                                      rows_of, stack_fast, window_inputs)
from calib.sim import effects

#: bias-drift warm-up time constants tried (profile likelihood over a grid) [s]
DRIFT_TAUS = (120.0, 300.0, 600.0, 900.0, 1200.0, 1800.0, 2700.0, 3600.0)


@dataclass
class Candidate:
    """One candidate term of the library: an effect id (verbatim from calib.sim.effects), the sensor it acts on,
    its parameter names / units, and the signature columns (n_obs, p) at the base solution."""

    effect: str
    sensor: str                      # 'accel' | 'gyro' | 'both' | 'site' | 'clock'
    names: list
    units: list
    axes: list                       # axis letter per parameter ('' if not axis-bound)
    S: np.ndarray | None = None      # (n_obs, p)
    kind: str = "linear"             # 'linear' | 'drift' (tau profiled) | 'offset' (nonlinear)
    S_by_tau: dict = field(default_factory=dict)
    untestable: str = ""             # reason if it cannot be tested at all on this recording
    experiment: str = ""
    keys: list = field(default_factory=list)   # (registry key, index) per parameter
    offset: object = None            # OffsetModel of the time-offset candidate
    # set by calib.diagnosis.term_identifiability.prepare_library for the problem the library serves:
    active: np.ndarray | None = None    # indices of the determined parameters
    visible: np.ndarray | None = None   # norm of each parameter's whitened signature not absorbed by the base
    absorbed: np.ndarray | None = None  # fraction of each parameter's signature the base absorbs
    se0: np.ndarray | None = None       # standard errors next to the base model alone

    @property
    def key(self) -> str:
        return self.effect if self.sensor in ("both", "site", "clock") else f"{self.effect}/{self.sensor}"

    @property
    def p(self) -> int:
        return len(self.names)


@dataclass
class SampleContext:
    """Clean inputs at the evaluation nodes of every window (registry units: g, deg/h), concatenated.

    Static windows are evaluated at <= 64 evenly spread samples, rotation windows at one sample per <= 0.5 deg
    of table angle; ``Wsub[j]`` are the window's reduction weights at its nodes, rescaled so that they sum
    like the full weights (a rectangle rule: the effect terms are smooth in time and periodic in the angle).
    """

    t: np.ndarray
    f: np.ndarray
    w: np.ndarray
    w_nb: np.ndarray
    dw_nb: np.ndarray
    temperature: np.ndarray | None
    slices: list
    Wsub: list
    plans: dict = field(default_factory=dict, repr=False, compare=False)   # _reduce_term's, per sensor


def window_nodes(geom: Geometry, w: Window):
    """Window-relative sample indices at which effect terms are evaluated (see :class:`SampleContext`)."""
    if w.kind == "static":
        m = min(w.n, 64)
        return ((np.arange(m) + 0.5) * w.n / m).astype(int)
    step = abs(w.rate_deg_s) * geom.dt
    stride = max(1, int(0.5 / step)) if step > 0 else 1
    return np.arange(stride // 2, w.n, stride)


def sample_context(geom: Geometry) -> SampleContext:
    """The :class:`SampleContext` of ``geom`` (geometry only: computed once per geometry, :meth:`Geometry.derived`)."""
    return geom.derived("sample_context", lambda: _sample_context(geom))


def _sample_context(geom: Geometry) -> SampleContext:
    ts, fs_, ws_, wnb, dwnb, temps, slices, Wsub = [], [], [], [], [], [], [], []
    pos = 0
    ca = TO_MODEL[geom.units_in["accel"]]
    cg = TO_MODEL[geom.units_in["gyro"]]
    for w in geom.windows:
        idx = window_nodes(geom, w)
        f, om, r, a = window_inputs(geom, w, idx=idx)
        ts.append(geom.time_s[w.i0 + idx] + 0.5 * geom.dt)
        fs_.append(np.asarray(f) / ca)
        ws_.append(np.asarray(om) / cg)
        wnb.append(r)
        dwnb.append(a)
        if geom.temperature is not None:
            temps.append(geom.temperature[w.i0 + idx])
        slices.append(slice(pos, pos + idx.size))
        Wsub.append(w.W[idx] * (w.n / idx.size))
        pos += idx.size
    return SampleContext(np.concatenate(ts), np.concatenate(fs_), np.concatenate(ws_), np.concatenate(wnb),
                         np.concatenate(dwnb), np.concatenate(temps) if temps else None, slices, Wsub)


def _reduce_term(geom: Geometry, ctx: SampleContext, d, sensor: str, Kdiag, conv) -> np.ndarray:
    """Observation column (n_obs,) of a per-sample input-referred term d (n, 3) [registry units] of ``sensor``:
    output change K_i d_i conv, reduced per window (zeros for the other sensor's observations)."""
    views, blk = _reduce_plan(geom, ctx, sensor)
    red = _reduce_windows(views, d * (Kdiag * conv)[None, :])   # (rows of all windows, 3 axes)
    out = np.zeros(geom.obs["n"])
    out[blk] = red.T.ravel()                                    # axis by axis, windows in order
    return out


def reduce_axis_terms(geom: Geometry, ctx: SampleContext, terms, sensor: str, axis: int, scale: float) -> np.ndarray:
    """Observation columns (n_obs, k) of k per-sample terms (each (n,) or a scalar) on sensor axis ``axis`` alone:
    column j is :func:`_reduce_term` of ``d`` with ``d[:, axis] = terms[j]`` and ``K_axis conv = scale``, zeros
    elsewhere -- all k reduced in one product per window instead of k (the generic bases of
    :mod:`calib.diagnosis.generic` are sets of such terms)."""
    views, _ = _reduce_plan(geom, ctx, sensor)
    n = ctx.t.size
    T = np.stack([np.broadcast_to(np.asarray(t, float), (n,)) for t in terms]) * scale   # (k, n): rows contiguous
    out = np.zeros((geom.obs["n"], T.shape[0]))
    out[geom.obs["blocks"][(SENSORS.index(sensor), axis)]] = _reduce_windows(views, T.T)
    return out


def _reduce_windows(views, D) -> np.ndarray:
    """The per-window reductions ``W^T D`` of per-node columns ``D`` (n, k), windows in order: (rows, k)."""
    return np.concatenate([Wt @ D[sl] for Wt, sl in views])


def _reduce_plan(geom: Geometry, ctx: SampleContext, sensor: str):
    """Per window the transposed reduction weights at its nodes and its slice of the context, and the observation
    indices of the sensor's three axes: fixed by the geometry, so made once per context and sensor."""
    key = (id(geom), sensor)
    if key not in ctx.plans:
        si = SENSORS.index(sensor)
        views = [(ctx.Wsub[j][:, :rows_of(sensor, w)].T, ctx.slices[j]) for j, w in enumerate(geom.windows)]
        ctx.plans[key] = (views, np.concatenate([geom.obs["blocks"][(si, a)] for a in range(3)]))
    return ctx.plans[key]


def _axis_groups(entries):
    """``entries`` (index tuples whose first index is the sensor axis) in groups with at most one entry per
    axis, so that a group's columns come from one evaluation of the effect: the vector entries (0,), (1,), (2,)
    together; matrix entries by their diagonal, (0, j), (1, j + 1), (2, j + 2) (mod 3)."""
    groups = []
    for e in entries:
        for g in groups:
            if all(x[0] != e[0] for x in g) and (len(e) == 1 or all((x[1] - x[0]) % 3 == (e[1] - e[0]) % 3
                                                                     for x in g)):
                g.append(e)
                break
        else:
            groups.append([e])
    return groups


def _split_axes(geom: Geometry, col: np.ndarray, sensor: str, axes_set) -> list:
    """One column per sensor axis in ``axes_set`` from an observation column holding several axes: axis i's
    observations kept, every other observation zero (what a unit parameter on axis i alone gives)."""
    si = SENSORS.index(sensor)
    out = []
    for a in axes_set:
        c = np.zeros_like(col)
        blk = geom.obs["blocks"][(si, a)]
        c[blk] = col[blk]
        out.append(c)
    return out


def is_shape_parameter(key: str) -> bool:
    """Registry keys that set the shape of an effect (time constants, the reference temperature), not its
    size: they are neither zeroed for a unit column nor scaled with the magnitude."""
    return key.endswith("tau_s") or key == "T_ref_degC"


_ZEROS: dict = {}


def zero_params(eid):
    """The registry defaults of effect ``eid`` with every size parameter set to zero (shape parameters kept).
    A new dict each call (built once per effect, copied: the library asks for thousands)."""
    if eid not in _ZEROS:
        p = copy.deepcopy(effects.REGISTRY[eid].defaults)
        for k, v in p.items():
            if is_shape_parameter(k):
                continue
            p[k] = (np.zeros_like(np.asarray(v, float))).tolist() if np.ndim(v) else 0.0
        _ZEROS[eid] = p
    return {k: _copy_nested(v) for k, v in _ZEROS[eid].items()}


def _copy_nested(v):
    return [_copy_nested(x) for x in v] if isinstance(v, list) else copy.copy(v)


#: (effect id, sensor, registry key(s), parameter layout)
_SENSOR_EFFECTS = [
    ("accel_quadratic_nonlinearity", "accel", [("k2_ug_per_g2", "vec")]),
    ("accel_cubic_nonlinearity", "accel", [("k3_ug_per_g3", "vec")]),
    ("accel_scale_asymmetry", "accel", [("asym_ppm", "vec")]),
    ("accel_cross_coupling", "accel", [("k_cross_ug_per_g2", "offdiag")]),
    ("accel_lever_arm", "accel", [("lever_arms_m", "mat")]),
    ("gyro_g_sensitivity", "gyro", [("G_deg_h_per_g", "mat")]),
    ("gyro_scale_asymmetry", "gyro", [("asym_ppm", "vec")]),
    ("gyro_scale_nonlinearity", "gyro", [("k_ppm_per_deg_s", "vec")]),
    ("temperature_sensitivity", "accel", [("accel_bias_ug_per_degC", "vec"), ("accel_scale_ppm_per_degC", "vec")]),
    ("temperature_sensitivity", "gyro", [("gyro_bias_deg_h_per_degC", "vec"), ("gyro_scale_ppm_per_degC", "vec")]),
]

EXPERIMENTS = {
    "gravity_error": ("a wrong local g cannot be seen: every accelerometer scale factor follows it (K -> K g_true/"
                      "g_assumed leaves every observation unchanged)",
                      "reference the accelerometer scale to something other than g: measure local g with a "
                      "gravimeter (or use a surveyed value), or add a centrifuge test (unit at a known radius r on "
                      "the rate table: centripetal omega^2 r sets the scale independently of g)"),
    "latitude_error_norm": ("without table attitudes the gyro cannot see the direction of Earth rate; latitude "
                            "enters the accelerometer norm only through g, which the scale factors absorb",
                            "record with known table attitudes (a segment table with nominal_attitude) so the "
                            "gyro static means see the Earth-rate direction"),
    "time_offset": ("the time offset shows only as a phase shift of the table-angle harmonics during rotations",
                    "record the table angle (table_angle) during constant-rate rotations about at least one axis "
                    "perpendicular to Earth rate, at two or more rates"),
    "accel_lever_arm": ("the lever arm (size effect) only acts during rotations (centripetal omega^2 r)",
                        "add constant-rate rotation segments (with their rates) about each body axis"),
    "temperature_sensitivity": ("no temperature channel, or it does not vary",
                                "record the unit temperature and let it change during the session (warm-up or a "
                                "thermal chamber step)"),
    "gyro_rot": ("gyro scale terms need table rates: at rest the gyros see only Earth rate",
                 "add + and - constant-rate rotations about each axis at two or more rates"),
    "gyro_norm": ("without a rate table or known attitudes the gyros see only Earth rate at rest, which is "
                  "below the noise and bias of MEMS gyros; nothing about gyro terms can be tested",
                  "record on a rate table (known rates and attitudes), or add labelled turns of known angle"),
}


def build_library(geom: Geometry, M: dict, b: dict, *, xr0=None, ones0=None, offset_grid_step=0.0125,
                  only: set | None = None) -> list:
    """All candidates with their signature columns at the base solution ``M[s]`` (3x3 = K E), ``b[s]``;
    ``only``: just the candidates with these keys (e.g. to rebuild the found terms at a refined K E)."""
    ctx = sample_context(geom)
    cands: list[Candidate] = []
    have_rot = len(geom.rotation) > 0
    have_harm = have_rot and geom.has_table_angle
    temp_ok = ctx.temperature is not None and float(np.ptp(ctx.temperature)) > 0.05
    conv = {s: TO_MODEL[geom.units_in[s]] for s in SENSORS}
    KE = {s: np.asarray(M[s], float) for s in SENSORS}
    Kd = {s: np.diag(KE[s]).copy() for s in SENSORS}
    Emat = {s: KE[s] / Kd[s][:, None] for s in SENSORS}
    y_a = effects.rows_times(ctx.f, Emat["accel"])
    y_g = effects.rows_times(ctx.w, Emat["gyro"])
    tctx = ctx.temperature if ctx.temperature is not None else np.full(ctx.t.shape, 25.0)
    sctx = effects.SensorContext(ctx.t, ctx.f, ctx.w, y_a, y_g, ctx.w_nb, ctx.dw_nb, tctx, Emat["accel"],
                                 Emat["gyro"])

    def axis_columns(eid, sensor, p, axes_set):
        """The observation columns of ``p`` with one unit parameter per sensor axis in ``axes_set`` (the effect's
        term on axis i depends on axis i's parameters only, so one evaluation gives every axis its column)."""
        da, dg = effects.REGISTRY[eid].apply(sctx, p)
        return _split_axes(geom, _reduce_term(geom, ctx, da if sensor == "accel" else dg, sensor, Kd[sensor],
                                              conv[sensor]), sensor, axes_set)

    for eid, sensor, layout in _SENSOR_EFFECTS:
        if only is not None and f"{eid}/{sensor}" not in only:
            continue
        names, units, axes_, cols, keys = [], [], [], [], []
        unit_of = effects.REGISTRY[eid].units
        for key, kind in layout:
            if kind == "vec":
                entries = [(i,) for i in range(3)]
            elif kind == "mat":
                entries = [(i, j) for i in range(3) for j in range(3)]
            else:
                entries = [(i, j) for i in range(3) for j in range(3) if i != j]
            col_of = {}
            for group in _axis_groups(entries):   # entries on distinct sensor axes: one evaluation per group
                p = zero_params(eid)
                arr = np.zeros(np.shape(effects.REGISTRY[eid].defaults[key]))
                for e in group:
                    arr[e] = 1.0
                p[key] = arr.tolist()
                col_of.update(zip(group, axis_columns(eid, sensor, p, [e[0] for e in group])))
            for e in entries:
                cols.append(col_of[e])
                nm = key + "[" + ",".join(AXES[i] for i in e) + "]"
                names.append(nm)
                units.append(unit_of.get(key, ""))
                axes_.append(AXES[e[0]])
                keys.append((key, e))
        c = Candidate(eid, sensor, names, units, axes_, np.column_stack(cols), keys=keys)
        if eid == "accel_lever_arm" and not have_rot:
            c.untestable, c.experiment = EXPERIMENTS["accel_lever_arm"]
        if eid in ("gyro_scale_asymmetry", "gyro_scale_nonlinearity") and not have_rot:
            c.untestable, c.experiment = EXPERIMENTS["gyro_rot"]
        if eid == "temperature_sensitivity" and not temp_ok:
            c.untestable, c.experiment = EXPERIMENTS["temperature_sensitivity"]
        cands.append(c)

    # bias drift: warm-up A exp(-t/tau) + trend s t/3600 per triad, tau profiled on a grid
    for sensor in SENSORS:
        if only is not None and f"bias_drift/{sensor}" not in only:
            continue
        pre = "accel" if sensor == "accel" else "gyro"
        wkey, tkey, skey = f"{pre}_warmup_{'ug' if sensor == 'accel' else 'deg_h'}", f"{pre}_tau_s", \
            f"{pre}_trend_{'ug_per_h' if sensor == 'accel' else 'deg_h_per_h'}"
        unit_of = effects.REGISTRY["bias_drift"].units
        names = [f"{wkey}[{a}]" for a in AXES] + [f"{skey}[{a}]" for a in AXES]
        units = [unit_of[wkey]] * 3 + [unit_of[skey]] * 3
        c = Candidate("bias_drift", sensor, names, units, list(AXES) * 2, kind="drift",
                      keys=[(wkey, (i,)) for i in range(3)] + [(skey, (i,)) for i in range(3)])
        p = zero_params("bias_drift")
        p[skey] = [1.0, 1.0, 1.0]
        trend_cols = axis_columns("bias_drift", sensor, p, range(3))
        for tau in DRIFT_TAUS:
            p = zero_params("bias_drift")
            p[wkey] = [1.0, 1.0, 1.0]
            p[tkey] = tau
            c.S_by_tau[tau] = np.column_stack(axis_columns("bias_drift", sensor, p, range(3)) + trend_cols)
        c.S = c.S_by_tau[900.0]
        cands.append(c)

    # truth effects: latitude (Earth rate direction + g), gravity, time offset
    if only is not None and not only & {"latitude_error", "gravity_error", "time_offset"}:
        return cands
    if xr0 is None or ones0 is None:
        xr0, ones0 = reduced_inputs(geom)
    base_M = {s: KE[s] for s in SENSORS}

    def pred_no_bias(xr):
        red = {s: [x @ base_M[s].T for x in xr[s]] for s in SENSORS}
        return stack_fast(geom, red)

    h = 0.01
    xp, _ = reduced_inputs(geom, latitude_deg=geom.latitude_deg + h)
    xm, _ = reduced_inputs(geom, latitude_deg=geom.latitude_deg - h)
    s_lat = (pred_no_bias(xp) - pred_no_bias(xm)) / (2 * h)
    lat = Candidate("latitude_error", "site", ["delta_lat_deg"], ["deg"], [""], s_lat[:, None],
                    keys=[("delta_lat_deg", ())])
    if geom.model != "vector":
        lat.untestable, lat.experiment = EXPERIMENTS["latitude_error_norm"]
    cands.append(lat)
    hg = 1e-3
    xgp, _ = reduced_inputs(geom, gravity_m_s2=geom.gravity_m_s2 + hg)
    xgm, _ = reduced_inputs(geom, gravity_m_s2=geom.gravity_m_s2 - hg)
    s_g = (pred_no_bias(xgp) - pred_no_bias(xgm)) / (2 * hg)
    cands.append(Candidate("gravity_error", "site", ["delta_g_m_s2"], ["m s-2"], [""], s_g[:, None],
                           keys=[("delta_g_m_s2", ())]))
    off = Candidate("time_offset", "clock", ["offset_s"], ["s"], [""], kind="offset", keys=[("offset_s", ())])
    if have_harm and geom.max_offset_s > 0:
        grid = np.arange(-geom.max_offset_s, geom.max_offset_s + 0.5 * offset_grid_step, offset_grid_step)
        rot_idx = [j for j, w in enumerate(geom.windows) if w.kind == "rotation"]
        off.offset = OffsetModel(grid, offset_grid_inputs(geom, grid), rot_idx, geom)
        # first-order signature at 0 (for the absorption / angle analysis)
        d0 = off.offset.design_delta(0.0, base_M, deriv=1)
        off.S = d0[:, None]
    else:
        off.untestable, off.experiment = EXPERIMENTS["time_offset"]
        off.S = np.zeros((geom.obs["n"], 1))
    cands.append(off)
    return cands


class OffsetModel:
    """Reduced inputs of the rotation windows as a function of the clock offset (cubic splines over a grid).

    ``rows(delta)`` gives the base-design rows (accel and gyro rotation observations) at that offset.
    """

    def __init__(self, grid, values, rot_idx, geom: Geometry):
        self.grid = np.asarray(grid, float)
        self.spline = CubicSpline(self.grid, np.asarray(values), axis=0)
        self.rot_idx = list(rot_idx)
        self.geom = geom
        # map flattened values -> (sensor, window, row, component)
        layout = []
        for s in SENSORS:
            for j in self.rot_idx:
                w = geom.windows[j]
                for r in range(rows_of(s, w)):
                    layout.append((s, j, r))
        self.layout = layout
        o = geom.obs
        self.obs_index = {}
        for k in range(o["n"]):
            wi = o["window"][k]
            if geom.windows[wi].kind == "rotation":
                self.obs_index.setdefault((SENSORS[o["sensor"][k]], wi, o["row"][k]), []).append(k)
        # patch_design as one scatter: observation k takes the inputs of layout entry src[k] into the three input
        # columns of its sensor and axis starting at col[k] (the geometry fixes all three)
        obs, src, col = [], [], []
        for e, (sn, j, r) in enumerate(layout):
            for k in self.obs_index[(sn, j, r)]:
                obs.append(k)
                src.append(e)
                col.append(12 * SENSORS.index(sn) + 3 * o["axis"][k])
        self._patch = (np.array(obs, int)[:, None], np.array(src, int), np.array(col, int)[:, None] + np.arange(3))

    @property
    def bounds(self):
        return float(self.grid[0]), float(self.grid[-1])

    def reduced(self, delta, deriv=0):
        v = self.spline(float(delta), deriv) if deriv else self.spline(float(delta))
        return v.reshape(-1, 3)

    def patch_design(self, X, delta):
        """Overwrite the input columns of the rotation observations in a copy of the base design X."""
        X = X.copy()
        obs, src, cols = self._patch
        X[obs, cols] = self.reduced(delta)[src]
        return X

    def design_delta(self, delta, M, deriv=1):
        """d(prediction)/d(delta) (n_obs,) at ``delta`` for the base matrices M[s] (no bias)."""
        out = np.zeros(self.geom.obs["n"])
        v = self.reduced(delta, deriv)
        for (s, j, r), x in zip(self.layout, v):
            y = M[s] @ x
            for k in self.obs_index[(s, j, r)]:
                out[k] = y[self.geom.obs["axis"][k]]
        return out
