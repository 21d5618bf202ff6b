"""Extra physics of the synthetic unit: named error terms beyond N = K E x + b, each off by default.

The ids are used verbatim in the configuration (``effects: {id: {enabled: true, <params>}}``) and by the
diagnosis stage. Two kinds:

* ``truth`` effects change the *world* the simulator integrates (site latitude and gravity, clock offset):
  ``apply(site: SiteTruth, params) -> SiteTruth``.
* ``sensor`` effects add terms to the per-sensor inputs before the scale factors:
  ``apply(ctx: SensorContext, params) -> (d_accel [g] (n, 3) | None, d_gyro [deg/h] (n, 3) | None)``.

Sensor model with effects (sensor axis i; Liu 2021 eqs. 1-4 plus the terms of this module)::

    y   = E x                                   input along the sensor axes (g or deg/h)
    N_i = K_i (y_i + sum_effects d_i + bias_instability_i + noise_i) + b_i        [count s-1]

Every term is computed from the *clean* inputs (not from another effect's output), so the order of the
effects does not matter and each term adds linearly. Units: specific force in standard g (9.80665 m/s^2),
angular rate in deg/h, temperatures in degC, times in s from power-on (session start). Frames: ``f_b``,
``w_b`` are body-frame (right-front-up) vectors; ``y`` are sensor-axis inputs; lever arms are body-frame
vectors in metres.

Formulas (sensor axis i, j over body axes):

=============================  ===============================================================  ==================
id                             term d_i                                                          parameters (units)
=============================  ===============================================================  ==================
accel_quadratic_nonlinearity   k2_i y_i^2                                                        k2_ug_per_g2 (ug/g^2)
accel_cubic_nonlinearity       k3_i y_i^3                                                        k3_ug_per_g3 (ug/g^3)
accel_scale_asymmetry          d_i |y_i|  (scale K_i (1 + d_i) for y_i > 0, K_i (1 - d_i) below)  asym_ppm (ppm)
accel_cross_coupling           sum_{j != i} C_ij f_i f_j  (body-frame f, pendulous/output-axis    k_cross_ug_per_g2 (ug/g^2,
                               products "K_xy")                                                  3x3, diagonal ignored)
accel_lever_arm                E_a[i] . (w_nb x (w_nb x r_i) + dw_nb x r_i) / g0                lever_arms_m (m, 3x3,
                               (size effect: proof mass i at body position r_i from the table     row i = r_i, body frame)
                               axes; table rate w_nb, angular acceleration dw_nb)
gyro_g_sensitivity             sum_j G_ij f_j  (body-frame specific force in g)                   G_deg_h_per_g (deg/h/g, 3x3)
gyro_scale_asymmetry           d_i |y_i|                                                         asym_ppm (ppm)
gyro_scale_nonlinearity        k_i y_i |y_i| / w_ref,  w_ref = 1 deg/s = 3600 deg/h (scale       k_ppm_per_deg_s (ppm per deg/s)
                               factor grows linearly with |rate|; odd, so it survives the +/-
                               difference of Liu 2021 eq. 25 and differs between 10/20/30 deg/s)
bias_drift                     A_i exp(-t / tau) + s_i t / 3600  per triad (warm-up + trend)      accel_warmup_ug (ug), accel_tau_s,
                                                                                                 accel_trend_ug_per_h (ug/h), gyro_...
                                                                                                 (deg/h, s, deg/h per h)
temperature_sensitivity        kb_i (T - T_ref) + ks_i 1e-6 (T - T_ref) y_i  per triad; T(t) is   T_ref_degC, accel_bias_ug_per_degC,
                               the session's temperature channel (always recorded)               accel_scale_ppm_per_degC, gyro_...
latitude_error    (truth)      true latitude = recorded latitude + delta (Earth rate and gravity  delta_lat_deg (deg)
                               follow the true latitude; the file keeps the assumed one)
gravity_error     (truth)      true |g| = WGS-84 normal gravity at the true latitude + delta      delta_g_m_s2 (m/s^2)
time_offset       (truth)      the IMU sample stamped t measures the motion at t + offset; the   offset_s (s)
                               table record (segment_index, table_angle) stays at t
=============================  ===============================================================  ==================
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace
from typing import Callable, NamedTuple

import numpy as np

from calib.core.earth import STANDARD_GRAVITY
from calib.core.earth import normal_gravity

UG = 1e-6     # micro-g in g
PPM = 1e-6
W_REF_DEG_H = 3600.0  # 1 deg/s in deg/h


@dataclass(frozen=True)
class SiteTruth:
    """The world as the simulator integrates it (after truth effects)."""

    latitude_deg: float        # true geodetic latitude [deg]
    height_m: float            # ellipsoidal height [m]
    gravity_m_s2: float        # true magnitude of local gravity [m/s^2]
    time_offset_s: float = 0.0  # IMU clock ahead of the table record [s]


@dataclass
class SensorContext:
    """Clean inputs at the quadrature nodes (n nodes)."""

    t: np.ndarray            # (n,) sensor time from the session start [s]
    f_b: np.ndarray          # (n, 3) body specific force at the table-axis point [g]
    w_b: np.ndarray          # (n, 3) body angular rate omega_ib^b [deg/h]
    y_a: np.ndarray          # (n, 3) accelerometer sensor-axis inputs E_a f_b [g]
    y_g: np.ndarray          # (n, 3) gyro sensor-axis inputs E_g w_b [deg/h]
    w_nb: np.ndarray         # (n, 3) table rate omega_nb^b [rad/s]
    dw_nb: np.ndarray        # (n, 3) table angular acceleration [rad/s^2]
    temperature: np.ndarray  # (n,) unit temperature [degC]
    E_a: np.ndarray          # (3, 3) accelerometer installation matrix
    E_g: np.ndarray          # (3, 3) gyro installation matrix


class Effect(NamedTuple):
    """Registry entry: ``apply, defaults`` first (so ``apply, defaults = REGISTRY[id][:2]``)."""

    apply: Callable
    defaults: dict
    stage: str   # 'truth' | 'sensor'
    units: dict
    doc: str


def rows_times(x, m):
    """``x @ m.T`` for (n, 3) rows and a 3x3 matrix, written out elementwise.

    Each output element is computed by the same three products and two sums whatever ``n`` is, so a
    chunked evaluation gives bit-identical results for every chunk size (a BLAS product need not).
    """
    m = np.asarray(m, dtype=float)
    x0, x1, x2 = x[:, 0:1], x[:, 1:2], x[:, 2:3]
    return x0 * m[:, 0] + x1 * m[:, 1] + x2 * m[:, 2]


# ---- accelerometer terms --------------------------------------------------------------------------

def _accel_quadratic(ctx: SensorContext, p):
    return np.asarray(p["k2_ug_per_g2"]) * UG * ctx.y_a**2, None


def _accel_cubic(ctx: SensorContext, p):
    return np.asarray(p["k3_ug_per_g3"]) * UG * ctx.y_a**3, None


def _accel_asym(ctx: SensorContext, p):
    return np.asarray(p["asym_ppm"]) * PPM * np.abs(ctx.y_a), None


def _accel_cross(ctx: SensorContext, p):
    c = np.array(p["k_cross_ug_per_g2"], dtype=float) * UG
    np.fill_diagonal(c, 0.0)
    f = ctx.f_b
    # d_i = f_i * sum_j C_ij f_j
    return f * rows_times(f, c), None


def _cross_columns(a0, a1, a2, b0, b1, b2):
    """``a x b`` by components (columns or numbers): the products and differences of ``np.cross``, in its order,
    without its broadcasting and temporaries."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


def _accel_lever(ctx: SensorContext, p):
    r = np.asarray(p["lever_arms_m"], dtype=float)  # row i = position of proof mass i [m], body frame
    w, dw = np.asarray(ctx.w_nb, dtype=float), np.asarray(ctx.dw_nb, dtype=float)
    wc, dwc = (w[:, 0], w[:, 1], w[:, 2]), (dw[:, 0], dw[:, 1], dw[:, 2])
    out = np.empty_like(ctx.y_a)
    for i in range(3):
        ri = tuple(r[i])
        c = _cross_columns(*wc, *ri)
        d = _cross_columns(*wc, *c)
        e = _cross_columns(*dwc, *ri)
        m = np.asarray(ctx.E_a[i], dtype=float)
        # a = w x (w x r) + dw x r [m/s^2, body frame]; its component along E_a[i] as rows_times forms it
        out[:, i] = ((d[0] + e[0]) * m[0] + (d[1] + e[1]) * m[1] + (d[2] + e[2]) * m[2]) / STANDARD_GRAVITY
    return out, None


# ---- gyro terms -----------------------------------------------------------------------------------

def _gyro_gsens(ctx: SensorContext, p):
    g = np.asarray(p["G_deg_h_per_g"], dtype=float)
    return None, rows_times(ctx.f_b, g)


def _gyro_asym(ctx: SensorContext, p):
    return None, np.asarray(p["asym_ppm"]) * PPM * np.abs(ctx.y_g)


def _gyro_nonlin(ctx: SensorContext, p):
    return None, np.asarray(p["k_ppm_per_deg_s"]) * PPM * ctx.y_g * np.abs(ctx.y_g) / W_REF_DEG_H


# ---- both triads ----------------------------------------------------------------------------------

def _positive_zeros(x) -> bool:
    """Whether every entry of ``x`` is +0.0."""
    return not np.any(x) and not np.any(np.signbit(x))


def _drift_triad(t, A, tau, S):
    """``A exp(-t / tau) + S t / 3600`` (n, 3) for times ``t`` (n,). A part whose coefficients are all +0.0 is a
    zero of known sign where ``t`` is finite (and ``exp(-t / tau)`` too): it is then not evaluated, and the sum
    is the other part plus +0.0, the same numbers to the bit (the library evaluates one part of one triad at a
    time)."""
    A, S = np.asarray(A), np.asarray(S)
    tt = t[:, None]
    zA, zS = _positive_zeros(A), _positive_zeros(S)
    if zA or zS:
        lo, hi = float(np.min(t)), float(np.max(t))
        # A exp(-t/tau) = +0 for A = +0: exp finite; S t = +0 for S = +0: t > 0 and finite (NaN fails each test)
        safe = math.isfinite(hi) and float(tau) > 0.0 and lo > -700.0 * float(tau)
        if safe and zA and zS and lo > 0.0:
            return np.zeros((t.shape[0], 3))
        if safe and zA:
            return S * tt / 3600.0 + 0.0
        if safe and zS and lo > 0.0:
            return A * np.exp(-tt / tau) + 0.0
    return A * np.exp(-tt / tau) + S * tt / 3600.0


def _bias_drift(ctx: SensorContext, p):
    da = _drift_triad(ctx.t, p["accel_warmup_ug"], p["accel_tau_s"], p["accel_trend_ug_per_h"]) * UG
    dg = _drift_triad(ctx.t, p["gyro_warmup_deg_h"], p["gyro_tau_s"], p["gyro_trend_deg_h_per_h"])
    return da, dg


def _temperature(ctx: SensorContext, p):
    dT = (ctx.temperature - p["T_ref_degC"])[:, None]
    da = (np.asarray(p["accel_bias_ug_per_degC"]) * UG * dT
          + np.asarray(p["accel_scale_ppm_per_degC"]) * PPM * dT * ctx.y_a)
    dg = (np.asarray(p["gyro_bias_deg_h_per_degC"]) * dT
          + np.asarray(p["gyro_scale_ppm_per_degC"]) * PPM * dT * ctx.y_g)
    return da, dg


# ---- truth (world) effects ------------------------------------------------------------------------

def _latitude_error(site: SiteTruth, p) -> SiteTruth:

    lat = site.latitude_deg + float(p["delta_lat_deg"])
    if not -90.0 <= lat <= 90.0:
        raise ValueError(f"effects.latitude_error.delta_lat_deg: true latitude {lat} outside [-90, 90]")
    return replace(site, latitude_deg=lat, gravity_m_s2=float(normal_gravity(math.radians(lat), site.height_m)))


def _gravity_error(site: SiteTruth, p) -> SiteTruth:
    return replace(site, gravity_m_s2=site.gravity_m_s2 + float(p["delta_g_m_s2"]))


def _time_offset(site: SiteTruth, p) -> SiteTruth:
    return replace(site, time_offset_s=site.time_offset_s + float(p["offset_s"]))


REGISTRY: dict[str, Effect] = {
    "accel_quadratic_nonlinearity": Effect(
        _accel_quadratic, {"k2_ug_per_g2": [50.0, -40.0, 30.0]}, "sensor", {"k2_ug_per_g2": "ug g-2"},
        "d_i = k2_i y_i^2 (accelerometer second-order scale nonlinearity)"),
    "accel_cubic_nonlinearity": Effect(
        _accel_cubic, {"k3_ug_per_g3": [20.0, -15.0, 10.0]}, "sensor", {"k3_ug_per_g3": "ug g-3"},
        "d_i = k3_i y_i^3 (accelerometer third-order scale nonlinearity)"),
    "accel_scale_asymmetry": Effect(
        _accel_asym, {"asym_ppm": [100.0, -80.0, 60.0]}, "sensor", {"asym_ppm": "ppm"},
        "d_i = asym_i |y_i| (scale K(1+asym) for positive, K(1-asym) for negative input)"),
    "accel_cross_coupling": Effect(
        _accel_cross, {"k_cross_ug_per_g2": [[0.0, 30.0, -20.0], [25.0, 0.0, 15.0], [-20.0, 20.0, 0.0]]},
        "sensor", {"k_cross_ug_per_g2": "ug g-2"},
        "d_i = sum_{j!=i} C_ij f_i f_j with body-frame specific force f in g"),
    "accel_lever_arm": Effect(
        _accel_lever, {"lever_arms_m": [[0.04, 0.01, -0.02], [-0.01, 0.04, -0.02], [0.01, -0.01, 0.03]]},
        "sensor", {"lever_arms_m": "m"},
        "d_i = E_a[i].(w x (w x r_i) + dw x r_i)/g0, r_i body-frame position of proof mass i"),
    "gyro_g_sensitivity": Effect(
        _gyro_gsens, {"G_deg_h_per_g": [[0.005, 0.002, -0.001], [-0.002, 0.004, 0.001], [0.001, -0.001, 0.006]]},
        "sensor", {"G_deg_h_per_g": "deg h-1 g-1"},
        "d_i = sum_j G_ij f_j, body-frame specific force in g"),
    "gyro_scale_asymmetry": Effect(
        _gyro_asym, {"asym_ppm": [20.0, -15.0, 10.0]}, "sensor", {"asym_ppm": "ppm"},
        "d_i = asym_i |y_i|"),
    "gyro_scale_nonlinearity": Effect(
        _gyro_nonlin, {"k_ppm_per_deg_s": [3.0, -2.0, 2.0]}, "sensor", {"k_ppm_per_deg_s": "ppm (deg s-1)-1"},
        "d_i = k_i y_i |y_i| / (3600 deg/h)"),
    "bias_drift": Effect(
        _bias_drift,
        {"accel_warmup_ug": [30.0, -20.0, 15.0], "accel_tau_s": 900.0, "accel_trend_ug_per_h": [4.0, -3.0, 2.0],
         "gyro_warmup_deg_h": [0.01, -0.008, 0.006], "gyro_tau_s": 1200.0,
         "gyro_trend_deg_h_per_h": [0.001, -0.0008, 0.0005]},
        "sensor",
        {"accel_warmup_ug": "ug", "accel_tau_s": "s", "accel_trend_ug_per_h": "ug h-1",
         "gyro_warmup_deg_h": "deg h-1", "gyro_tau_s": "s", "gyro_trend_deg_h_per_h": "deg h-1 h-1"},
        "d_i(t) = A_i exp(-t/tau) + s_i t/3600 per triad"),
    "temperature_sensitivity": Effect(
        _temperature,
        {"T_ref_degC": 25.0, "accel_bias_ug_per_degC": [2.0, -3.0, 1.5], "accel_scale_ppm_per_degC": [10.0, -8.0, 12.0],
         "gyro_bias_deg_h_per_degC": [0.002, -0.001, 0.0015], "gyro_scale_ppm_per_degC": [1.0, -0.8, 0.6]},
        "sensor",
        {"T_ref_degC": "degC", "accel_bias_ug_per_degC": "ug degC-1", "accel_scale_ppm_per_degC": "ppm degC-1",
         "gyro_bias_deg_h_per_degC": "deg h-1 degC-1", "gyro_scale_ppm_per_degC": "ppm degC-1"},
        "d_i = kb_i (T - T_ref) + ks_i 1e-6 (T - T_ref) y_i per triad"),
    "latitude_error": Effect(
        _latitude_error, {"delta_lat_deg": 0.5}, "truth", {"delta_lat_deg": "deg"},
        "true latitude = recorded latitude + delta; Earth rate and normal gravity follow the true latitude"),
    "gravity_error": Effect(
        _gravity_error, {"delta_g_m_s2": 5e-4}, "truth", {"delta_g_m_s2": "m s-2"},
        "true |g| = normal gravity (at the true latitude) + delta"),
    "time_offset": Effect(
        _time_offset, {"offset_s": 0.05}, "truth", {"offset_s": "s"},
        "IMU sample stamped t measures the motion at t + offset; the table record stays at t"),
}

#: order in which truth effects are applied (latitude before gravity: the anomaly adds to the new gamma)
TRUTH_ORDER = ("latitude_error", "gravity_error", "time_offset")


class EffectConfigError(ValueError):
    """A bad ``effects`` entry; the message names the config key and the fix."""


def resolve(effects_cfg: dict | None, where: str = "effects") -> dict[str, dict]:
    """Enabled effects with their full parameters (defaults merged), validated.

    ``effects_cfg`` maps id to ``true`` / ``false`` or to a dict of parameters with an optional
    ``enabled`` (default ``true`` when the entry is present). Unknown ids or keys and wrong shapes raise
    :class:`EffectConfigError` naming ``<where>.<id>.<key>``.
    """
    out: dict[str, dict] = {}
    for eid, entry in (effects_cfg or {}).items():
        if eid not in REGISTRY:
            raise EffectConfigError(f"{where}.{eid}: unknown effect id; known ids: {', '.join(REGISTRY)}")
        if isinstance(entry, bool):
            entry = {"enabled": entry}
        if entry is None:
            entry = {}
        if not isinstance(entry, dict):
            raise EffectConfigError(f"{where}.{eid}: expected true/false or a mapping of parameters, got {entry!r}")
        entry = dict(entry)
        enabled = entry.pop("enabled", True)
        if not isinstance(enabled, bool):
            raise EffectConfigError(f"{where}.{eid}.enabled: expected true or false, got {enabled!r}")
        defaults = REGISTRY[eid].defaults
        params = copy.deepcopy(defaults)
        for k, v in entry.items():
            if k not in defaults:
                raise EffectConfigError(f"{where}.{eid}.{k}: unknown parameter; allowed: {', '.join(defaults)}")
            want = np.shape(defaults[k])
            arr = np.asarray(v, dtype=float) if not isinstance(v, str) else None
            if arr is None or arr.shape != want or not np.all(np.isfinite(arr)):
                raise EffectConfigError(f"{where}.{eid}.{k}: expected finite numbers of shape {want or 'scalar'}"
                                        f" ({REGISTRY[eid].units.get(k, '')}), got {v!r}")
            params[k] = arr.tolist() if want else float(arr)
        for k in ("accel_tau_s", "gyro_tau_s"):
            if k in params and not params[k] > 0:
                raise EffectConfigError(f"{where}.{eid}.{k}: time constant must be positive, got {params[k]}")
        if enabled:
            out[eid] = params
    return out


def apply_truth(site: SiteTruth, resolved: dict[str, dict]) -> SiteTruth:
    """Apply the enabled truth effects in :data:`TRUTH_ORDER`."""
    for eid in TRUTH_ORDER:
        if eid in resolved:
            site = REGISTRY[eid].apply(site, resolved[eid])
    return site


def sensor_terms(ctx: SensorContext, resolved: dict[str, dict]):
    """Sum of the enabled sensor terms: ``(d_accel [g], d_gyro [deg/h])``, each (n, 3)."""
    da = np.zeros_like(ctx.y_a)
    dg = np.zeros_like(ctx.y_g)
    for eid, p in resolved.items():
        eff = REGISTRY[eid]
        if eff.stage != "sensor":
            continue
        a, g = eff.apply(ctx, p)
        if a is not None:
            da += a
        if g is not None:
            dg += g
    return da, dg
