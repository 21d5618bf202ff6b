"""The simulated unit's output engine: the noise-free increments of the sensor model, the noise streams and the
pulse counter, shared by the calibration and the static sessions.

Sensor output (Liu 2021 eqs. 1-4, with the terms of :mod:`calib.sim.effects`), sensor axis i::

    N_i(t) = K_i (y_i(t) + d_i(t) + beta_i(t) + n_i(t)) + b_i          [count s-1]
    y      = E x,  x = f^b / g0 [g]  (accel)  or  omega_ib^b [deg/h]  (gyro)

with ``beta`` the bias instability (first-order Gauss-Markov, or random walk) and ``n`` white noise
(accel velocity random walk, gyro angle random walk), both referred to the input (the noise keys and their
defaults: :mod:`calib.sim.settings`).

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
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from calib.core import earth
from calib.core.earth import STANDARD_GRAVITY
from calib.core.triad import TriadModel
from calib.sim import effects
from calib.sim.settings import SimConfigError

#: samples per noise block (fixed: the noise of sample k never depends on the writer's chunk size)
NOISE_BLOCK = 1 << 16
#: SeedSequence spawn-key streams
STREAM_COUNTS, STREAM_INIT, STREAM_PHYSICAL_GYRO, STREAM_PHYSICAL_ACCEL = 1, 2, 3, 4
INT32_MAX = 2**31 - 1
#: sensor effects whose terms change with time at constant inputs
TIME_DEPENDENT_EFFECTS = {"bias_drift", "temperature_sensitivity"}
SENSOR_NAME = "liu2021 synthetic nav-grade unit"


def temperature_profile(t, prof: dict) -> np.ndarray:
    """Unit temperature [degC] at times ``t`` [s]: ``end + (start - end) exp(-t / tau)`` (warm-up)."""
    t = np.asarray(t, dtype=float)
    return prof["end_degC"] + (prof["start_degC"] - prof["end_degC"]) * np.exp(-np.maximum(t, 0.0) / prof["tau_s"])


def noise_terms(noise: dict, dt: float):
    """The six channels' noise terms (accelerometer x, y, z then gyro x, y, z) in input units: white noise per
    sample (g s, deg/h s), bias-instability level (g, deg/h) and its correlation time (s)."""
    sig_white = np.array([noise["accel_vrw_ug_rthz"] * 1e-6 * math.sqrt(dt)] * 3
                         + [noise["gyro_arw_deg_rth"] * 60.0 * math.sqrt(dt)] * 3)
    sig_b = np.array([noise["accel_bias_instability_ug"] * 1e-6] * 3 + [noise["gyro_bias_instability_deg_h"]] * 3)
    tau = np.array([noise["accel_bias_corr_time_s"]] * 3 + [noise["gyro_bias_corr_time_s"]] * 3)
    return sig_white, sig_b, tau


class BlockNormals:
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
    (:meth:`calib.sim.calibration_session.CalibrationSimulator.noise_increments`); ``clean + out`` is then the
    increment to the bit."""
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
def _count_into(clean, noise, carry, acc, gyr, i0):  # pragma: no cover
    """The pulse counter of :func:`_count` writing the counts of rows ``i0 ..`` of ``acc`` and ``gyr`` (int32)
    directly, without the increments: the same operations per sample (``x = clean + noise``, ``r = carry + x``,
    ``floor``), ``carry`` updated in place. Returns the largest ``|count|`` (as :meth:`CountsEngine.next` checks
    it against int32 before it keeps a count)."""
    n = clean.shape[0]
    big = 0.0
    for i in range(n):
        for j in range(6):
            x = clean[i, j] + noise[i, j]
            r = carry[j] + x
            q = math.floor(r)
            carry[j] = r - q
            aq = abs(q)
            if aq > big:
                big = aq
            if aq <= INT32_MAX:
                if j < 3:
                    acc[i0 + i, j] = np.int32(q)
                else:
                    gyr[i0 + i, j - 3] = np.int32(q)
    return big


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


#: the temperatures of the last chunks :meth:`CountsEngine.run` made with given noise (key: sample range, sample
#: interval, clock offset, warm-up profile), at most :data:`_TEMPERATURES_KEPT` (oldest dropped first)
_TEMPERATURES: dict = {}
_TEMPERATURES_KEPT = 32


class CountsEngine:
    """Sequential generator of the pulse-count output of a :class:`TriadModel` pair.

    ``inputs_fn(t) -> (f_b [m/s^2], w_ib_b [rad/s], w_nb_b [rad/s], dw_nb_b [rad/s^2])`` gives the true
    inputs at sensor times ``t`` (n,). Call :meth:`next` repeatedly; state (bias, carry) flows between calls.
    ``constant_inputs``: the inputs never change (a unit at rest); the clean output is then computed once
    unless a time-dependent effect is enabled. ``clean``: the noise-free increments of every sample of the
    run (n, 6) [count], computed before
    (:meth:`calib.sim.calibration_session.CalibrationSimulator.clean_increments`); they are used instead of
    evaluating the kinematics, so that many noise seeds of one session share them.
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
        self.normals = BlockNormals(seed, STREAM_COUNTS, 12)
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
        sessions of one unit that share a seed share them
        (:meth:`calib.sim.calibration_session.CalibrationSimulator.noise_increments`)."""
        out = np.empty((int(n), 6))
        z = self.normals.get(self.pos, self.pos + int(n))
        _noise_increments(z, self.sig_white, self.a, self.c, self.K, self.dt, self.beta, out)
        self.pos += int(n)
        return out

    def noise_key(self) -> tuple:
        """Everything the noise increments of this engine depend on besides the sample count (for a cache)."""
        return (self.normals.seed, self.normals.stream, self.dt, tuple(self.sig_white), tuple(self.a),
                tuple(self.c), tuple(self.K), tuple(self.beta), str(self.noise.get("bias_model")))

    def clean_increments(self, i0: int, n: int) -> np.ndarray:
        """Noise-free increments int (K (E x + d) + b) dt over samples ``i0 .. i0 + n - 1`` [count], shape (n, 6),
        accel then gyro. Does not advance the engine."""
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
        clean = self._clean_chunk(i0, n)
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
        temp = self._chunk_temperature(i0, n)
        self.pos += n
        return Chunk(i0, counts[:, :3], counts[:, 3:], inc[:, :3], inc[:, 3:], temp)

    def _clean_chunk(self, i0: int, n: int) -> np.ndarray:
        """The noise-free increments of samples ``i0 .. i0 + n - 1`` (n, 6) [count]: given, constant or computed."""
        if self._clean_given is not None:
            return self._clean_given[i0:i0 + n]
        if self.constant_inputs and not (set(self.eff) & TIME_DEPENDENT_EFFECTS):
            if self._clean_const is None:
                self._clean_const = self.clean_increments(0, 1)[0]
            return np.broadcast_to(self._clean_const, (n, 6))
        return self.clean_increments(i0, n)

    def _chunk_temperature(self, i0: int, n: int, keep: bool = False) -> np.ndarray:
        """The unit temperature [degC] at the mid-times of samples ``i0 .. i0 + n - 1``. ``keep``: look it up in
        (and add it to) :data:`_TEMPERATURES` (read only): it depends on the sample times and the warm-up profile
        only, so the many noise seeds of one session (:meth:`run` with given noise) compute it once."""
        key = (i0, n, self.dt, self.site.time_offset_s, repr(sorted(self.temp.items())))
        hit = _TEMPERATURES.get(key) if keep else None
        if hit is None:
            tk = np.arange(i0, i0 + n, dtype=np.float64) * self.dt
            hit = temperature_profile(tk + 0.5 * self.dt + self.site.time_offset_s, self.temp)
            if keep:
                if len(_TEMPERATURES) >= _TEMPERATURES_KEPT:
                    _TEMPERATURES.pop(next(iter(_TEMPERATURES)))
                hit.flags.writeable = False
                _TEMPERATURES[key] = hit
        return hit

    def run(self, n: int, chunk: int = NOISE_BLOCK, noise: np.ndarray | None = None,
            temperature_dtype=np.float64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The next ``n`` samples held in memory: accelerometer and gyro counts (n, 3) each and the temperature
        (n,), generated ``chunk`` samples at a time (the samples do not depend on ``chunk``, only the size of the
        temporaries does). ``noise``: the noise increments of the ``n`` samples (n, 6), as for :meth:`next`."""
        dtype = np.int32 if self.noise["quantize"] else np.float64
        acc = np.empty((n, 3), dtype=dtype)
        gyr = np.empty((n, 3), dtype=dtype)
        temp = np.empty(n, dtype=temperature_dtype)
        if noise is not None and self.noise["quantize"]:
            # given noise (the proof's seeds): the counter writes the int32 counts in place, without the chunk's
            # increments and int64 counts that next() keeps for its Chunk (the same counts, the same checks)
            for i0 in range(0, n, chunk):
                k = min(chunk, n - i0)
                clean = np.ascontiguousarray(self._clean_chunk(self.pos, k), dtype=np.float64)
                big = _count_into(clean, noise[i0:i0 + k], self.carry, acc, gyr, i0)
                if big > INT32_MAX:
                    raise SimConfigError(f"sample_rate_hz: {int(big)} counts in one sample overflow int32; "
                                         "raise the sample rate or lower the rotation rates")
                temp[i0:i0 + k] = self._chunk_temperature(self.pos, k, keep=True)
                self.pos += k
            return acc, gyr, temp
        for i0 in range(0, n, chunk):
            k = min(chunk, n - i0)
            ch = self.next(k, None if noise is None else noise[i0:i0 + k])
            acc[i0:i0 + k] = ch.accel
            gyr[i0:i0 + k] = ch.gyro
            temp[i0:i0 + k] = ch.temperature
        return acc, gyr, temp


def counts_recording_attrs(conceal: bool, resolved_effects: dict, quantize: bool, extra: dict | None = None) -> dict:
    """The global attributes a recording of the engine's counts carries: frames, sensor model, units, time
    convention, quantisation, ``extra``, and the enabled effects unless ``conceal``."""
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
    if not conceal:
        attrs["effects_enabled"] = ",".join(resolved_effects) if resolved_effects else "none"
    return attrs
