"""Windows, observations and the base-model design of the mismatch diagnosis.

Everything here is a function of the recording's *geometry* (segment table, table angle, temperature,
site); the data enter only through :func:`reduce_data`. The diagnosis is then linear algebra on segment
means (:mod:`calib.diagnosis.noise` for their covariance, :mod:`calib.diagnosis.library` for the effect
signatures).

Observations (vector model, Liu 2021 eqs. 1-4: N = K E x + b)
--------------------------------------------------------------
Rate readings ``N`` [count s-1 for the synthetic unit: counts per sample / dt] are reduced per *window*:

* static segment m: the mean over its samples (one 3-vector per triad);
* rotation segment j (cut to whole revolutions with the recorded ``table_angle``): the coefficients of the
  least-squares fit ``N(t) = c0 + c1 cos(theta) + c2 sin(theta)`` over the window, ``theta`` the table angle at
  the sample *mid-times* (sample k covers [k dt, (k+1) dt)). Over whole revolutions ``c0`` is the window mean
  (Liu 2021 eq. 23); ``c1, c2`` are the table-angle harmonics through which the Earth-rate component
  perpendicular to the axis shows (Liu 2021 eq. 22). The gyros use (c0, c1, c2); the accelerometers only c0
  (their harmonics are zero with the axis vertical for every term of the library).

Each observation o is ``sum_k w_ok N_k`` with known weights, so its prediction under any model is the same
reduction of the per-sample prediction, and its noise covariance follows from the noise model
(:func:`calib.diagnosis.noise.covariance_parts`).

Inputs of the base model: body specific force ``f^b = C_n^b (0, 0, g)`` [input unit, g for counts] and
angular rate ``omega_ib^b = u theta' + C_n^b omega_ie^n`` [deg/h for counts], with ``C_b^n = C0 R_u(theta)``
(``C0`` = ``nominal_attitude`` of the segment, body to ENU) during rotations.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from calib.core import earth
from calib.core.earth import STANDARD_GRAVITY
from calib.io.recording import SAMPLE_INTERVAL_START, SAMPLE_TIME_CONVENTIONS
from calib.signal.segments import RATE_UNIT_OF_INCREMENT, input_unit_for, rate_reading

SENSORS = ("accel", "gyro")
AXES = ("x", "y", "z")
ROWS = ("mean", "cos", "sin")
#: registry input units: accel g, gyro deg/h; factor from the registry unit to a model input unit
TO_MODEL = {"g": 1.0, "m s-2": STANDARD_GRAVITY, "deg h-1": 1.0, "rad s-1": earth.DEG_PER_H,
             "deg s-1": 1.0 / 3600.0}


class DiagnosisInputError(ValueError):
    """A recording the diagnosis cannot work on; ``reason`` is the plain-words cause for the report."""

    def __init__(self, reason: str, fix: str = ""):
        self.reason, self.fix = reason, fix
        super().__init__(reason + (f" -- fix: {fix}" if fix else ""))


# =====================================================================================================
# geometry
# =====================================================================================================
@dataclass
class Window:
    """One observation window: a static segment or the whole-revolution part of a rotation segment."""

    kind: str                 # 'static' | 'rotation'
    label: str
    segment: int
    i0: int                   # first sample (recording index)
    i1: int                   # one past the last sample
    attitude: np.ndarray | None = None   # C_b^n at theta = 0 (body to ENU)
    axis: np.ndarray | None = None       # rotation axis, unit vector, body frame
    rate_deg_s: float = 0.0              # nominal signed table rate about axis
    theta_mid: np.ndarray | None = None  # table angle at sample mid-times [rad], 0 at the segment start
    revolutions: int = 0
    W: np.ndarray | None = None          # (n, r) reduction weights: obs = W^T N
    spline: CubicSpline | None = None    # continuous table angle [rad] vs time [s] around the window
    phase: str = ""                      # 'P1'.. for static positions of the Liu 2021 path
    position: int = -1                   # position number within the phase (0-based)

    @property
    def n(self) -> int:
        return self.i1 - self.i0

    @property
    def rows(self) -> int:
        return self.W.shape[1]


@dataclass
class Geometry:
    """Everything about a recording the diagnosis needs except the sensor samples."""

    source: str
    fs: float
    dt: float
    n_samples: int
    latitude_deg: float
    height_m: float
    gravity_m_s2: float
    gravity_source: str
    units_out: dict                      # sensor -> output (rate) unit
    units_in: dict                       # sensor -> model input unit
    windows: list
    model: str                           # 'vector' | 'norm'
    temperature: np.ndarray | None       # per sample [degC] or None
    time_s: np.ndarray                   # per-sample start times from the first sample [s]
    has_table_angle: bool
    notes: list = field(default_factory=list)
    max_offset_s: float = 0.0
    obs: dict = field(default_factory=dict)   # observation metadata (see build_observations)
    sample_start_s: float = 0.0          # start of a sample's interval relative to its stamp [s] (the recording's
                                         # sample_time_convention; 0 for interval_start)
    derived_cache: dict = field(default_factory=dict, repr=False, compare=False)

    def derived(self, key, fn):
        """``fn()`` computed once per geometry and cached under ``key``: for quantities that depend on the
        geometry alone (window samples, reduction weights, inputs), never on the sensor data or the noise --
        so every noise seed that shares the geometry (``library_from``) shares them too. The windows are fixed
        before anything is derived (the norm set-up narrows them to the static ones right after
        :func:`build_geometry`)."""
        if key not in self.derived_cache:
            self.derived_cache[key] = fn()
        return self.derived_cache[key]

    @property
    def static(self):
        return [w for w in self.windows if w.kind == "static"]

    @property
    def rotation(self):
        return [w for w in self.windows if w.kind == "rotation"]


def _rodrigues_T(axis, theta, v, cs=None):
    """R_u(theta)^T v for per-sample angles theta (n,) and a fixed vector v (3,): rotation by -theta.
    ``cs``: ``(cos theta, sin theta)`` as (n, 1) columns when the caller already has them."""
    u = np.asarray(axis, float)
    v = np.asarray(v, float)
    c, s = cs if cs is not None else (np.cos(theta)[:, None], np.sin(theta)[:, None])
    uxv = np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])  # u x v
    return v[None, :] * c - uxv[None, :] * s + (u @ v) * u[None, :] * (1.0 - c)


def _stitch_angle(a_deg, seg_idx):
    """Continuous table angle [deg] from the recorded one, which restarts at 0 at segment starts and axis
    changes (and may carry the previous primitive's value on a segment's first sample).

    A restart shows as an isolated spike in the step sequence d_k = a_{k+1} - a_k (both neighbours differ
    from it by more than a tolerance while the table's angular acceleration is piecewise constant). The bad
    step is replaced by the linear extrapolation of the two steps on the side that belongs to the same
    segment run (primitive boundaries lie on the sample grid: a spike inside a segment run is the
    first-sample artefact and its step belongs to the new primitive -> extrapolate from the right; a spike
    across a change of segment index belongs to the old primitive -> extrapolate from the left).
    Returns angles (same length) with a[0] kept.
    """
    a = np.asarray(a_deg, dtype=float)
    si = np.asarray(seg_idx)
    d = np.diff(a)
    m = d.size
    if m < 5:
        return np.concatenate([[a[0]], a[0] + np.cumsum(d)])
    dd = np.abs(np.diff(d))
    tol = max(0.05, 20.0 * float(np.median(dd)))
    bad = np.zeros(m, dtype=bool)
    bad[1:-1] = (dd[:-1] > tol) & (dd[1:] > tol)
    bad[0] = dd[0] > tol and (m < 3 or dd[1] <= tol)
    bad[-1] = dd[-1] > tol and dd[-2] <= tol
    out = d.copy()
    for k in np.flatnonzero(bad):
        right_ok = k + 2 < m and not bad[k + 1] and not bad[k + 2]
        left_ok = k >= 2 and not bad[k - 1] and not bad[k - 2]
        same_run = si[k] == si[k + 1]
        if (same_run and right_ok) or (right_ok and not left_ok):
            out[k] = 2.0 * d[k + 1] - d[k + 2]
        elif left_ok:
            out[k] = 2.0 * out[k - 1] - out[k - 2]
        else:
            out[k] = out[k - 1] if k > 0 else d[k + 1]
    return np.concatenate([[a[0]], a[0] + np.cumsum(out)])


def rate_readings(ds, sensor):
    """Per-sample rate readings of ``sensor`` (increments times the sample rate) and their unit
    (:func:`calib.signal.segments.rate_reading`)."""
    return rate_reading(ds, sensor)


def build_geometry(ds, *, max_offset_s: float = 0.25, min_static: int = 6, trim_s: float | None = None) -> Geometry:
    """Windows, inputs and reduction weights of a ``calib-recording-1`` dataset with a segment table.

    ``max_offset_s``: largest clock offset the time-offset candidate is evaluated for (limited by the
    recorded table motion around the rotation windows). Static windows are trimmed by ``trim_s`` (default:
    ``max_offset_s``) at both ends, so that no sample of a static window can see table motion under any
    offset tested (one sample at the start of a move changes a 60 s gyro mean by rate x dt / 60 s).
    ``min_static``: fewer static segments -> error.
    Raises :class:`DiagnosisInputError` with the reason when the recording cannot be diagnosed.
    """
    src = str(ds.attrs.get("_path", "<in-memory recording>"))
    if "segment_index" not in ds or "segment_kind" not in ds:
        raise DiagnosisInputError(f"{src}: no segment table (segment_index / segment_kind)",
                                  "add the segment table (synthetic sessions have one; for imported recordings "
                                  "run the static detection, calib.signal.detect.add_segment_table)")
    fs = float(ds.attrs["sample_rate_hz"])
    dt = 1.0 / fs
    conv_t = str(ds.attrs.get("sample_time_convention", SAMPLE_TIME_CONVENTIONS[0]))
    if conv_t not in SAMPLE_INTERVAL_START:
        raise DiagnosisInputError(f"{ds.attrs.get('_path', 'recording')}: sample_time_convention {conv_t!r} unknown",
                                  f"one of {', '.join(SAMPLE_TIME_CONVENTIONS)}")
    t_start = SAMPLE_INTERVAL_START[conv_t] * dt   # a sample's interval starts this long after its stamp [s]
    n = int(ds.sizes["time"])
    lat = float(ds.attrs["latitude_deg"])
    h = float(ds.attrs.get("height_m", 0.0))
    g_attr = ds.attrs.get("gravity_m_s2")
    if g_attr is not None:
        g, g_src = float(g_attr), "recording attribute gravity_m_s2"
    else:
        g, g_src = float(earth.normal_gravity(math.radians(lat), h)), "WGS-84 normal gravity at the recorded site"
    units_out, units_in = {}, {}
    for s in SENSORS:
        if s not in ds:
            raise DiagnosisInputError(f"{src}: variable '{s}' missing")
        kind, units = ds[s].attrs.get("sample_kind"), ds[s].attrs.get("units")
        out = RATE_UNIT_OF_INCREMENT.get(units, f"{units} s-1") if kind == "increment" else units
        units_out[s] = out
        iu = input_unit_for(s, out)
        if iu not in TO_MODEL:
            raise DiagnosisInputError(f"{src}: {s} output unit {out!r} has no input unit the library knows")
        units_in[s] = iu
    si = np.asarray(ds["segment_index"].values, dtype=np.int64)
    kinds = [str(k) for k in ds["segment_kind"].values]
    labels = ([str(v) for v in ds["segment_label"].values] if "segment_label" in ds
              else [f"segment {i}" for i in range(len(kinds))])
    att_all = np.asarray(ds["nominal_attitude"].values, float) if "nominal_attitude" in ds else None
    has_angle = "table_angle" in ds
    angle = np.asarray(ds["table_angle"].values, float) if has_angle else None
    rates = np.asarray(ds["rotation_rate"].values, float) if "rotation_rate" in ds else None
    axes = np.asarray(ds["rotation_axis"].values, float) if "rotation_axis" in ds else None
    if "time" in ds.coords:
        tt = np.asarray(ds["time"].values, dtype=float)
        time_s = tt - tt[0]
    else:
        time_s = np.arange(n) * dt
    temp = np.asarray(ds["temperature"].values, float) if "temperature" in ds else None
    trim = int(math.ceil((max_offset_s if trim_s is None else trim_s) * fs))
    notes = []
    windows: list[Window] = []
    m_off = int(math.ceil(max_offset_s / dt)) + 4
    for s, kind in enumerate(kinds):
        idx = np.flatnonzero(si == s)
        if idx.size == 0:
            continue
        if np.any(np.diff(idx) != 1):
            raise DiagnosisInputError(f"{src}: segment {s} ({labels[s]}) is not one contiguous run of samples")
        i0, i1 = int(idx[0]), int(idx[-1]) + 1
        if kind == "static":
            i0, i1 = i0 + trim, i1 - trim
            if i1 - i0 < 3:
                continue
            att = None if att_all is None else att_all[s]
            w = Window("static", labels[s], s, i0, i1, attitude=att)
            w.W = np.full((i1 - i0, 1), 1.0 / (i1 - i0))
            lab = labels[s]
            if lab.startswith("P") and "-POS" in lab:
                w.phase = lab.split("-")[0]
                try:
                    w.position = int(lab.split("POS")[1]) - 1
                except ValueError:
                    w.position = -1
            windows.append(w)
        elif kind == "rotation":
            if rates is None or axes is None:
                notes.append(f"rotation segment {labels[s]} skipped: no rotation_rate / rotation_axis")
                continue
            r = float(rates[s])
            u = axes[s] / np.linalg.norm(axes[s])
            att = None if att_all is None else att_all[s]
            spline = None
            if has_angle:
                j0, j1 = max(i0 - m_off, 0), min(i1 + m_off, n - 1)
                cont = _stitch_angle(angle[j0:j1 + 1], si[j0:j1 + 1])
                tau = (np.arange(j0, j1 + 1) - i0) * dt   # stamps relative to the first sample's stamp
                if t_start == 0.0:
                    cont = cont - cont[i0 - j0]      # 0 at the segment start (the recording's convention)
                    th_seg = cont[i0 - j0:i1 - j0 + 1]   # angles at sample starts, i0..i1 (inclusive end)
                else:
                    # the segment starts where its first sample's interval starts, t_start from that stamp
                    cont = cont - float(CubicSpline(tau, cont)(t_start))
                    th_seg = CubicSpline(tau, cont)(np.arange(i1 - i0 + 1) * dt + t_start)
                spline = CubicSpline(tau, np.radians(cont))
            else:
                th_seg = r * np.arange(i1 - i0 + 1) * dt
                notes.append(f"{labels[s]}: no table_angle; nominal rate x time used, harmonics not formed")
            ends = np.abs(th_seg[1:])
            k = int(math.floor((ends[-1] + 0.5 * abs(r) * dt) / 360.0))
            if k < 1:
                notes.append(f"rotation segment {labels[s]} skipped: less than one whole revolution")
                continue
            nwin = int(np.searchsorted(ends, k * 360.0 + 0.25 * abs(r) * dt, side="right"))
            thm = np.radians(0.5 * (th_seg[:nwin] + th_seg[1:nwin + 1]))
            w = Window("rotation", labels[s], s, i0, i0 + nwin, attitude=att, axis=u, rate_deg_s=r,
                       theta_mid=thm, revolutions=k, spline=spline)
            if has_angle:
                X = np.column_stack([np.ones(nwin), np.cos(thm), np.sin(thm)])
                w.W = X @ np.linalg.inv(X.T @ X)
            else:
                w.W = np.full((nwin, 1), 1.0 / nwin)
            windows.append(w)
    st = [w for w in windows if w.kind == "static"]
    if len(st) < min_static:
        raise DiagnosisInputError(f"{src}: only {len(st)} static segments (at least {min_static} are needed to "
                                  "calibrate the base model and test anything beyond it; a field calibration of "
                                  "the same file has no redundancy to check its model either)",
                                  "record more static positions (Liu 2021 uses 24)")
    vector = att_all is not None and all(w.attitude is not None and np.all(np.isfinite(w.attitude)) for w in windows)
    if has_angle and windows:
        max_off = max_offset_s
    else:
        max_off = 0.0
    geom = Geometry(source=src, fs=fs, dt=dt, n_samples=n, latitude_deg=lat, height_m=h, gravity_m_s2=g,
                    gravity_source=g_src, units_out=units_out, units_in=units_in, windows=windows,
                    model="vector" if vector else "norm", temperature=temp, time_s=time_s,
                    has_table_angle=has_angle, notes=notes, max_offset_s=max_off)
    geom.sample_start_s = t_start
    if conv_t != SAMPLE_TIME_CONVENTIONS[0]:
        notes.append(f"sample_time_convention {conv_t}: each sample covers the interval starting "
                     f"{t_start * 1e3:+.4g} ms from its stamp")
    build_observations(geom)
    return geom


# =====================================================================================================
# observations
# =====================================================================================================
def rows_of(sensor: str, w: Window) -> int:
    """Reduction rows used: accel 1 (mean), gyro all (mean, cos, sin when the table angle is known)."""
    return 1 if sensor == "accel" else w.rows


def build_observations(geom: Geometry):
    """Observation metadata (arrays over observations, ordered sensor > axis > window > row)."""
    sen, ax, win, row = [], [], [], []
    for si, s in enumerate(SENSORS):
        for a in range(3):
            for wi, w in enumerate(geom.windows):
                for r in range(rows_of(s, w)):
                    sen.append(si)
                    ax.append(a)
                    win.append(wi)
                    row.append(r)
    geom.obs = {"sensor": np.array(sen), "axis": np.array(ax), "window": np.array(win), "row": np.array(row)}
    geom.obs["n"] = len(sen)
    blocks = {}
    for si in range(2):
        for a in range(3):
            blocks[(si, a)] = np.flatnonzero((geom.obs["sensor"] == si) & (geom.obs["axis"] == a))
    geom.obs["blocks"] = blocks


def reduce_windows(geom: Geometry, per_sample, sensor: str):
    """Reduce per-sample values (n_samples, 3) of the *recording* to the observation vector of ``sensor``
    (length n_obs(sensor) = 3 axes x rows): list per window of (rows, 3)."""
    out = []
    for w in geom.windows:
        r = rows_of(sensor, w)
        out.append(w.W[:, :r].T @ per_sample[w.i0:w.i1])
    return out


def stack_fast(geom: Geometry, red: dict) -> np.ndarray:
    """Observation vector from per-window reductions ``red[sensor]`` (order sensor > axis > window > row)."""
    parts = []
    for s in SENSORS:
        for a in range(3):
            parts.append(np.concatenate([r[:, a] for r in red[s]]))
    return np.concatenate(parts)


def pulse_counter_channels(ds) -> dict:
    """Sensors whose samples are integer counts per sample (a pulse counter: quantisation known)."""
    out = {}
    for s in SENSORS:
        v = ds[s]
        ok = v.attrs.get("sample_kind") == "increment" and v.attrs.get("units") == "count"
        if ok:
            head = np.asarray(v.values[:2000], dtype=float)
            ok = bool(np.all(np.mod(head, 1.0) == 0.0))
        out[s] = ok
    return out


def reduce_data(geom: Geometry, ds) -> tuple[np.ndarray, dict]:
    """Observation vector of the recording's rate readings, and the readings themselves per sensor."""
    y = {}
    red = {}
    for s in SENSORS:
        y[s], _ = rate_readings(ds, s)
        if not np.all(np.isfinite(y[s])):
            raise DiagnosisInputError(f"{geom.source}: variable '{s}' holds NaN or Inf")
        red[s] = reduce_windows(geom, y[s], s)
    return stack_fast(geom, red), y


# =====================================================================================================
# base model inputs and design
# =====================================================================================================
def site_vectors(geom: Geometry, latitude_deg=None, gravity_m_s2=None):
    """Gravity (0, 0, g) and Earth rate omega_ie^n in the model input units (accel, gyro)."""
    lat = geom.latitude_deg if latitude_deg is None else latitude_deg
    g = geom.gravity_m_s2 if gravity_m_s2 is None else gravity_m_s2
    ga = np.array([0.0, 0.0, g]) / STANDARD_GRAVITY * TO_MODEL[geom.units_in["accel"]]
    wg = earth.earth_rate_enu(math.radians(lat)) / earth.DEG_PER_H * TO_MODEL[geom.units_in["gyro"]]
    return ga, wg


def window_inputs(geom: Geometry, w: Window, delta_s: float = 0.0, latitude_deg=None, gravity_m_s2=None,
                  idx=None, need_accel=True):
    """Per-sample true inputs over a window (model input units): f (n,3), omega_ib (n,3), table rate
    omega_nb [rad/s] (n,3), angular acceleration [rad/s^2] (n,3). ``delta_s``: clock offset (the sample at t
    measures the motion at t + delta). ``idx``: window-relative sample indices to evaluate (default all)."""
    ga, wg = site_vectors(geom, latitude_deg, gravity_m_s2)
    k = np.arange(w.n) if idx is None else np.asarray(idx)
    n = k.size
    if w.kind == "static" or w.attitude is None:
        C = w.attitude if w.attitude is not None else np.eye(3)
        f = np.broadcast_to(C.T @ ga, (n, 3))
        om = np.broadcast_to(C.T @ wg, (n, 3))
        z = np.zeros((n, 3))
        return f, om, z, z
    u, C0 = w.axis, w.attitude
    gyro_unit = TO_MODEL[geom.units_in["gyro"]]
    if w.spline is not None:
        tk = k * geom.dt + delta_s + geom.sample_start_s   # the sample's interval, on the stamps of the table angle
        th0 = w.spline(tk)
        th1 = w.spline(tk + geom.dt)
        thm = w.spline(tk + 0.5 * geom.dt)
        rate = (th1 - th0) / geom.dt                      # rad/s, sample average
        acc = w.spline(tk + 0.5 * geom.dt, 2) if need_accel else np.zeros(n)
    else:
        thm = w.theta_mid[k]
        rate = np.full(n, math.radians(w.rate_deg_s))
        acc = np.zeros(n)
    cs = (np.cos(thm)[:, None], np.sin(thm)[:, None])
    f = _rodrigues_T(u, thm, C0.T @ ga, cs)
    om = _rodrigues_T(u, thm, C0.T @ wg, cs) + np.outer(rate, u) / earth.DEG_PER_H * gyro_unit
    return f, om, np.outer(rate, u), np.outer(acc, u)


def reduced_inputs(geom: Geometry, delta_s=0.0, latitude_deg=None, gravity_m_s2=None, only_rotation=False):
    """Reduced inputs per sensor: list per window of (rows, 3) [model input units], and the bias rows
    (rows,) = W^T 1. A function of the geometry and the arguments only: computed once per geometry and argument
    set (:meth:`Geometry.derived`; the callers only read the arrays)."""
    key = ("reduced_inputs", float(delta_s), None if latitude_deg is None else float(latitude_deg),
           None if gravity_m_s2 is None else float(gravity_m_s2), bool(only_rotation))
    return geom.derived(key, lambda: _reduced_inputs(geom, delta_s, latitude_deg, gravity_m_s2, only_rotation))


def window_ones(geom: Geometry):
    """The bias rows W^T 1 of every window per sensor (lists over windows), computed once per geometry."""
    def build():
        one_a, one_g = [], []
        for w in geom.windows:
            one_a.append(w.W[:, :rows_of("accel", w)].sum(axis=0))
            one_g.append(w.W[:, :rows_of("gyro", w)].sum(axis=0))
        return one_a, one_g
    return geom.derived("window_ones", build)


def _reduced_inputs(geom: Geometry, delta_s, latitude_deg, gravity_m_s2, only_rotation):
    xa, xg = [], []
    one_a, one_g = window_ones(geom)
    ga, wg = site_vectors(geom, latitude_deg, gravity_m_s2)
    for j, w in enumerate(geom.windows):
        sa, sg_ = one_a[j], one_g[j]
        if only_rotation and w.kind != "rotation":
            xa.append(None)
            xg.append(None)
            continue
        if w.kind == "static" or w.attitude is None:
            C = w.attitude if w.attitude is not None else np.eye(3)
            xa.append(sa[:, None] * (C.T @ ga)[None, :])
            xg.append(sg_[:, None] * (C.T @ wg)[None, :])
            continue
        if w.spline is not None:
            angles = _angles0(geom, j) if float(delta_s) == 0.0 else None
            ra, rg = rotation_reduced(geom, w, np.array([float(delta_s)]), ga, wg, angles=angles)
            xa.append(ra[0])
            xg.append(rg[0])
            continue
        f, om, _, _ = window_inputs(geom, w, delta_s, latitude_deg, gravity_m_s2, need_accel=False)
        xa.append(w.W[:, :rows_of("accel", w)].T @ f)
        xg.append(w.W[:, :rows_of("gyro", w)].T @ om)
    return {"accel": xa, "gyro": xg}, {"accel": one_a, "gyro": one_g}


def offset_grid_inputs(geom: Geometry, grid) -> np.ndarray:
    """Reduced inputs of the rotation windows at every clock offset of ``grid``: (len(grid), m) with row d the
    concatenation over sensors, then rotation windows, of ``reduced_inputs(geom, grid[d], only_rotation=True)``
    raveled -- the same numbers, computed window by window for all offsets at once and once per geometry."""
    grid = np.asarray(grid, dtype=float)

    def build():
        ga, wg = site_vectors(geom)
        parts = {s: [] for s in SENSORS}
        for w in geom.rotation:
            if w.spline is None or w.attitude is None:
                for s, x in zip(SENSORS, _reduced_one_by_one(geom, w, grid)):
                    parts[s].append(x)
                continue
            xa, xg = rotation_reduced(geom, w, grid, ga, wg)
            parts["accel"].append(xa.reshape(grid.size, -1))
            parts["gyro"].append(xg.reshape(grid.size, -1))
        return np.concatenate([p for s in SENSORS for p in parts[s]], axis=1)
    return geom.derived(("offset_grid_inputs", tuple(grid.tolist())), build)


def _reduced_one_by_one(geom, w, grid):
    xa, xg = [], []
    for d in grid:
        f, om, _, _ = window_inputs(geom, w, float(d), need_accel=False)
        xa.append((w.W[:, :rows_of("accel", w)].T @ f).ravel())
        xg.append((w.W[:, :rows_of("gyro", w)].T @ om).ravel())
    return np.array(xa), np.array(xg)


# ------------------------------------------------------------------ rotation windows: a compiled sample loop
# The reduced inputs of a rotation window under a clock offset are sums over every sample of the window, and the
# time-offset candidate needs them on a grid of offsets (calib.diagnosis.library.OffsetModel): ~3 million
# sample evaluations of the table-angle spline, its cosine and sine. A compiled loop does, per sample, exactly
# the floating-point operations of :func:`window_inputs` in its order (the spline evaluated as scipy's PPoly
# does: the interval with x[i] <= t < x[i+1], clamped to the end intervals, then c3 + c2 s + c1 s^2 + c0 s^3
# summed in that order; no fused multiply-add), so the angle terms are the same to the last bit; the inputs,
# linear in them, are reduced by four matrix products (:func:`rotation_reduced`).
def _angles_loop(kdt, deltas, s0, dt, bx, cc, out_c, out_s, out_rate):  # pragma: no cover - compiled
    """cos / sin of the table angle at the sample mid-times and the sample-average rate, (D, n) each."""
    m = bx.size
    half = 0.5 * dt
    inv = 1.0 / dt
    x0 = bx[0]
    th = np.empty(3)
    for d in range(deltas.size):
        for k in range(kdt.size):
            tk = kdt[k] + deltas[d] + s0
            for e in range(3):
                if e == 0:
                    x = tk
                elif e == 1:
                    x = tk + dt
                else:
                    x = tk + half
                q = int(math.floor((x - x0) * inv))   # a first guess, corrected by the comparisons below
                if q < 0:
                    q = 0
                elif q > m - 2:
                    q = m - 2
                while q > 0 and x < bx[q]:
                    q -= 1
                while q < m - 2 and x >= bx[q + 1]:
                    q += 1
                sx = x - bx[q]
                res = cc[3, q] + cc[2, q] * sx
                z = sx * sx
                res = res + cc[1, q] * z
                z = z * sx
                res = res + cc[0, q] * z
                th[e] = res
            out_rate[d, k] = (th[1] - th[0]) / dt
            out_c[d, k] = math.cos(th[2])
            out_s[d, k] = math.sin(th[2])


_KERNELS: list = []


def _kernels():
    """The loop compiled by numba (cached on disk beside this module; imported and compiled on first use)."""
    if not _KERNELS:
        import numba

        _KERNELS.append(numba.njit(cache=True, nogil=True)(_angles_loop))
    return _KERNELS


#: samples x offsets evaluated per call (bounds the memory of a long rotation window)
_CHUNK = 1 << 18


def rotation_angles(geom: Geometry, w: Window, deltas):
    """(cos theta, sin theta, rate) at the sample mid-times of rotation window ``w`` (with a table-angle spline)
    under each clock offset of ``deltas``: arrays (len(deltas), n), as :func:`window_inputs` computes them."""
    deltas = np.ascontiguousarray(deltas, dtype=float)
    shape = (deltas.size, w.n)
    c, s, r = np.empty(shape), np.empty(shape), np.empty(shape)
    angles_loop, = _kernels()
    args = (np.arange(w.n) * geom.dt, float(geom.sample_start_s), float(geom.dt),
            np.ascontiguousarray(w.spline.x, dtype=float), np.ascontiguousarray(w.spline.c, dtype=float))

    def rows(a, b):
        angles_loop(args[0], deltas[a:b], *args[1:], c[a:b], s[a:b], r[a:b])

    h = deltas.size // 2
    if h and deltas.size * w.n >= _THREADED and angles_loop.signatures and _cores() > 1:
        # the offsets in two halves, one in a thread (the loop holds no GIL): each row's numbers are its own
        import threading

        t = threading.Thread(target=rows, args=(0, h))
        t.start()
        try:
            rows(h, deltas.size)
        finally:
            t.join()
    else:
        rows(0, deltas.size)
    return c, s, r


#: samples x offsets from which :func:`rotation_angles` uses a second core
_THREADED = 1 << 16


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _angles0(geom: Geometry, j: int):
    """:func:`rotation_angles` of window ``j`` at zero offset, once per geometry (the base inputs and the
    latitude and gravity differences all use them)."""
    return geom.derived(("rotation_angles0", j), lambda: rotation_angles(geom, geom.windows[j], [0.0]))


def _cross(u, v):
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


def rotation_reduced(geom: Geometry, w: Window, deltas, ga, wg, angles=None):
    """Reduced inputs (len(deltas), rows, 3) of accel and gyro of rotation window ``w`` under each clock offset,
    for the site vectors ``ga``, ``wg`` (:func:`site_vectors`): ``W^T`` :func:`window_inputs`, offset by offset.
    ``angles``: :func:`rotation_angles` of these offsets when the caller has them.

    The inputs are linear in the angle terms: f = v cos(theta) - (u x v) sin(theta) + (u.v) u (1 - cos(theta)) for
    v = C0^T g (and C0^T omega_ie plus the table rate along u for the gyros, :func:`_rodrigues_T`), so
    ``W^T f = (W^T cos) v - (W^T sin) (u x v) + (W^T (1 - cos)) (u.v) u``: four products of the window's weights
    with the angle terms of every offset at once, instead of f sample by sample and offset by offset: the same
    numbers but for the order of the sums, within their rounding bound 2 (n + 4) eps sum |W| |terms|
    (tests/cli/test_diagnose_fast_paths.py; measured on a seed-000 session: <= 9e-14 of sum |W| |f|, a few per cent
    of the bound)."""
    deltas = np.asarray(deltas, dtype=float)
    u, C0 = np.asarray(w.axis, float), w.attitude
    vf, vw = C0.T @ ga, C0.T @ wg
    ra, rg = rows_of("accel", w), rows_of("gyro", w)
    Wt = w.W[:, :max(ra, rg)].T
    terms_a = np.stack([vf, -_cross(u, vf), (u @ vf) * u])                       # rows: cos, sin, 1 - cos
    terms_g = np.stack([vw, -_cross(u, vw), (u @ vw) * u,
                        u / float(earth.DEG_PER_H) * float(TO_MODEL[geom.units_in["gyro"]])])   # and the rate
    xa, xg = np.empty((deltas.size, ra, 3)), np.empty((deltas.size, rg, 3))
    step = max(1, _CHUNK // max(w.n, 1))
    for d0 in range(0, deltas.size, step):
        dd = deltas[d0:d0 + step]
        c, s, r = angles if angles is not None and dd.size == deltas.size else rotation_angles(geom, w, dd)
        red = np.stack([Wt @ a.T for a in (c, s, 1.0 - c, r)], axis=-1)      # (rows, offsets, 4 angle terms)
        xa[d0:d0 + dd.size] = np.einsum("rdk,kj->drj", red[:ra, :, :3], terms_a)
        xg[d0:d0 + dd.size] = np.einsum("rdk,kj->drj", red[:rg], terms_g)
    return xa, xg


BASE_NAMES = tuple(f"{s}:{n}" for s in SENSORS for n in
                   ("M_xx", "M_xy", "M_xz", "M_yx", "M_yy", "M_yz", "M_zx", "M_zy", "M_zz", "b_x", "b_y", "b_z"))


def base_design(geom: Geometry, xr: dict, ones: dict) -> np.ndarray:
    """Design matrix (n_obs, 24) of the base model N = M x + b, columns [accel M (row-major), accel b,
    gyro M, gyro b]."""
    o = geom.obs
    X = np.zeros((o["n"], 24))
    for k in range(o["n"]):
        si, a, wi, r = o["sensor"][k], o["axis"][k], o["window"][k], o["row"][k]
        s = SENSORS[si]
        c0 = 12 * si
        X[k, c0 + 3 * a:c0 + 3 * a + 3] = xr[s][wi][r]
        X[k, c0 + 9 + a] = ones[s][wi][r]
    return X
