"""Synthetic sessions of the Liu 2021 unit and the He 2019 stationary navigation data.

(Kept as one module of ~770 lines on purpose: the calibration-session and stationary generators share one
noise-and-quantisation engine, one configuration checker and one truth-sidecar writer, whose private state
would otherwise have to cross module boundaries.)

Three generators, all deterministic functions of ``(cfg, seed)``:

* :func:`simulate_calibration_session` — the Liu 2021 calibration path (24 static positions and the ±
  rotation windows, :mod:`calib.sim.trajectory`) as a ``calib-recording-1`` file of integer pulse counts.
* :func:`simulate_static_session` mode ``physical`` — He 2019 §IV.A: a stationary unit, increments
  dtheta [rad] and dv [m/s] (float64), constant gyro drift, gyro random walk, accelerometer bias.
* :func:`simulate_static_session` mode ``counts`` — the calibration unit (same :class:`TriadModel` pair,
  noise model, effects and quantisation) at rest, for Liu 2021's static navigation check (§4).

Sensor output (Liu 2021 eqs. 1-4, with the terms of :mod:`calib.sim.effects`), sensor axis i::

    N_i(t) = K_i (y_i(t) + d_i(t) + beta_i(t) + n_i(t)) + b_i          [count s-1]
    y      = E x,  x = f^b / g0 [g]  (accel)  or  omega_ib^b [deg/h]  (gyro)

with ``beta`` the bias instability (first-order Gauss-Markov, or random walk) and ``n`` white noise
(accel velocity random walk, gyro angle random walk), both referred to the input.

Sample k covers ``[k dt, (k+1) dt)``. Its increment is ``I_k = int N dt`` over the interval: the clean part by
Gauss-Legendre quadrature at ``n_nodes`` points of the exact kinematics (3 for the calibration path;
exact for the piecewise-smooth motion to ~1e-6 count because every primitive boundary is on the sample
grid), the noise as per-sample increments (white: variance ``sigma^2 dt``; bias: ``beta_k dt``).
Quantisation is a pulse counter: the running sum of ``I_k`` plus a carried fraction is floored, the integer
step is emitted as the sample's count (int32) and the remainder ``r`` in ``[0, 1)`` is carried, so
``|sum_k c_k - sum_k I_k| < 1`` count at every sample.

Noise determinism: the standard normals of sample k come from block ``k // NOISE_BLOCK`` of a generator
``PCG64(SeedSequence(seed, spawn_key=(stream, block)))``; the Gauss-Markov recursion, the quantiser
carry and the quadrature times depend only on the sample index. So the output does not depend on the
chunk size used to write the file.

Default noise (navigation-grade quartz accelerometers and FOGs; all in ``cfg['noise']``):

=================================  ===========  ==========================================================
key                                default      meaning
=================================  ===========  ==========================================================
accel_vrw_ug_rthz                  10.0         accel white noise PSD^(1/2) [ug/sqrt(Hz)] (VRW)
accel_bias_instability_ug          5.0          accel bias instability: stationary sigma of beta [ug]
accel_bias_corr_time_s             300.0        its correlation time [s] (Gauss-Markov)
gyro_arw_deg_rth                   0.002        gyro angle random walk [deg/sqrt(h)]
gyro_bias_instability_deg_h        0.003        gyro bias instability: stationary sigma of beta [deg/h]
gyro_bias_corr_time_s              600.0        its correlation time [s]
bias_model                         gauss_markov gauss_markov (stationary, starts in its stationary law) |
                                                random_walk (starts at 0; sigma reached after corr_time_s)
quantize                           true         pulse-counter int32 counts; false: float64 counts
=================================  ===========  ==========================================================

The Allan-deviation maximum of a Gauss-Markov bias of sigma s and correlation time T is about 0.62 s at
an averaging time of about 1.9 T; the "bias instability" keys set s directly (the simple reading).
"""
from __future__ import annotations

import copy
import math
import time as _time
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np
import xarray as xr

from calib.core import earth
from calib.sim import effects
from calib.io import recording
from calib.io.atomic import write_json
from calib.io.netcdf import CF_VERSION, provenance
from calib.core.earth import STANDARD_GRAVITY
from calib.core.triad import OFFDIAG, PARAM_NAMES, TriadModel, liu2021_model
from calib.sim.trajectory import (Trajectory, calibration_plan, plan_duration, recorded_segments,
                         sample_segment_index, segment_table)
from calib.core.rotations import euler_to_dcm

#: samples per noise block (fixed: the noise of sample k never depends on the writer's chunk size)
NOISE_BLOCK = 1 << 16
#: SeedSequence spawn-key streams
STREAM_COUNTS, STREAM_INIT, STREAM_PHYSICAL_GYRO, STREAM_PHYSICAL_ACCEL = 1, 2, 3, 4
INT32_MAX = 2**31 - 1
#: sensor effects whose terms change with time at constant inputs
TIME_DEPENDENT_EFFECTS = {"bias_drift", "temperature_sensitivity"}
SENSOR_NAME = "liu2021 synthetic nav-grade unit"
TRUTH_FORMAT = "calib-truth-1"

NOISE_DEFAULTS = {
    "accel_vrw_ug_rthz": 10.0,
    "accel_bias_instability_ug": 5.0,
    "accel_bias_corr_time_s": 300.0,
    "gyro_arw_deg_rth": 0.002,
    "gyro_bias_instability_deg_h": 0.003,
    "gyro_bias_corr_time_s": 600.0,
    "bias_model": "gauss_markov",
    "quantize": True,
}
#: temperature channel of the unit (always recorded): T(t) = end + (start - end) exp(-t / tau)
TEMPERATURE_DEFAULTS = {"start_degC": 22.0, "end_degC": 30.0, "tau_s": 1800.0}

CALIBRATION_DEFAULTS = {
    "sample_rate_hz": 100.0,
    "dwell_s": 60.0,
    "step_deg": 45.0,
    "positions_per_phase": 8,
    "rotation_rates_deg_s": [10.0, 20.0, 30.0],
    "revolutions": 2,
    "rotation_axes": "vertical",
    "transition_s": [2.0, 3.0],
    "move_rate_deg_s": 20.0,
    "sensor": "liu2021",
    "noise": {},
    "effects": {},
    "conceal": False,
    "temperature": {},
    "site": None,
}

STATIC_COMMON = {"site": None, "mode": "physical", "duration_h": 240.0, "sample_rate_hz": 100.0,
                 "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}}
STATIC_PHYSICAL_DEFAULTS = {
    **STATIC_COMMON,
    "gyro_drift_deg_h": [-0.01, 0.01, 0.01],
    "gyro_noise": {"model": "arw", "arw_deg_rth": 0.001, "white_deg_h": 0.001},
    "accel_bias_m_s2": [0.001, 0.001, 0.001],
    "accel_vrw_ug_rthz": 0.0,
}
STATIC_COUNTS_DEFAULTS = {
    **STATIC_COMMON,
    "sensor": "liu2021",
    "noise": {},
    "effects": {},
    "conceal": False,
    "temperature": {},
}


class SimConfigError(ValueError):
    """Bad simulator configuration; the message names the key and the fix."""


# ---------------------------------------------------------------------------------------------------
# configuration helpers
# ---------------------------------------------------------------------------------------------------

def _merge(cfg: dict, defaults: dict, where: str) -> dict:
    cfg = dict(cfg or {})
    unknown = sorted(set(cfg) - set(defaults))
    if unknown:
        raise SimConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(defaults))}")
    out = copy.deepcopy(defaults)
    out.update(copy.deepcopy(cfg))
    return out


def _site(cfg: dict, where: str):
    site = cfg.get("site")
    if not isinstance(site, dict) or "latitude_deg" not in site:
        raise SimConfigError(f"{where}.site.latitude_deg: required (site latitude in degrees); "
                             "pass cfg['site'] = {'latitude_deg': ..., 'height_m': ...}")
    extra = set(site) - {"latitude_deg", "height_m", "longitude_deg"}
    if extra:
        raise SimConfigError(f"{where}.site: unknown key(s) {', '.join(sorted(extra))}")
    lat = float(site["latitude_deg"])
    if not -90.0 < lat < 90.0:
        raise SimConfigError(f"{where}.site.latitude_deg: {lat} outside (-90, 90) degrees")
    return lat, float(site.get("height_m", 0.0))


def _vec(v, name, shape=(3,)):
    a = np.asarray(v, dtype=float)
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise SimConfigError(f"{name}: expected finite numbers of shape {shape}, got {v!r}")
    return a


def sensor_models(sensor_cfg="liu2021", where: str = "sensor") -> tuple[TriadModel, TriadModel]:
    """True accelerometer and gyro models.

    ``'liu2021'`` (Liu 2021 Tables 1 and 3 "separate calibration results") or a mapping
    ``{accel: {...}, gyro: {...}}`` overriding parts of it: ``K`` (3,) [count s-1 per input unit], ``b`` (3,)
    [count s-1], ``E`` (3x3 with unit diagonal, or the 6 off-diagonal terms in the order
    Exy Exz Eyx Eyz Ezx Ezy), or ``vector`` (the 12 parameters in :data:`calib.core.triad.PARAM_NAMES` order).
    Input units: accel g (9.80665 m/s^2), gyro deg/h.
    """
    acc, gyr = liu2021_model("accel"), liu2021_model("gyro")
    if sensor_cfg in (None, "liu2021"):
        return acc, gyr
    if not isinstance(sensor_cfg, dict):
        raise SimConfigError(f"{where}: expected 'liu2021' or a mapping with accel/gyro overrides, got {sensor_cfg!r}")
    extra = set(sensor_cfg) - {"accel", "gyro"}
    if extra:
        raise SimConfigError(f"{where}: unknown key(s) {', '.join(sorted(extra))}; allowed: accel, gyro")
    out = []
    for name, m in (("accel", acc), ("gyro", gyr)):
        o = sensor_cfg.get(name) or {}
        bad = set(o) - {"K", "E", "b", "vector"}
        if bad:
            raise SimConfigError(f"{where}.{name}: unknown key(s) {', '.join(sorted(bad))}; allowed: K, E, b, vector")
        if "vector" in o:
            m = TriadModel.from_vector(_vec(o["vector"], f"{where}.{name}.vector", (12,)), m.input_unit, m.output_unit)
        if "K" in o:
            m.K = _vec(o["K"], f"{where}.{name}.K")
            if np.any(m.K == 0):
                raise SimConfigError(f"{where}.{name}.K: scale factors must be non-zero")
        if "b" in o:
            m.b = _vec(o["b"], f"{where}.{name}.b")
        if "E" in o:
            e = np.asarray(o["E"], dtype=float)
            if e.shape == (6,):
                full = np.eye(3)
                for k, (i, j) in enumerate(OFFDIAG):
                    full[i, j] = e[k]
                e = full
            e = _vec(e, f"{where}.{name}.E", (3, 3))
            if not np.allclose(np.diag(e), 1.0):
                raise SimConfigError(f"{where}.{name}.E: diagonal must be 1 (Liu 2021 eq. 2), got {np.diag(e)}")
            m.E = e
        if abs(np.linalg.det(m.KE)) < 1e-12 * np.prod(np.abs(m.K)):
            raise SimConfigError(f"{where}.{name}: K E is singular")
        out.append(m)
    return out[0], out[1]


def _noise_cfg(noise: dict | None, where: str) -> dict:
    n = _merge(noise or {}, NOISE_DEFAULTS, f"{where}.noise")
    for k, v in n.items():
        if k == "bias_model":
            if v not in ("gauss_markov", "random_walk"):
                raise SimConfigError(f"{where}.noise.bias_model: {v!r}; use gauss_markov or random_walk")
        elif k == "quantize":
            if not isinstance(v, bool):
                raise SimConfigError(f"{where}.noise.quantize: expected true/false, got {v!r}")
        else:
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise SimConfigError(f"{where}.noise.{k}: expected a number >= 0, got {v!r}")
            if k.endswith("corr_time_s") and v <= 0:
                raise SimConfigError(f"{where}.noise.{k}: correlation time must be positive")
            n[k] = float(v)
    return n


def _temperature_cfg(t: dict | None, where: str) -> dict:
    t = _merge(t or {}, TEMPERATURE_DEFAULTS, f"{where}.temperature")
    for k in t:
        t[k] = float(t[k])
    if t["tau_s"] <= 0:
        raise SimConfigError(f"{where}.temperature.tau_s: must be positive")
    return t


def _unit_cfg(c: dict, where: str):
    """The simulated unit's settings shared by the calibration and the static sessions: sensor models, noise,
    effects, conceal flag and temperature profile, each checked (errors name the key)."""
    acc, gyr = sensor_models(c["sensor"], f"{where}.sensor")
    noise = _noise_cfg(c["noise"], where)
    try:
        eff = effects.resolve(c["effects"], f"{where}.effects")
    except effects.EffectConfigError as exc:
        raise SimConfigError(str(exc)) from exc
    if not isinstance(c["conceal"], bool):
        raise SimConfigError(f"{where}.conceal: expected true/false")
    return acc, gyr, noise, eff, _temperature_cfg(c["temperature"], where)


def temperature_profile(t, prof: dict) -> np.ndarray:
    """Unit temperature [degC] at times ``t`` [s]: ``end + (start - end) exp(-t / tau)`` (warm-up)."""
    t = np.asarray(t, dtype=float)
    return prof["end_degC"] + (prof["start_degC"] - prof["end_degC"]) * np.exp(-np.maximum(t, 0.0) / prof["tau_s"])


def _model_json(m: TriadModel) -> dict:
    return {"K": m.K.tolist(), "E": m.E.tolist(), "b": m.b.tolist(),
            "vector": m.to_vector().tolist(), "param_names": list(PARAM_NAMES),
            "input_unit": m.input_unit, "output_unit": m.output_unit}


# ---------------------------------------------------------------------------------------------------
# noise and quantisation kernels
# ---------------------------------------------------------------------------------------------------

class _BlockNormals:
    """Standard normals of width ``width`` per sample, drawn per fixed block of NOISE_BLOCK samples."""

    def __init__(self, seed: int, stream: int, width: int):
        self.seed, self.stream, self.width = int(seed), int(stream), int(width)
        self._cache = (None, None)

    def _block(self, j: int) -> np.ndarray:
        if self._cache[0] == j:
            return self._cache[1]
        ss = np.random.SeedSequence(self.seed, spawn_key=(self.stream, j))
        z = np.random.Generator(np.random.PCG64(ss)).standard_normal((NOISE_BLOCK, self.width))
        self._cache = (j, z)
        return z

    def get(self, i0: int, i1: int) -> np.ndarray:
        out = np.empty((i1 - i0, self.width))
        i = i0
        while i < i1:
            j = i // NOISE_BLOCK
            b0 = j * NOISE_BLOCK
            e = min(i1, b0 + NOISE_BLOCK)
            out[i - i0:e - i0] = self._block(j)[i - b0:e - b0]
            i = e
        return out


@numba.njit(cache=True)
def _noise_increments(z, sig_w, a, c, K, dt, beta, out):  # pragma: no cover
    """The noise of the increments: ``out[i, j] = K (sig_w z_i + beta_i dt)`` [count], beta (updated in place) by
    the recursion of :func:`_noise_and_count`. Alone where the noise of a session is drawn once and shared
    (:meth:`CalibrationSimulator.noise_increments`); ``clean + out`` is then the increment to the bit."""
    n = out.shape[0]
    for i in range(n):
        for j in range(6):
            s = a[j] * beta[j] + c[j] * z[i, 6 + j]
            beta[j] = s
            out[i, j] = K[j] * (sig_w[j] * z[i, j] + s * dt)


@numba.njit(cache=True)
def _count(clean, noise, carry, quantize, inc, counts):  # pragma: no cover
    """The pulse counter of :func:`_noise_and_count` on precomputed noise (:func:`_noise_increments`):
    ``inc = clean + noise``, counts with the fraction carried (``carry`` updated in place)."""
    n = inc.shape[0]
    for i in range(n):
        for j in range(6):
            x = clean[i, j] + noise[i, j]
            inc[i, j] = x
            if quantize:
                r = carry[j] + x
                q = math.floor(r)
                counts[i, j] = q
                carry[j] = r - q


@numba.njit(cache=True)
def _noise_and_count(clean, z, sig_w, a, c, K, dt, beta, carry, quantize, inc, counts):  # pragma: no cover
    """Add noise to the clean increments and run the pulse counter (6 channels): :func:`_noise_increments` then
    :func:`_count`, a block of rows at a time (the noise of a block stays in cache; one implementation of each).

    z[:, j] white-noise normal of channel j, z[:, 6 + j] the bias-instability driving normal.
    beta_i = a beta_{i-1} + c z_i (Gauss-Markov with a < 1, random walk with a = 1), input units.
    inc_i = clean_i + K (sig_w z_i + beta_i dt)  [count]; pulse counter: counts_i = floor(r + inc_i), the
    fraction r in [0, 1) carried. ``beta`` and ``carry`` (length 6) are updated in place.
    """
    n = inc.shape[0]
    block = 4096
    noise = np.empty((min(n, block), 6))
    for i0 in range(0, n, block):
        i1 = min(n, i0 + block)
        nb = noise[:i1 - i0]
        _noise_increments(z[i0:i1], sig_w, a, c, K, dt, beta, nb)
        _count(clean[i0:i1], nb, carry, quantize, inc[i0:i1], counts[i0:i1])


@dataclass
class Chunk:
    """One chunk of simulated samples."""

    i0: int
    accel: np.ndarray           # counts per sample (int32 if quantised, else float64)
    gyro: np.ndarray
    accel_increment: np.ndarray  # un-quantised increments int N dt [count] (float64)
    gyro_increment: np.ndarray
    temperature: np.ndarray     # [degC] at the sample mid-times


def noise_terms(noise: dict, dt: float):
    """The six channels' noise terms (accelerometer x, y, z then gyro x, y, z) in input units: white noise per
    sample (g s, deg/h s), bias-instability level (g, deg/h) and its correlation time (s)."""
    sig_white = np.array([noise["accel_vrw_ug_rthz"] * 1e-6 * math.sqrt(dt)] * 3
                         + [noise["gyro_arw_deg_rth"] * 60.0 * math.sqrt(dt)] * 3)
    sig_b = np.array([noise["accel_bias_instability_ug"] * 1e-6] * 3 + [noise["gyro_bias_instability_deg_h"]] * 3)
    tau = np.array([noise["accel_bias_corr_time_s"]] * 3 + [noise["gyro_bias_corr_time_s"]] * 3)
    return sig_white, sig_b, tau


class CountsEngine:
    """Sequential generator of the pulse-count output of a :class:`TriadModel` pair.

    ``inputs_fn(t) -> (f_b [m/s^2], w_ib_b [rad/s], w_nb_b [rad/s], dw_nb_b [rad/s^2])`` gives the true
    inputs at sensor times ``t`` (n,). Call :meth:`next` repeatedly; state (bias, carry) flows between calls.
    ``constant_inputs``: the inputs never change (a unit at rest); the clean output is then computed once
    unless a time-dependent effect is enabled. ``clean``: the noise-free increments of every sample of the
    run (n, 6) [count], computed before (:meth:`CalibrationSimulator.clean_increments`); they are used
    instead of evaluating the kinematics, so that many noise seeds of one session share them.
    """

    def __init__(self, accel: TriadModel, gyro: TriadModel, noise: dict, resolved_effects: dict,
                 site: effects.SiteTruth, sample_rate_hz: float, seed: int, inputs_fn, temperature: dict,
                 n_nodes: int = 3, constant_inputs: bool = False, clean: np.ndarray | None = None):
        self.constant_inputs, self._clean_const = bool(constant_inputs), None
        self._clean_given = None if clean is None else np.asarray(clean, dtype=np.float64)
        self.accel, self.gyro, self.noise, self.eff = accel, gyro, noise, resolved_effects
        self.site, self.fs, self.dt = site, float(sample_rate_hz), 1.0 / float(sample_rate_hz)
        self.inputs_fn, self.temp = inputs_fn, temperature
        x, w = np.polynomial.legendre.leggauss(int(n_nodes))
        self.s_nodes, self.w_nodes = (x + 1.0) / 2.0, w / 2.0
        self.pos = 0
        self.normals = _BlockNormals(seed, STREAM_COUNTS, 12)
        dt = self.dt
        self.sig_white, sig_b, tau = noise_terms(noise, dt)
        if noise["bias_model"] == "gauss_markov":
            self.a = np.exp(-dt / tau)
            self.c = sig_b * np.sqrt(1.0 - self.a**2)
            z0 = np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(seed), spawn_key=(STREAM_INIT,))))
            self.beta = sig_b * z0.standard_normal(6)
        else:
            self.a = np.ones(6)
            self.c = sig_b * np.sqrt(dt / tau)
            self.beta = np.zeros(6)
        self.carry = np.zeros(6)
        self.K = np.concatenate([accel.K, gyro.K])

    def noise_increments(self, n: int) -> np.ndarray:
        """The noise increments K (sig_w z + beta dt) [count] of the next ``n`` samples (n, 6), advancing the noise
        state as :meth:`next` does. They depend on the noise seed and the noise terms only, not on the inputs: the
        sessions of one unit that share a seed share them (:meth:`CalibrationSimulator.noise_increments`)."""
        out = np.empty((int(n), 6))
        z = self.normals.get(self.pos, self.pos + int(n))
        _noise_increments(z, self.sig_white, self.a, self.c, self.K, self.dt, self.beta, out)
        self.pos += int(n)
        return out

    def noise_key(self) -> tuple:
        """Everything the noise increments of this engine depend on besides the sample count (for a cache)."""
        return (self.normals.seed, self.normals.stream, self.dt, tuple(self.sig_white), tuple(self.a),
                tuple(self.c), tuple(self.K), tuple(self.beta), str(self.noise.get("bias_model")))

    def _clean(self, i0: int, n: int) -> np.ndarray:
        """Noise-free increments int (K (E x + d) + b) dt over each sample [count], shape (n, 6)."""
        dt, m = self.dt, len(self.s_nodes)
        tk = np.arange(i0, i0 + n, dtype=np.float64) * dt
        tn = (tk[:, None] + dt * self.s_nodes[None, :]).reshape(-1) + self.site.time_offset_s
        f, w, wnb, dwnb = self.inputs_fn(tn)
        fg = f / STANDARD_GRAVITY
        wd = w / earth.DEG_PER_H
        ya = effects.rows_times(fg, self.accel.E)
        yg = effects.rows_times(wd, self.gyro.E)
        if self.eff:
            ctx = effects.SensorContext(tn, fg, wd, ya, yg, wnb, dwnb, temperature_profile(tn, self.temp),
                                        self.accel.E, self.gyro.E)
            da, dg = effects.sensor_terms(ctx, self.eff)
            ya = ya + da
            yg = yg + dg
        na = ya * self.accel.K + self.accel.b
        ng = yg * self.gyro.K + self.gyro.b
        na, ng = na.reshape(n, m, 3), ng.reshape(n, m, 3)
        out = np.zeros((n, 6))
        for j in range(m):  # Gauss-Legendre sum written out: the same operations for every chunk size
            out[:, :3] += (self.w_nodes[j] * dt) * na[:, j, :]
            out[:, 3:] += (self.w_nodes[j] * dt) * ng[:, j, :]
        return out

    def next(self, n: int, noise: np.ndarray | None = None) -> Chunk:
        """The next ``n`` samples. ``noise``: their noise increments (n, 6) [count] from :meth:`noise_increments` of
        an engine of the same noise seed and noise terms, instead of drawing them (the same samples to the bit)."""
        n = int(n)
        i0, dt = self.pos, self.dt
        if self._clean_given is not None:
            clean = self._clean_given[i0:i0 + n]
        elif self.constant_inputs and not (set(self.eff) & TIME_DEPENDENT_EFFECTS):
            if self._clean_const is None:
                self._clean_const = self._clean(0, 1)[0]
            clean = np.broadcast_to(self._clean_const, (n, 6))
        else:
            clean = self._clean(i0, n)
        inc = np.empty((n, 6))
        quant = bool(self.noise["quantize"])
        counts = np.empty((n, 6), dtype=np.int64) if quant else inc
        if noise is None:
            z = self.normals.get(i0, i0 + n)
            _noise_and_count(clean, z, self.sig_white, self.a, self.c, self.K, dt, self.beta, self.carry, quant,
                             inc, counts)
        else:
            _count(np.ascontiguousarray(clean, dtype=np.float64), noise, self.carry, quant, inc, counts)
        if quant:
            big = np.abs(counts).max(initial=0)
            if big > INT32_MAX:
                raise SimConfigError(f"sample_rate_hz: {big} counts in one sample overflow int32; "
                                     "raise the sample rate or lower the rotation rates")
            counts = counts.astype(np.int32)
        else:
            counts = inc.copy()
        tk = np.arange(i0, i0 + n, dtype=np.float64) * dt
        temp = temperature_profile(tk + 0.5 * dt + self.site.time_offset_s, self.temp)
        self.pos += n
        return Chunk(i0, counts[:, :3], counts[:, 3:], inc[:, :3], inc[:, 3:], temp)


# ---------------------------------------------------------------------------------------------------
# calibration session
# ---------------------------------------------------------------------------------------------------

@dataclass
class CalibrationSimulator:
    """Everything :func:`simulate_calibration_session` derives from ``(cfg, seed)`` before generating."""

    cfg: dict
    seed: int
    plan: list
    trajectory: Trajectory
    accel: TriadModel
    gyro: TriadModel
    noise: dict
    effects: dict
    temperature: dict
    latitude_deg: float       # recorded (assumed) latitude
    height_m: float
    site: effects.SiteTruth   # the world actually simulated
    sample_rate_hz: float
    n_samples: int

    def inputs(self, t):
        lat = math.radians(self.site.latitude_deg)
        k = self.trajectory.kinematics(t, lat, self.site.height_m, self.site.gravity_m_s2)
        return k.f_b, k.w_ib_b, k.w_nb_b, k.dw_nb_b

    def engine(self, seed: int | None = None, clean: np.ndarray | None = None) -> CountsEngine:
        """The counts generator of the session for noise ``seed`` (default: the simulator's own seed);
        ``clean``: precomputed noise-free increments (:meth:`clean_increments`)."""
        return CountsEngine(self.accel, self.gyro, self.noise, self.effects, self.site, self.sample_rate_hz,
                            self.seed if seed is None else int(seed), self.inputs, self.temperature, n_nodes=3,
                            clean=clean)

    def clean_increments(self) -> np.ndarray:
        """Noise-free increments int N dt of every sample (n_samples, 6) [count], accel then gyro: they do not
        depend on the noise seed, so one evaluation of the kinematics serves every seed of the session."""
        n = self.n_samples
        eng = self.engine()
        out = np.empty((n, 6))
        for i0 in range(0, n, NOISE_BLOCK):
            k = min(NOISE_BLOCK, n - i0)
            out[i0:i0 + k] = eng._clean(i0, k)
        return out

    def noise_key(self, seed: int | None = None) -> tuple:
        """The key :meth:`noise_increments` returns for ``seed``, without drawing the noise."""
        return self.engine(seed).noise_key() + (self.n_samples,)

    def noise_increments(self, seed: int | None = None) -> tuple[tuple, np.ndarray]:
        """``(key, noise)``: the noise increments (n_samples, 6) [count] of noise ``seed`` (:meth:`CountsEngine.noise_increments`,
        drawn in the blocks :meth:`counts` draws them in) and the key of everything they depend on (seed, noise terms,
        scale factors, sample count): sessions of the same unit with equal keys have equal noise."""
        n = self.n_samples
        eng = self.engine(seed)
        key = eng.noise_key() + (n,)
        out = np.empty((n, 6))
        for i0 in range(0, n, NOISE_BLOCK):
            k = min(NOISE_BLOCK, n - i0)
            out[i0:i0 + k] = eng.noise_increments(k)
        return key, out

    def counts(self, seed: int | None = None, clean: np.ndarray | None = None,
               noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Accelerometer and gyro counts per sample (n_samples, 3 each) for noise ``seed`` (default: the
        simulator's own): exactly the samples :func:`simulate_calibration_session` writes for that seed.
        ``clean``: :meth:`clean_increments`, computed once for many seeds of the same configuration. ``noise``:
        :meth:`noise_increments` of the same seed (e.g. computed once for every session of the unit)."""
        n = self.n_samples
        eng = self.engine(seed, clean)
        dtype = np.int32 if self.noise["quantize"] else np.float64
        acc = np.empty((n, 3), dtype=dtype)
        gyr = np.empty((n, 3), dtype=dtype)
        for i0 in range(0, n, NOISE_BLOCK):
            k = min(NOISE_BLOCK, n - i0)
            ch = eng.next(k, None if noise is None else noise[i0:i0 + k])
            acc[i0:i0 + len(ch.accel)] = ch.accel
            gyr[i0:i0 + len(ch.gyro)] = ch.gyro
        return acc, gyr


def build_calibration_simulator(cfg: dict, seed: int) -> CalibrationSimulator:
    """Resolve and validate a calibration-session configuration (keys: :data:`CALIBRATION_DEFAULTS`)."""
    where = "calibration_session"
    c = _merge(cfg, CALIBRATION_DEFAULTS, where)
    lat, h = _site(c, where)
    fs = float(c["sample_rate_hz"])
    if not (math.isfinite(fs) and fs > 0):
        raise SimConfigError(f"{where}.sample_rate_hz: {fs} is not a positive rate")
    try:
        plan = calibration_plan(step_deg=float(c["step_deg"]), positions_per_phase=int(c["positions_per_phase"]),
                                dwell_s=float(c["dwell_s"]), rotation_rates_deg_s=list(c["rotation_rates_deg_s"]),
                                revolutions=c["revolutions"], rotation_axes=c["rotation_axes"],
                                transition_s=list(c["transition_s"]), move_rate_deg_s=float(c["move_rate_deg_s"]),
                                time_grid_s=1.0 / fs)
    except ValueError as exc:
        raise SimConfigError(f"{where}: {exc}") from exc
    acc, gyr, noise, eff, temp = _unit_cfg(c, where)
    site0 = effects.SiteTruth(lat, h, float(earth.normal_gravity(math.radians(lat), h)))
    site = effects.apply_truth(site0, eff)
    n = int(math.floor(plan_duration(plan) * fs + 1e-6))
    return CalibrationSimulator(c, int(seed), plan, Trajectory(plan), acc, gyr, noise, eff, temp, lat, h, site, fs, n)


def _recording_attrs(sim_cfg: dict, eff: dict, quantize: bool, extra: dict | None = None) -> dict:
    attrs = {
        "body_frame": "right-front-up",
        "navigation_frame": "ENU",
        "sensor_model": "N = K E x + b (Liu 2021 eqs. 1-4); output rate in count s-1",
        "accel_input_unit": "g",
        "gyro_input_unit": "deg h-1",
        "output_rate_unit": "count s-1",
        "standard_gravity_m_s2": STANDARD_GRAVITY,
        "sample_time_convention": "interval_start",   # sample k covers [t_k, t_k + dt) (calib.io.recording)
        "quantization": ("pulse counter: integer counts per sample, fractional remainder carried"
                         if quantize else "none (float counts per sample)"),
    }
    if extra:
        attrs.update(extra)
    if not sim_cfg["conceal"]:
        attrs["effects_enabled"] = ",".join(eff) if eff else "none"
    return attrs


def calibration_session_channels(sim: CalibrationSimulator) -> dict:
    """The seed-independent parts of a calibration-session recording: ``segment_index``, ``table_angle``, the
    segment table and the global attributes (:func:`calibration_session_dataset` takes them precomputed when many
    noise seeds of one session are generated)."""
    n, fs = sim.n_samples, sim.sample_rate_hz
    return {"segment_index": sample_segment_index(sim.plan, n, fs),
            "table_angle": sim.trajectory.kinematics(np.arange(n) / fs,
                                                     math.radians(sim.latitude_deg)).table_angle_deg,
            "segments": segment_table(sim.plan),
            "attrs": _recording_attrs(sim.cfg, sim.effects, sim.noise["quantize"], {"session": "calibration"})}


def calibration_session_dataset(sim: CalibrationSimulator, seed: int | None = None, clean: np.ndarray | None = None,
                                channels: dict | None = None):
    """The in-memory recording (``xarray.Dataset``) of the session for noise ``seed`` (default: the simulator's
    own): exactly the dataset :func:`simulate_calibration_session` writes. ``clean``
    (:meth:`CalibrationSimulator.clean_increments`) and ``channels`` (:func:`calibration_session_channels`):
    seed-independent parts computed once for many seeds of the same session."""
    n, fs = sim.n_samples, sim.sample_rate_hz
    quant = sim.noise["quantize"]
    dtype = np.int32 if quant else np.float64
    acc = np.empty((n, 3), dtype=dtype)
    gyr = np.empty((n, 3), dtype=dtype)
    temp = np.empty(n)
    eng = sim.engine(seed, clean)
    for i0 in range(0, n, NOISE_BLOCK):
        ch = eng.next(min(NOISE_BLOCK, n - i0))
        acc[i0:i0 + len(ch.accel)] = ch.accel
        gyr[i0:i0 + len(ch.gyro)] = ch.gyro
        temp[i0:i0 + len(ch.temperature)] = ch.temperature
    fixed = calibration_session_channels(sim) if channels is None else channels
    return recording.make_dataset(
        acc, gyr, sample_rate_hz=fs, latitude_deg=sim.latitude_deg, height_m=sim.height_m,
        accel_units="count", gyro_units="count", accel_kind="increment", gyro_kind="increment",
        source="synthetic", sensor=SENSOR_NAME, temperature=temp, segment_index=fixed["segment_index"],
        segments=fixed["segments"], table_angle=fixed["table_angle"], extra_attrs=dict(fixed["attrs"]))


def simulate_calibration_session(cfg: dict, seed: int, out_path, truth_path=None, prov=None) -> Path:
    """Simulate the Liu 2021 calibration session and write it as a ``calib-recording-1`` file.

    ``cfg``: see :data:`CALIBRATION_DEFAULTS` (the ``calibration_session`` section plus ``site``).
    Output: accel/gyro int32 counts per sample (``sample_kind='increment'``, ``units='count'``),
    ``temperature``, ``segment_index`` (-1 in transitions), ``table_angle`` and the segment table.
    ``truth_path``: JSON sidecar with the true sensor parameters, noise, effects, site and seed.
    With ``conceal: true`` nothing in the recording names the effects.
    """
    t_wall = _time.perf_counter()
    sim = build_calibration_simulator(cfg, seed)
    ds = calibration_session_dataset(sim)
    if prov is None:
        prov = provenance("simulate_calibration_session", cfg, seed)
    out = recording.write(ds, out_path, prov)
    if truth_path is not None:
        write_json(_truth_calibration(sim, time_s=_time.perf_counter() - t_wall), truth_path)
    return out


def calibration_truth(sim: CalibrationSimulator) -> dict:
    """The truth sidecar of :func:`simulate_calibration_session` as a dict (its ``generation_time_s`` set to 0)."""
    return _truth_calibration(sim, time_s=0.0)


def _noise_json(noise: dict, accel: TriadModel, gyro: TriadModel, dt: float) -> dict:
    d = dict(noise)
    sig_w = noise_terms(noise, dt)[0]
    d["per_sample_white_sigma_count"] = {"accel": (sig_w[:3] * accel.K).tolist(), "gyro": (sig_w[3:] * gyro.K).tolist()}
    d["noise_block_samples"] = NOISE_BLOCK
    return d


def _truth_calibration(sim: CalibrationSimulator, time_s: float) -> dict:
    return {
        "format": TRUTH_FORMAT,
        "session": "calibration",
        "seed": sim.seed,
        "sample_rate_hz": sim.sample_rate_hz,
        "n_samples": sim.n_samples,
        "site": {"latitude_deg_recorded": sim.latitude_deg, "height_m": sim.height_m,
                 "latitude_deg_true": sim.site.latitude_deg, "gravity_m_s2_true": sim.site.gravity_m_s2,
                 "normal_gravity_m_s2_recorded_latitude":
                     float(earth.normal_gravity(math.radians(sim.latitude_deg), sim.height_m)),
                 "time_offset_s": sim.site.time_offset_s},
        "accel": _model_json(sim.accel),
        "gyro": _model_json(sim.gyro),
        "noise": _noise_json(sim.noise, sim.accel, sim.gyro, 1.0 / sim.sample_rate_hz),
        "effects": sim.effects,
        "temperature": sim.temperature,
        "segments": [{"label": s.label, "kind": s.kind, "t_start_s": s.t_start_s, "duration_s": s.duration_s,
                      "axis": s.axis.tolist(), "rate_deg_s": s.rate_deg_s}
                     for s in recorded_segments(sim.plan)],
        "config": sim.cfg,
        "generation_time_s": time_s,
    }


# ---------------------------------------------------------------------------------------------------
# long stationary sessions
# ---------------------------------------------------------------------------------------------------

def _attitude(c: dict, where: str) -> tuple[np.ndarray, dict]:
    att = c["attitude_deg"]
    if not isinstance(att, dict) or set(att) - {"pitch", "roll", "yaw"}:
        raise SimConfigError(f"{where}.attitude_deg: expected {{pitch, roll, yaw}} in degrees, got {att!r}")
    a = {k: float(att.get(k, 0.0)) for k in ("pitch", "roll", "yaw")}
    return euler_to_dcm(math.radians(a["pitch"]), math.radians(a["roll"]), math.radians(a["yaw"])), a


def _time_chunking(n: int, target: int) -> int:
    """Samples per file chunk along ``time`` of a long stationary recording: about ``target``, splitting the
    ``n`` samples into equal chunks (the last one short by fewer samples than there are chunks, so the file
    carries almost no padding). Chunks of about 2**20 samples (24 MB of a float64 triad) are read by one large
    request each: cold-cache reading of the 240 h session is about twice as fast as with 2**18."""
    target = max(1, min(int(target), int(n)))
    k = -(-int(n) // target)
    return -(-int(n) // k)


def _static_layout(c: dict, where: str = "static_session"):
    """Site, rate, duration, sample count and attitude of a merged static-session config, each checked (one
    line naming the key on a bad value): ``(lat, h, fs, dur_h, n, cbn, att)``."""
    lat, h = _site(c, where)
    fs = float(c["sample_rate_hz"])
    dur_h = float(c["duration_h"])
    if not (fs > 0 and math.isfinite(fs)):
        raise SimConfigError(f"{where}.sample_rate_hz: {fs} is not a positive rate")
    if not (dur_h > 0 and math.isfinite(dur_h)):
        raise SimConfigError(f"{where}.duration_h: {dur_h} is not a positive duration")
    n = int(round(dur_h * 3600.0 * fs))
    if n < 2:
        raise SimConfigError(f"{where}.duration_h: {dur_h} h at {fs} Hz gives fewer than 2 samples")
    cbn, att = _attitude(c, where)
    return lat, h, fs, dur_h, n, cbn, att


def simulate_static_session(cfg: dict, seed: int, out_path, truth_path=None, prov=None, progress=None,
                            chunk_samples: int = 1 << 20) -> Path:
    """A long stationary recording written chunk by chunk (memory flat in the duration).

    ``cfg['mode']``:

    * ``'physical'`` (default; He 2019 §IV.A) keys :data:`STATIC_PHYSICAL_DEFAULTS`: increments
      ``dtheta = (C_n^b omega_ie^n + drift) dt + noise`` [rad] and ``dv = (C_n^b (0, 0, gamma) + bias) dt +
      noise`` [m/s], float64. Gyro noise ``model: arw`` — angle random walk ``arw_deg_rth`` [deg/sqrt(h)],
      per-sample sigma ``arw/60 sqrt(dt)`` deg; ``model: white`` — white rate noise of sigma ``white_deg_h``
      [deg/h] per sample (sigma ``white dt``). Accel VRW ``accel_vrw_ug_rthz`` [ug/sqrt(Hz)].
    * ``'counts'`` keys :data:`STATIC_COUNTS_DEFAULTS`: the calibration unit's int32 pulse counts (same
      sensor, noise model, effects and quantisation as :func:`simulate_calibration_session`) plus the
      temperature channel.

    Attitude ``attitude_deg: {pitch, roll, yaw}`` (ENU convention of :mod:`calib.core.rotations`; zero = body
    axes along E, N, U). ``progress(done_samples, total_samples)`` is called after each chunk.
    ``chunk_samples`` changes only memory use and file chunking (chunks of about that many samples along
    ``time``, see :func:`_time_chunking`), never the samples.
    """
    mode = (cfg or {}).get("mode", "physical")
    if mode not in ("physical", "counts"):
        raise SimConfigError(f"static_session.mode: {mode!r}; use 'physical' or 'counts'")
    c = _merge(cfg, STATIC_PHYSICAL_DEFAULTS if mode == "physical" else STATIC_COUNTS_DEFAULTS, "static_session")
    lat, h, fs, dur_h, n, cbn, att = _static_layout(c)
    chunk_samples = _time_chunking(n, chunk_samples)  # written by whole file chunks
    t_wall = _time.perf_counter()
    if prov is None:
        prov = provenance("simulate_static_session", cfg, seed)
    if mode == "physical":
        truth = _static_physical(c, seed, out_path, prov, progress, chunk_samples, lat, h, fs, n, cbn, att)
    else:
        truth = _static_counts(c, seed, out_path, prov, progress, chunk_samples, lat, h, fs, n, cbn, att)
    truth["generation_time_s"] = _time.perf_counter() - t_wall
    if truth_path is not None:
        write_json(truth, truth_path)
    return Path(out_path)


def static_physical_means(cfg: dict) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free per-sample increments (dtheta [rad], dv [m/s]) of a physical-mode static session."""
    c = _merge(cfg, STATIC_PHYSICAL_DEFAULTS, "static_session")
    lat, h = _site(c, "static_session")
    cbn, _ = _attitude(c, "static_session")
    dt = 1.0 / float(c["sample_rate_hz"])
    drift = _vec(c["gyro_drift_deg_h"], "static_session.gyro_drift_deg_h") * earth.DEG_PER_H
    bias = _vec(c["accel_bias_m_s2"], "static_session.accel_bias_m_s2")
    w_ib = cbn.T @ earth.earth_rate_enu(math.radians(lat)) + drift
    f_b = cbn.T @ np.array([0.0, 0.0, float(earth.normal_gravity(math.radians(lat), h))]) + bias
    return w_ib * dt, f_b * dt


def _static_physical(c, seed, out_path, prov, progress, chunk, lat, h, fs, n, cbn, att) -> dict:
    where = "static_session"
    dt = 1.0 / fs
    gn = _merge(c["gyro_noise"], {"model": "arw", "arw_deg_rth": 0.001, "white_deg_h": 0.001}, f"{where}.gyro_noise")
    if gn["model"] not in ("arw", "white"):
        raise SimConfigError(f"{where}.gyro_noise.model: {gn['model']!r}; use arw or white")
    for k in ("arw_deg_rth", "white_deg_h"):
        if not (float(gn[k]) >= 0):
            raise SimConfigError(f"{where}.gyro_noise.{k}: must be >= 0")
    vrw = float(c["accel_vrw_ug_rthz"])
    if not vrw >= 0:
        raise SimConfigError(f"{where}.accel_vrw_ug_rthz: must be >= 0")
    dth0, dv0 = static_physical_means(c)
    if gn["model"] == "arw":
        sig_g = float(gn["arw_deg_rth"]) * earth.DEG / 60.0 * math.sqrt(dt)  # rad per sample
    else:
        sig_g = float(gn["white_deg_h"]) * earth.DEG_PER_H * dt
    sig_a = vrw * 1e-6 * STANDARD_GRAVITY * math.sqrt(dt)  # m/s per sample
    normals_g = _BlockNormals(seed, STREAM_PHYSICAL_GYRO, 3)
    normals_a = _BlockNormals(seed, STREAM_PHYSICAL_ACCEL, 3) if sig_a > 0 else None
    attrs = {"session": "stationary navigation (He 2019 IV.A)", "body_frame": "right-front-up",
             "navigation_frame": "ENU", "attitude_pitch_deg": att["pitch"], "attitude_roll_deg": att["roll"],
             "attitude_yaw_deg": att["yaw"]}
    with recording.LongRecordingWriter(out_path, n, fs, latitude_deg=lat, height_m=h, accel_units="m s-1",
                                       gyro_units="rad", accel_kind="increment", gyro_kind="increment",
                                       dtype="f8", source="synthetic", sensor="He 2019 simulated stationary INS",
                                       extra_attrs=attrs, chunk_samples=chunk) as w:
        for i0 in range(0, n, chunk):
            i1 = min(n, i0 + chunk)
            dth = dth0 + sig_g * normals_g.get(i0, i1)
            dv = dv0 + sig_a * normals_a.get(i0, i1) if normals_a is not None else np.broadcast_to(dv0, (i1 - i0, 3))
            w.append(dv, dth)
            if progress is not None:
                progress(i1, n)
    return {
        "format": TRUTH_FORMAT, "session": "static", "mode": "physical", "seed": int(seed),
        "sample_rate_hz": fs, "n_samples": n,
        "site": {"latitude_deg": lat, "height_m": h, "gravity_m_s2": float(earth.normal_gravity(math.radians(lat), h))},
        "attitude_deg": att, "cbn": cbn.tolist(),
        "gyro_drift_deg_h": list(map(float, c["gyro_drift_deg_h"])),
        "accel_bias_m_s2": list(map(float, c["accel_bias_m_s2"])),
        "gyro_noise": gn, "accel_vrw_ug_rthz": vrw,
        "per_sample_sigma": {"gyro_rad": sig_g, "accel_m_s": sig_a},
        "mean_increment": {"gyro_rad": dth0.tolist(), "accel_m_s": dv0.tolist()},
        "noise_block_samples": NOISE_BLOCK, "config": c,
    }


def _static_counts_unit(c, seed, lat, h, fs, cbn):
    """The calibration unit at rest of a counts-mode static session: (engine, accel, gyro, noise, effects,
    temperature profile, simulated site)."""
    where = "static_session"
    acc, gyr, noise, eff, temp = _unit_cfg(c, where)
    site = effects.apply_truth(effects.SiteTruth(lat, h, float(earth.normal_gravity(math.radians(lat), h))), eff)
    w_ib = cbn.T @ earth.earth_rate_enu(math.radians(site.latitude_deg))
    f_b = cbn.T @ np.array([0.0, 0.0, site.gravity_m_s2])
    zero = np.zeros(3)

    def inputs(t):
        k = len(t)
        z = np.broadcast_to(zero, (k, 3))
        return np.broadcast_to(f_b, (k, 3)), np.broadcast_to(w_ib, (k, 3)), z, z

    eng = CountsEngine(acc, gyr, noise, eff, site, fs, seed, inputs, temp, n_nodes=1, constant_inputs=True)
    return eng, acc, gyr, noise, eff, temp, site


def _static_counts_attrs(c, eff, quant, att) -> dict:
    return _recording_attrs(c, eff, quant, {"session": "static", "attitude_pitch_deg": att["pitch"],
                                            "attitude_roll_deg": att["roll"], "attitude_yaw_deg": att["yaw"]})


def _static_counts(c, seed, out_path, prov, progress, chunk, lat, h, fs, n, cbn, att) -> dict:
    eng, acc, gyr, noise, eff, temp, site = _static_counts_unit(c, seed, lat, h, fs, cbn)
    quant = noise["quantize"]
    attrs = _static_counts_attrs(c, eff, quant, att)
    with recording.LongRecordingWriter(out_path, n, fs, latitude_deg=lat, height_m=h, accel_units="count",
                                       gyro_units="count", accel_kind="increment", gyro_kind="increment",
                                       dtype="i4" if quant else "f8", source="synthetic", sensor=SENSOR_NAME,
                                       extra_attrs=attrs, chunk_samples=chunk, temperature=True) as w:
        for i0 in range(0, n, chunk):
            ch = eng.next(min(chunk, n - i0))
            w.append(ch.accel, ch.gyro, ch.temperature)
            if progress is not None:
                progress(i0 + len(ch.accel), n)
    return {
        "format": TRUTH_FORMAT, "session": "static", "mode": "counts", "seed": int(seed),
        "sample_rate_hz": fs, "n_samples": n,
        "site": {"latitude_deg_recorded": lat, "height_m": h, "latitude_deg_true": site.latitude_deg,
                 "gravity_m_s2_true": site.gravity_m_s2, "time_offset_s": site.time_offset_s},
        "attitude_deg": att, "cbn": cbn.tolist(),
        "accel": _model_json(acc), "gyro": _model_json(gyr),
        "noise": _noise_json(noise, acc, gyr, 1.0 / fs), "effects": eff, "temperature": temp, "config": c,
    }


def static_counts_dataset(cfg: dict, seed: int, chunk_samples: int = NOISE_BLOCK, path: str | None = None):
    """The counts-mode static session of ``(cfg, seed)`` in memory: the ``xarray.Dataset`` that
    ``recording.load`` returns for the file :func:`simulate_static_session` writes (same samples, dtypes, variable
    and global attributes; ``temperature`` float32 as stored), without the file and its provenance attributes.
    ``path``: the ``_path`` attribute a loaded file carries (default: none). For the many short records of a
    study (the whole record is held in memory; generated by chunks of ``chunk_samples``, which keeps the
    temporaries small and changes no sample)."""
    c = _merge(cfg, STATIC_COUNTS_DEFAULTS, "static_session")
    if c.get("mode", "counts") != "counts":
        raise SimConfigError(f"static_session.mode: {c['mode']!r}; the in-memory static record is counts only")
    lat, h, fs, dur_h, n, cbn, att = _static_layout(c)
    chunk = max(1, int(chunk_samples))  # the samples do not depend on it (module docstring), only the memory does
    eng, _, _, noise, eff, _, _ = _static_counts_unit(c, seed, lat, h, fs, cbn)
    quant = noise["quantize"]
    dtype = np.int32 if quant else np.float64
    acc = np.empty((n, 3), dtype=dtype)
    gyr = np.empty((n, 3), dtype=dtype)
    temp = np.empty(n, dtype=np.float32)
    for i0 in range(0, n, chunk):
        ch = eng.next(min(chunk, n - i0))
        k = len(ch.accel)
        acc[i0:i0 + k] = ch.accel
        gyr[i0:i0 + k] = ch.gyro
        temp[i0:i0 + k] = ch.temperature
    attrs = {"Conventions": f"{CF_VERSION} {recording.CONVENTIONS}", "latitude_deg": lat, "height_m": h,
             "sample_rate_hz": fs, "t0_s": 0.0, "source": "synthetic", "sensor": SENSOR_NAME}
    attrs.update(_static_counts_attrs(c, eff, quant, att))
    attrs = {k: np.float64(v) if isinstance(v, float) else v for k, v in attrs.items()}  # as netCDF4 reads them
    if path is not None:
        attrs["_path"] = str(path)
    data = {"accel": (("time", "axis"), acc, {"sample_kind": "increment", "units": "count",
                                              "long_name": "accelerometer triad output"}),
            "gyro": (("time", "axis"), gyr, {"sample_kind": "increment", "units": "count",
                                             "long_name": "gyroscope triad output"}),
            "temperature": (("time",), temp, {"units": "degC", "long_name": "unit temperature"})}
    coords = {"axis": list(recording.AXES), "time": 0.0 + np.arange(n) / fs}
    return xr.Dataset(data, coords=coords, attrs=attrs)
