"""Observations, noise covariance and the effect library of the mismatch diagnosis (:mod:`calib.diagnosis.diagnose`).

Everything here is a function of the recording's *geometry* (segment table, table angle, temperature,
site) and, for the effect signatures, of the base calibration (K E, b); the data enter only through
:func:`reduce_data` and the noise fit. The diagnosis is then linear algebra on segment means.

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
(:func:`covariance_parts`).

Inputs of the base model: body specific force ``f^b = C_n^b (0, 0, g)`` [input unit, g for counts] and
angular rate ``omega_ib^b = u theta' + C_n^b omega_ie^n`` [deg/h for counts], with ``C_b^n = C0 R_u(theta)``
(``C0`` = ``nominal_attitude`` of the segment, body to ENU) during rotations.

Noise of a window mean (per sensor axis)
-----------------------------------------
From the Allan deviation pooled over the static segments (``allan.adev_pooled``), a model
``AVAR(tau) = 3 Q^2/tau^2 + N^2/tau + K^2 tau/3`` (quantisation, white rate noise, rate random walk; terms
chosen by a penalised fit, :func:`fit_noise`). For observation weights w the covariance is

    Cov_N(o, p) = N^2 / dt * sum_k w_ok w_pk                               (same window)
    Cov_Q(o, p) = Q^2 / dt^2 * sum_k (w_o,k-1 - w_ok)(w_p,k-1 - w_pk)      (same window; phase quantisation)
    Cov_K(o, p) = K^2 * int_0^inf W_o(u) W_p(u) du,  W_o(u) = sum_{k: t_k > u} w_ok   (all windows)

the last one the Brownian (random-walk) covariance ``K^2 min(s, t)``. A bias instability of correlation time
T_c looks like a random walk at tau << T_c (K^2 = 2 sigma_b^2 / T_c); modelling it as one over the whole
session overstates its long-lag variance, so the test is conservative for slow (time-smooth) effects
(bias drift, temperature bias), exact for white noise.

Effect library
--------------
Each candidate is a term of :mod:`calib.sim.effects` (ids verbatim) with its own parameters in the registry's
units. Its *signature* is the derivative of the predicted observations with respect to those parameters at
the base solution: the registry's own term evaluated at the window samples with unit parameters, times the
scale factor K_i, reduced like the data. Truth effects: ``latitude_error`` and ``gravity_error`` by central
differences of the base prediction; ``time_offset`` exactly as a function of the offset (the IMU sample at
t measures the table motion at t + offset: the table angle is re-evaluated on a spline of the recorded
angle, including the neighbouring spin-up / spin-down) on a grid, interpolated by cubic splines.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, optimize
from scipy.interpolate import CubicSpline

from calib.signal import allan
from calib.core import earth
from calib.sim import effects
from calib.signal import noisecov
from calib.core.earth import STANDARD_GRAVITY
from calib.signal.segments import RATE_UNIT_OF_INCREMENT, input_unit_for

SENSORS = ("accel", "gyro")
AXES = ("x", "y", "z")
ROWS = ("mean", "cos", "sin")
#: registry input units: accel g, gyro deg/h; factor from the registry unit to a model input unit
_TO_MODEL = {"g": 1.0, "m s-2": STANDARD_GRAVITY, "deg h-1": 1.0, "rad s-1": earth.DEG_PER_H,
             "deg s-1": 1.0 / 3600.0}
#: bias-drift warm-up time constants tried (profile likelihood over a grid) [s]
DRIFT_TAUS = (120.0, 300.0, 600.0, 900.0, 1200.0, 1800.0, 2700.0, 3600.0)


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

    @property
    def static(self):
        return [w for w in self.windows if w.kind == "static"]

    @property
    def rotation(self):
        return [w for w in self.windows if w.kind == "rotation"]


def _rodrigues_T(axis, theta, v):
    """R_u(theta)^T v for per-sample angles theta (n,) and a fixed vector v (3,): rotation by -theta."""
    u = np.asarray(axis, float)
    v = np.asarray(v, float)
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    return v[None, :] * c - np.cross(u, v)[None, :] * s + (u @ v) * u[None, :] * (1.0 - c)


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


def _rate_readings(ds, sensor):
    v = ds[sensor]
    kind = v.attrs.get("sample_kind")
    units = v.attrs.get("units")
    fs = float(ds.attrs["sample_rate_hz"])
    y = np.asarray(v.values, dtype=np.float64)
    if kind == "increment":
        return y * fs, RATE_UNIT_OF_INCREMENT.get(units, f"{units} s-1")
    return y, units


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
        if iu not in _TO_MODEL:
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
                cont = cont - cont[i0 - j0]          # 0 at the segment start (the recording's convention)
                th_seg = cont[i0 - j0:i1 - j0 + 1]   # angles at sample starts, i0..i1 (inclusive end)
                spline = CubicSpline((np.arange(j0, j1 + 1) - i0) * dt, np.radians(cont))
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
                                  "calibrate the base model and test anything beyond it)",
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
    build_observations(geom)
    return geom


# =====================================================================================================
# observations
# =====================================================================================================
def _rows_of(sensor: str, w: Window) -> int:
    """Reduction rows used: accel 1 (mean), gyro all (mean, cos, sin when the table angle is known)."""
    return 1 if sensor == "accel" else w.rows


def build_observations(geom: Geometry):
    """Observation metadata (arrays over observations, ordered sensor > axis > window > row)."""
    sen, ax, win, row = [], [], [], []
    for si, s in enumerate(SENSORS):
        for a in range(3):
            for wi, w in enumerate(geom.windows):
                for r in range(_rows_of(s, w)):
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
        r = _rows_of(sensor, w)
        out.append(w.W[:, :r].T @ per_sample[w.i0:w.i1])
    return out


def stack_fast(geom: Geometry, red: dict) -> np.ndarray:
    """Vectorised :func:`stack` (same order)."""
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
        y[s], _ = _rate_readings(ds, s)
        if not np.all(np.isfinite(y[s])):
            raise DiagnosisInputError(f"{geom.source}: variable '{s}' holds NaN or Inf")
        red[s] = reduce_windows(geom, y[s], s)
    return stack_fast(geom, red), y


# =====================================================================================================
# noise model and covariance
# =====================================================================================================
@dataclass
class NoiseFit:
    """Noise model per sensor: Allan result, quantisation Q and white N per axis (output unit), and the slow
    part per axis: ``slow[s][a] = (Tc, sigma)`` -- a Gauss-Markov bias of correlation time Tc [s] and
    standard deviation sigma (Tc = inf: a random walk with K = sigma [unit s^-1/2]); sigma = 0: none."""

    allan: dict
    Q: dict
    N: dict
    slow: dict
    method: str = ""

    def describe(self, sensor, a) -> str:
        tc, sig = self.slow[sensor][a]
        if sig <= 0:
            return "no slow component"
        if math.isinf(tc):
            return f"random walk K = {sig:.4g} {self.allan[sensor].unit} s^-1/2"
        return f"Gauss-Markov bias sigma = {sig:.4g} {self.allan[sensor].unit}, Tc = {tc:g} s"

    def set_level(self, sensor: str, axes, lam: float, tc: float, rho: float):
        """The noise of ``sensor`` on ``axes`` at level ``lam`` (scale of the Allan shape) with a slow part
        of correlation time ``tc`` and relative variance ``rho`` (sigma_slow = sqrt(lam rho))."""
        for a in axes:
            self.scale[sensor][a] = lam
            self.N[sensor][a] = self.N_shape[sensor][a] * math.sqrt(lam)
            self.Q[sensor][a] = self.Q_shape[sensor][a] * math.sqrt(lam)
            self.slow[sensor][a] = (tc, math.sqrt(lam * rho))


#: correlation times tried for the slow part of the noise [s]. Slower variations are, by convention, bias
#: drift: a Gauss-Markov bias with a correlation time beyond the session cannot be told from a drift
SLOW_TCS = (60.0, 120.0, 300.0, 600.0)


def fit_noise(geom: Geometry, y: dict, pulse_counter: dict | None = None) -> NoiseFit:
    """Shape of the fast noise from the Allan deviation pooled over the static windows:
    AVAR = 3Q^2/tau^2 + N^2/tau + K^2 tau/3 fitted by NNLS with weights from the equivalent degrees of
    freedom. For pulse-counter data (integer counts per sample, remainder carried: ``pulse_counter[s]``) the
    quantisation is known, Q = 1/sqrt(12) count (the carried remainder is uniform in [0, 1)), and N, K are
    fitted to tau >= 1 s (where the carry has mixed). The overall level of the fast part and the slow part
    (bias instability) are then estimated from the spread of the segment means themselves
    (:func:`reml_slow`)."""
    res, Q, N, slow = {}, {}, {}, {}
    pulse_counter = pulse_counter or {}
    for s in SENSORS:
        recs = [y[s][w.i0:w.i1] for w in geom.static]
        try:
            A = allan.adev_pooled(recs, geom.fs, unit=geom.units_out[s])
        except allan.AllanError as exc:
            raise DiagnosisInputError(f"{geom.source}: no noise estimate for '{s}' ({exc})",
                                      "the static segments must hold varying samples (not flat data)") from exc
        if pulse_counter.get(s):
            q = 1.0 / math.sqrt(12.0)
            sel = A.tau >= 1.0
            if sel.sum() < 3:
                sel = np.ones_like(A.tau, dtype=bool)
            tau, edf = A.tau[sel], A.edf[sel]
            B = np.column_stack([1.0 / tau, tau / 3.0])
            Nq, Kq = np.zeros(3), np.zeros(3)
            for a in range(3):
                av = A.avar[sel, a] - 3.0 * q**2 / tau**2
                w = np.sqrt(edf / 2.0) / A.avar[sel, a]
                c, _ = optimize.nnls(B * w[:, None], av * w)
                for _ in range(2):
                    w = np.sqrt(edf / 2.0) / np.maximum(B @ c + 3.0 * q**2 / tau**2, 1e-300)
                    c, _ = optimize.nnls(B * w[:, None], av * w)
                Nq[a], Kq[a] = math.sqrt(c[0]), math.sqrt(c[1])
            Q[s], N[s] = np.full(3, q), Nq
            slow[s] = [(math.inf, float(Kq[a])) for a in range(3)]
        else:
            m = A.noise_model(("Q", "N", "K"))
            Q[s], N[s] = m.Q.copy(), m.N.copy()
            slow[s] = [(math.inf, float(m.K[a])) for a in range(3)]
        if np.any(~(N[s] > 0)):
            raise DiagnosisInputError(f"{geom.source}: '{s}' white-noise level is zero (flat data?)",
                                      "check the channel; a noise-free channel gives no chi-square")
        res[s] = A
    nf = NoiseFit(res, Q, N, slow, method=(
        "shape of the fast noise (white N, quantisation Q) from the Allan deviation pooled over the static "
        "segments (3Q^2/tau^2 + N^2/tau + K^2 tau/3, NNLS; Q = 1/sqrt(12) count for pulse-counter data); its level "
        "and the slow part of the window means (a Gauss-Markov bias instability, correlation time profiled on a "
        "grid <= 600 s) by restricted maximum likelihood from the contrasts orthogonal to the base model and the "
        "library's attitude-, rate- and angle-dependent terms, once, before any term is tested"))
    nf.scale = {s: np.ones(3) for s in SENSORS}
    nf.N_shape = {s: N[s].copy() for s in SENSORS}
    nf.Q_shape = {s: Q[s].copy() for s in SENSORS}
    return nf


def gm_part(geom: Geometry, sensor: str, tc: float):
    """Covariance structure (unit variance) of a Gauss-Markov bias of correlation time ``tc`` over one axis'
    observations: exact for the window means (closed form of the double integral of exp(-|s-t|/tc)), its
    high-frequency (random-walk, K^2 = 2/tc) equivalent for the harmonic rows within their window."""
    ws = geom.windows
    rows = [_rows_of(sensor, w) for w in ws]
    starts = np.cumsum([0] + rows)
    m = starts[-1]
    A = np.zeros((m, m))
    means = starts[:-1]
    A[np.ix_(means, means)] = noisecov.gm_mean_cov([geom.time_s[w.i0] for w in ws], [w.n * geom.dt for w in ws], tc)
    # harmonic rows: within-window random-walk equivalent (K^2 = 2/tc), uncorrelated with the means
    _, _, AK = covariance_parts(geom, sensor, rw_within_only=True)
    for j in range(len(ws)):
        if rows[j] > 1:
            sl = slice(starts[j] + 1, starts[j] + rows[j])
            A[sl, sl] = AK[sl, sl] * (2.0 / tc)
    return A


def slow_structure(parts, geom, sensor, tc, cache=None):
    """Unit structure of the slow part for correlation time ``tc`` (inf: random walk), cached."""
    if math.isinf(tc):
        return parts[sensor][2]
    key = (sensor, tc)
    if cache is not None and key in cache:
        return cache[key]
    A = gm_part(geom, sensor, tc)
    if cache is not None:
        cache[key] = A
    return A


def profile_noise(geom: Geometry, noise: NoiseFit, y, X, parts, cache=None, tcs=SLOW_TCS, *, blocks=None,
                  method: str = "reml", update: bool = True, grid_out: dict | None = None):
    """Profile likelihood of the noise of each sensor given the fixed-effect design ``X``, pooled over the
    sensor's three axis blocks (one level, one bias instability for the triad):

        C_axis = lam (C_fast,axis + rho A_GM(Tc)),   C_fast,axis = N_a^2 A_N + Q_a^2 A_Q  (Allan shape)

    ``lam`` profiled analytically, ``rho`` on a log grid (plus 0) for every Tc in ``tcs`` (per block
    C_fast = L L^T, L^-1 A L^-T = V Lam V^T, so every rho costs O(m)). ``method='reml'``: restricted likelihood of
    the error contrasts orthogonal to X (the noise estimate); ``'ml'``: the full likelihood (to compare
    designs). The slow part is kept only when it beats rho = 0 by a BIC margin (2 parameters).
    Returns {sensor: (-2 log L up to a constant shared by all designs, lam, Tc, rho)}; with ``update`` the noise
    model is set to the optimum (sigma_slow,axis = sqrt(lam rho) N-shape independent). ``grid_out``: a dict
    that receives, per sensor, every grid point as (-2 log L, Tc, rho, lam) (for confidence sets)."""
    cache = {} if cache is None else cache
    out = {}
    keys = blocks if blocks is not None else [(si, a) for si in range(2) for a in range(3)]
    for si, s in enumerate(SENSORS):
        mine = [(sj, a) for sj, a in keys if sj == si]
        if not mine:
            continue
        AN, AQ, _ = parts[s]
        pre = []
        for _, a in mine:
            idx = geom.obs["blocks"][(si, a)]
            Xb = X[idx]
            Xb = Xb[:, np.any(Xb != 0, axis=0)]
            C0 = noise.N_shape[s][a] ** 2 * AN + noise.Q_shape[s][a] ** 2 * AQ
            L0 = np.linalg.cholesky(C0)
            X1 = linalg.solve_triangular(L0, Xb, lower=True)
            y1 = linalg.solve_triangular(L0, y[idx], lower=True)
            U, sv, _ = np.linalg.svd(X1, full_matrices=False)
            X1 = U[:, sv > 1e-9 * sv[0]] if sv.size else U
            pre.append((L0, X1, y1))
        m_tot = sum(p[1].shape[0] for p in pre)
        nfree = sum(p[1].shape[0] - (p[1].shape[1] if method == "reml" else 0) for p in pre)
        best, white = None, None
        for tc in tcs:
            A = slow_structure(parts, geom, s, tc, cache)
            rr_t, ld_t = 0.0, 0.0
            rho = None
            for L0, X1, y1 in pre:
                B = linalg.solve_triangular(L0, linalg.solve_triangular(L0, A, lower=True).T, lower=True)
                lam, V = np.linalg.eigh(0.5 * (B + B.T))
                lam = np.clip(lam, 0.0, None)
                if rho is None:
                    scale = 1.0 / max(lam.max(), 1e-300)
                    rho = np.concatenate([[0.0], scale * np.logspace(-4, 3, 71)])
                Xt, yt = V.T @ X1, V.T @ y1
                d = 1.0 + rho[:, None] * lam[None, :]
                w = 1.0 / d
                XtWX = np.einsum("gm,mi,mj->gij", w, Xt, Xt)
                XtWy = np.einsum("gm,mi,m->gi", w, Xt, yt)
                yWy = np.einsum("gm,m->g", w, yt * yt)
                sol = np.linalg.solve(XtWX, XtWy[..., None])[..., 0]
                rr_t = rr_t + (yWy - np.einsum("gi,gi->g", sol, XtWy))
                ld_t = ld_t + np.sum(np.log(d), axis=1)
                if method == "reml":
                    ld_t = ld_t + np.linalg.slogdet(XtWX)[1]
            lam_hat = rr_t / nfree
            nll = nfree * np.log(lam_hat) + ld_t
            if grid_out is not None:
                grid_out.setdefault(s, []).extend(
                    (float(v), tc, float(r), float(lh)) for v, r, lh in zip(nll, rho, lam_hat))
            if white is None:
                white = (float(nll[0]), math.inf, 0.0, float(lam_hat[0]))
            j = int(np.argmin(nll))
            if best is None or nll[j] < best[0]:
                best = (float(nll[j]), tc, float(rho[j]), float(lam_hat[j]))
        if white[0] - best[0] < 2.0 * math.log(m_tot):
            best = white
        nll_b, tc, rho_b, lam_b = best
        out[s] = (nll_b, lam_b, tc, rho_b)
        if update:
            noise.set_level(s, [a for _, a in mine], lam_b, tc, rho_b)
    return out


def reml_slow(geom: Geometry, noise: NoiseFit, y, X, parts, cache=None, tcs=SLOW_TCS):
    """Noise level and slow part by restricted ML (:func:`profile_noise`), stored in ``noise``."""
    return profile_noise(geom, noise, y, X, parts, cache, tcs, method="reml", update=True)


def covariance_parts(geom: Geometry, sensor: str, rw_within_only: bool = False):
    """Geometry-only matrices (A_N, A_Q, A_K) over one axis' observations of ``sensor`` so that the
    covariance is ``N^2 A_N + Q^2 A_Q + K^2 A_K`` (formulas in the module docstring)."""
    dt = geom.dt
    ws = geom.windows
    rows = [_rows_of(sensor, w) for w in ws]
    m = sum(rows)
    AN = np.zeros((m, m))
    AQ = np.zeros((m, m))
    AK = np.zeros((m, m))
    starts = np.cumsum([0] + rows)
    S = np.zeros(m)         # sum of weights
    I = np.zeros(m)         # int_0^inf W(u) du
    tmid0 = np.zeros(m)
    for j, w in enumerate(ws):
        r = rows[j]
        W = w.W[:, :r]
        sl = slice(starts[j], starts[j] + r)
        AN[sl, sl] = W.T @ W / dt
        pad = np.vstack([np.zeros((1, r)), W, np.zeros((1, r))])
        dW = np.diff(pad, axis=0)
        AQ[sl, sl] = dW.T @ dW / dt**2
        tail = np.cumsum(W[::-1], axis=0)[::-1]          # tail[k] = sum_{j >= k} w_j
        t_first = geom.time_s[w.i0] + 0.5 * dt
        s_w = W.sum(axis=0)
        T1 = tail[1:]
        AK[sl, sl] = np.outer(s_w, s_w) * t_first + T1.T @ T1 * dt
        S[sl] = s_w
        I[sl] = s_w * t_first + T1.sum(axis=0) * dt
        tmid0[sl] = t_first
    if rw_within_only:
        return AN, AQ, AK
    # cross-window random-walk terms: Cov = K^2 S_later I_earlier
    for j, w in enumerate(ws):
        slj = slice(starts[j], starts[j] + rows[j])
        for k in range(j + 1, len(ws)):
            slk = slice(starts[k], starts[k] + rows[k])
            if tmid0[slk.start] >= tmid0[slj.start]:
                blk = np.outer(I[slj], S[slk])
            else:
                blk = np.outer(S[slj], I[slk])
            AK[slj, slk] = blk
            AK[slk, slj] = blk.T
    return AN, AQ, AK


def covariance_blocks(geom: Geometry, noise: NoiseFit, parts, cache=None):
    """Per (sensor index, axis) covariance blocks of the observations and their Cholesky factors."""
    C, L = {}, {}
    for si, s in enumerate(SENSORS):
        AN, AQ, _ = parts[s]
        for a in range(3):
            tc, sig = noise.slow[s][a]
            c = noise.N[s][a] ** 2 * AN + noise.Q[s][a] ** 2 * AQ
            if sig > 0:
                c = c + sig**2 * slow_structure(parts, geom, s, tc, cache)
            C[(si, a)] = c
            L[(si, a)] = np.linalg.cholesky(c)
    return C, L


# =====================================================================================================
# base model inputs and design
# =====================================================================================================
def site_vectors(geom: Geometry, latitude_deg=None, gravity_m_s2=None):
    """Gravity (0, 0, g) and Earth rate omega_ie^n in the model input units (accel, gyro)."""
    lat = geom.latitude_deg if latitude_deg is None else latitude_deg
    g = geom.gravity_m_s2 if gravity_m_s2 is None else gravity_m_s2
    ga = np.array([0.0, 0.0, g]) / STANDARD_GRAVITY * _TO_MODEL[geom.units_in["accel"]]
    wg = earth.earth_rate_enu(math.radians(lat)) / earth.DEG_PER_H * _TO_MODEL[geom.units_in["gyro"]]
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
    gyro_unit = _TO_MODEL[geom.units_in["gyro"]]
    if w.spline is not None:
        tk = k * geom.dt + delta_s
        th0 = w.spline(tk)
        th1 = w.spline(tk + geom.dt)
        thm = w.spline(tk + 0.5 * geom.dt)
        rate = (th1 - th0) / geom.dt                      # rad/s, sample average
        acc = w.spline(tk + 0.5 * geom.dt, 2) if need_accel else np.zeros(n)
    else:
        thm = w.theta_mid[k]
        rate = np.full(n, math.radians(w.rate_deg_s))
        acc = np.zeros(n)
    f = _rodrigues_T(u, thm, C0.T @ ga)
    om = _rodrigues_T(u, thm, C0.T @ wg) + np.outer(rate, u) / earth.DEG_PER_H * gyro_unit
    return f, om, np.outer(rate, u), np.outer(acc, u)


def reduced_inputs(geom: Geometry, delta_s=0.0, latitude_deg=None, gravity_m_s2=None, only_rotation=False):
    """Reduced inputs per sensor: list per window of (rows, 3) [model input units], and the bias rows
    (rows,) = W^T 1."""
    xa, xg, one_a, one_g = [], [], [], []
    ga, wg = site_vectors(geom, latitude_deg, gravity_m_s2)
    for w in geom.windows:
        ra, rg = _rows_of("accel", w), _rows_of("gyro", w)
        sa, sg_ = w.W[:, :ra].sum(axis=0), w.W[:, :rg].sum(axis=0)
        one_a.append(sa)
        one_g.append(sg_)
        if only_rotation and w.kind != "rotation":
            xa.append(None)
            xg.append(None)
            continue
        if w.kind == "static" or w.attitude is None:
            C = w.attitude if w.attitude is not None else np.eye(3)
            xa.append(sa[:, None] * (C.T @ ga)[None, :])
            xg.append(sg_[:, None] * (C.T @ wg)[None, :])
            continue
        f, om, _, _ = window_inputs(geom, w, delta_s, latitude_deg, gravity_m_s2, need_accel=False)
        xa.append(w.W[:, :ra].T @ f)
        xg.append(w.W[:, :rg].T @ om)
    return {"accel": xa, "gyro": xg}, {"accel": one_a, "gyro": one_g}


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


# =====================================================================================================
# effect library
# =====================================================================================================
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


def _nodes(geom: Geometry, w: Window):
    if w.kind == "static":
        m = min(w.n, 64)
        return ((np.arange(m) + 0.5) * w.n / m).astype(int)
    step = abs(w.rate_deg_s) * geom.dt
    stride = max(1, int(0.5 / step)) if step > 0 else 1
    return np.arange(stride // 2, w.n, stride)


def sample_context(geom: Geometry) -> SampleContext:
    ts, fs_, ws_, wnb, dwnb, temps, slices, Wsub = [], [], [], [], [], [], [], []
    pos = 0
    ca = _TO_MODEL[geom.units_in["accel"]]
    cg = _TO_MODEL[geom.units_in["gyro"]]
    for w in geom.windows:
        idx = _nodes(geom, w)
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
    out = np.zeros(geom.obs["n"])
    si = SENSORS.index(sensor)
    dd = d * (Kdiag * conv)[None, :]
    red = [ctx.Wsub[j][:, :_rows_of(sensor, w)].T @ dd[ctx.slices[j]] for j, w in enumerate(geom.windows)]
    vec = np.concatenate([np.concatenate([r[:, a] for r in red]) for a in range(3)])
    blk = np.concatenate([geom.obs["blocks"][(si, a)] for a in range(3)])
    out[blk] = vec
    return out


def is_shape_parameter(key: str) -> bool:
    """Registry keys that set the shape of an effect (time constants, the reference temperature), not its
    size: they are neither zeroed for a unit column nor scaled with the magnitude."""
    return key.endswith("tau_s") or key == "T_ref_degC"


def _zero_params(eid):
    p = copy.deepcopy(effects.REGISTRY[eid].defaults)
    for k, v in p.items():
        if is_shape_parameter(k):
            continue
        p[k] = (np.zeros_like(np.asarray(v, float))).tolist() if np.ndim(v) else 0.0
    return p


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
    conv = {s: _TO_MODEL[geom.units_in[s]] for s in SENSORS}
    KE = {s: np.asarray(M[s], float) for s in SENSORS}
    Kd = {s: np.diag(KE[s]).copy() for s in SENSORS}
    Emat = {s: KE[s] / Kd[s][:, None] for s in SENSORS}
    y_a = effects.rows_times(ctx.f, Emat["accel"])
    y_g = effects.rows_times(ctx.w, Emat["gyro"])
    tctx = ctx.temperature if ctx.temperature is not None else np.full(ctx.t.shape, 25.0)
    sctx = effects.SensorContext(ctx.t, ctx.f, ctx.w, y_a, y_g, ctx.w_nb, ctx.dw_nb, tctx, Emat["accel"],
                                 Emat["gyro"])

    def column(eid, sensor, p):
        da, dg = effects.REGISTRY[eid].apply(sctx, p)
        d = da if sensor == "accel" else dg
        return _reduce_term(geom, ctx, d, sensor, Kd[sensor], conv[sensor])

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
            for e in entries:
                p = _zero_params(eid)
                arr = np.zeros(np.shape(effects.REGISTRY[eid].defaults[key]))
                arr[e] = 1.0
                p[key] = arr.tolist()
                cols.append(column(eid, sensor, p))
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
        trend_cols = []
        for i in range(3):
            p = _zero_params("bias_drift")
            v = [0.0, 0.0, 0.0]
            v[i] = 1.0
            p[skey] = v
            trend_cols.append(column("bias_drift", sensor, p))
        for tau in DRIFT_TAUS:
            cols = []
            for i in range(3):
                p = _zero_params("bias_drift")
                v = [0.0, 0.0, 0.0]
                v[i] = 1.0
                p[wkey] = v
                p[tkey] = tau
                cols.append(column("bias_drift", sensor, p))
            c.S_by_tau[tau] = np.column_stack(cols + trend_cols)
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
        vals = []
        for d in grid:
            xr, _ = reduced_inputs(geom, delta_s=float(d), only_rotation=True)
            vals.append(np.concatenate([np.concatenate([xr[s][j].ravel() for j in rot_idx]) for s in SENSORS]))
        off.offset = OffsetModel(grid, np.array(vals), rot_idx, geom)
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
                for r in range(_rows_of(s, w)):
                    layout.append((s, j, r))
        self.layout = layout
        o = geom.obs
        self.obs_index = {}
        for k in range(o["n"]):
            wi = o["window"][k]
            if geom.windows[wi].kind == "rotation":
                self.obs_index.setdefault((SENSORS[o["sensor"][k]], wi, o["row"][k]), []).append(k)

    @property
    def bounds(self):
        return float(self.grid[0]), float(self.grid[-1])

    def reduced(self, delta, deriv=0):
        v = self.spline(float(delta), deriv) if deriv else self.spline(float(delta))
        return v.reshape(-1, 3)

    def patch_design(self, X, delta):
        """Overwrite the input columns of the rotation observations in a copy of the base design X."""
        X = X.copy()
        v = self.reduced(delta)
        for (s, j, r), x in zip(self.layout, v):
            c0 = 12 * SENSORS.index(s)
            for k in self.obs_index[(s, j, r)]:
                a = self.geom.obs["axis"][k]
                X[k, c0 + 3 * a:c0 + 3 * a + 3] = x
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
