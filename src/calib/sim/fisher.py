"""Noise-limited bounds of the library's effect parameters from the Fisher information of the generative model.

How precisely *could* any unbiased estimator determine an effect's parameters from one simulated session? The
answer depends only on the generative model: the noise-free output as a function of the parameters, and the
noise the simulator adds. It is computed here without the diagnosis (:mod:`calib.diagnosis`): no window means, no
signatures, no noise estimate of its own. The diagnosis's standard errors and its spread over noise seeds are then
compared against it (the concealed-effect proof, :mod:`calib.studies.diagnosis_proof`): an estimator that claims
a standard error below the bound is overconfident; one far above it leaves information unused.

Model (per channel c of the six, accelerometer x, y, z then gyro x, y, z; sample k covers [k dt, (k + 1) dt)):

    counts_k = mu_k(theta, eta) + K_c (sigma_w z_k + beta_k dt) + (r_k-1 - r_k)

* ``mu``: the noise-free increments of the session
  (:meth:`calib.sim.calibration_session.CalibrationSimulator.clean_increments`)
  with the effect made by :mod:`calib.sim.physical` (or, for ``latitude_error`` / ``gravity_error``, by the
  simulator's world); ``theta``: the effect's parameters; ``eta``: the nuisance parameters of the base model
  ``N = K E x + b`` (Liu 2021 eqs. 1-4: 3 scale factors, 6 misalignments, 3 biases per triad), whose
  derivatives follow from the true inputs ``x`` recovered from ``mu``.
* white noise ``sigma_w`` (the simulator's VRW / ARW per sample), a first-order Gauss-Markov bias ``beta`` (AR(1),
  ``a = exp(-dt / tau)``, stationary standard deviation ``sigma_b``), and the pulse counter's carried remainder
  ``r`` (uniform on [0, 1): the quantisation noise is the difference of two uniforms, spectrum
  ``(1/12) |1 - e^{-i w}|^2``).

The Gaussian Fisher information ``J = D^T Sigma^-1 D`` (D the derivatives of ``mu``) is evaluated in the frequency
domain (Whittle's approximation: ``J = sum_k Re(D_k^H D_k) / (n S(w_k))`` over the DFT of each column, with the
spectral density ``S`` of the noise per sample), exact as the session grows long compared with the bias
correlation time. The quantisation noise is not Gaussian; its second-order description is used, which the
bound then assumes. Bounds: ``sqrt(diag(J^-1))`` for the parameters the information determines; a parameter in
the null space of ``J`` (the data cannot tell it apart from a combination of the others) is reported as
``None`` ("not determined").
"""
from __future__ import annotations

import copy
import math

import numpy as np
from scipy import sparse
from scipy.linalg import solve_banded

from calib.core.information import seen_inverse
from calib.sim import effects as sim_effects
from calib.sim import physical
from calib.sim.calibration_session import build_calibration_simulator
from calib.sim.counts_engine import noise_terms, temperature_profile
from calib.signal.noisecov import PULSE_COUNTER_Q, MeanNoiseModel

AXES = ("x", "y", "z")
#: parameters that fix the form of an effect, not its size (held at their true values)
SHAPE_PARAMETERS = {"accel_tau_s", "gyro_tau_s", "T_ref_degC"}
#: effects the simulator makes by changing the world (derivatives by re-simulating the noise-free session)
WORLD_EFFECTS = {"latitude_error", "gravity_error"}
_REL_STEP = 1e-3
#: effects of the physical path whose noise-free increments are affine in their size parameters (one effect at a
#: time, :func:`calib.sim.physical.inject`: output (K s h + b) dt + K e with the transfer h, the scale s and the
#: additive e each affine in the sizes): a derivative is the difference of two evaluations, at zero and at one
#: size. The clock offset shifts the stream (not affine): central differences
AFFINE_EFFECTS = frozenset(physical.EFFECTS) - {"time_offset"}


def noise_spectrum(sim, n: int) -> np.ndarray:
    """Spectral density of the noise per sample [count^2] of the six channels at the rfft frequencies of ``n``
    samples, shape (6, n // 2 + 1)."""
    dt = 1.0 / float(sim.sample_rate_hz)
    nz = sim.noise
    K = np.concatenate([sim.accel.K, sim.gyro.K])
    sig_w, sig_b, tau = noise_terms(nz, dt)
    w = 2.0 * math.pi * np.arange(n // 2 + 1) / n
    S = np.empty((6, w.size))
    for c in range(6):
        white = (K[c] * sig_w[c]) ** 2
        if nz["bias_model"] == "gauss_markov":
            a = math.exp(-dt / tau[c])
            gm = (K[c] * dt * sig_b[c]) ** 2 * (1.0 - a * a) / np.abs(1.0 - a * np.exp(-1j * w)) ** 2
        else:   # random walk: increments of variance sig_b^2 dt / tau per sample
            with np.errstate(divide="ignore"):
                gm = (K[c] * dt * sig_b[c]) ** 2 * (dt / tau[c]) / np.abs(1.0 - np.exp(-1j * w)) ** 2
        quant = (2.0 - 2.0 * np.cos(w)) / 12.0 if nz["quantize"] else 0.0
        S[c] = white + gm + quant
    return S


def mean_noise_models(sim) -> dict:
    """The simulator's noise as the noise model of window means of the rate reading [count s-1] per triad
    (:class:`calib.signal.noisecov.MeanNoiseModel`, whose covariance of window means the calibration bound
    :mod:`calib.calibration.bound` uses): white density ``N = K sigma_w / sqrt(dt)`` [count s-1 s^1/2] (sigma_w the
    per-sample white noise in input unit s), the pulse counter's carried remainder ``Q = 1/sqrt(12)`` count when
    quantised, and the bias instability ``K sigma_b`` [count s-1] with correlation time ``tau`` (first-order
    Gauss-Markov, the AR(1) of the engine with a = exp(-dt / tau)) or, for a random walk from zero at the first
    sample, the density ``K sigma_b / sqrt(tau)`` [count s-1 s^-1/2]. Returns ``{"accel": model, "gyro": model}``."""
    dt = 1.0 / float(sim.sample_rate_hz)
    nz = sim.noise
    sig_w, sig_b, tau = noise_terms(nz, dt)
    gm = nz["bias_model"] == "gauss_markov"
    out = {}
    for name, model, sl in (("accel", sim.accel, slice(0, 3)), ("gyro", sim.gyro, slice(3, 6))):
        K = np.asarray(model.K, dtype=float)
        q = PULSE_COUNTER_Q if nz["quantize"] else 0.0
        out[name] = MeanNoiseModel(
            unit="count s-1", Q=np.full(3, q), N=K * sig_w[sl] / math.sqrt(dt),
            slow=["gm" if gm else "rw"] * 3, sigma=K * sig_b[sl] if gm else np.zeros(3),
            tc=tau[sl].astype(float), K=np.zeros(3) if gm else K * sig_b[sl] / np.sqrt(tau[sl]),
            source="the simulator's noise settings")
    return out


def _names(eid: str, params: dict):
    """(parameter name as reported, key, index) of every scalar size parameter of an effect."""
    out = []
    for key, v in params.items():
        if key in SHAPE_PARAMETERS or key == "enabled":
            continue
        a = np.asarray(v, dtype=float)
        if a.ndim == 0:
            out.append((key, key, ()))
        elif a.ndim == 1:
            out += [(f"{key}[{AXES[i]}]", key, (i,)) for i in range(a.shape[0])]
        else:
            out += [(f"{key}[{AXES[i]},{AXES[j]}]", key, (i, j)) for i in range(a.shape[0]) for j in range(a.shape[1])]
    return out


def _with(params: dict, key: str, idx, value: float) -> dict:
    p = copy.deepcopy(params)
    a = np.array(p[key], dtype=float)
    if a.ndim == 0:
        p[key] = float(value)
    else:
        a[idx] = value
        p[key] = a.tolist()
    return p


def _effect_columns(cfg: dict, sim, clean, eid: str, params: dict, temperature):
    """Derivatives of the noise-free increments (n, 6) with respect to each size parameter of the effect."""
    cols, names = [], []
    affine = eid in AFFINE_EFFECTS
    if affine:    # every size at zero (the shape parameters kept): the base of the differences
        zero = {k: v if k in SHAPE_PARAMETERS or k == "enabled" else
                (np.zeros(np.shape(v)).tolist() if np.ndim(v) else 0.0) for k, v in params.items()}
        f0 = physical.inject(sim, clean, {eid: zero}, temperature)
    for name, key, idx in _names(eid, params):
        v0 = float(np.asarray(params[key], dtype=float)[idx])
        if affine:
            h = max(abs(v0), 1.0)
            d = (physical.inject(sim, clean, {eid: _with(zero, key, idx, h)}, temperature) - f0) / h
            if np.any(d != 0.0):
                cols.append(d)
                names.append(name)
            continue
        h = _REL_STEP * max(abs(v0), 1e-3 if eid == "time_offset" else 1.0)
        out = []
        for v in (v0 + h, v0 - h):
            p = _with(params, key, idx, v)
            if eid in WORLD_EFFECTS:
                c = copy.deepcopy(cfg)
                c["effects"] = {eid: p}
                out.append(build_calibration_simulator(c, 0).clean_increments())
            else:
                out.append(physical.inject(sim, clean, {eid: p}, temperature))
        d = (out[0] - out[1]) / (2.0 * h)
        if np.any(d != 0.0):          # an element the effect ignores (e.g. the diagonal of cross-coupling)
            cols.append(d)
            names.append(name)
    return names, cols


class ChannelColumns:
    """Derivative columns (of ``n`` samples, six channels) held by channel: ``by_channel[c]`` the ``(column index,
    samples (n,))`` of the columns that are not all zero in channel ``c``, in column order; ``p`` the number of
    columns. A base parameter's derivative touches one channel only: held this way its 24 columns take a sixth of
    the memory of (n, 6) arrays, and the per-channel blocks the informations are built from (:meth:`block`) are
    stacked from them directly, with the values and layout of a stack of the (n, 6) columns' channel."""

    def __init__(self, n: int, p: int, by_channel):
        self.n, self.p = int(n), int(p)
        self.by_channel = [list(b) for b in by_channel]

    @classmethod
    def from_columns(cls, cols, copy: bool = False) -> "ChannelColumns":
        """The columns ``cols`` (list of (n, 6)) by channel: views of them, or with ``copy`` contiguous copies of
        the channels they touch (the (n, 6) arrays can then be dropped)."""
        take = (lambda v: np.ascontiguousarray(v)) if copy else (lambda v: v)
        by = [[(k, take(col[:, c])) for k, col in enumerate(cols) if np.any(col[:, c] != 0.0)] for c in range(6)]
        return cls(cols[0].shape[0] if cols else 0, len(cols), by)

    def __add__(self, other: "ChannelColumns") -> "ChannelColumns":
        """The columns of ``self`` then those of ``other``."""
        return ChannelColumns(self.n, self.p + other.p,
                              [a + [(self.p + k, v) for k, v in b] for a, b in zip(self.by_channel, other.by_channel)])

    def block(self, c: int):
        """(indices of the columns that touch channel ``c``, their samples there stacked (n, p_c)); ([], None)
        when none does."""
        use = [k for k, _ in self.by_channel[c]]
        if not use:
            return use, None
        return use, np.stack([v for _, v in self.by_channel[c]], axis=1)


def as_channel_columns(cols) -> ChannelColumns:
    """``cols`` (a list of (n, 6) columns, or already :class:`ChannelColumns`) by channel."""
    return cols if isinstance(cols, ChannelColumns) else ChannelColumns.from_columns(cols)


def _nuisance_channels(sim, clean):
    """Derivatives of N dt = (K E x + b) dt with respect to K, the off-diagonal E and b of both triads (names, the
    columns by channel, :class:`ChannelColumns`): each touches the one channel of its parameter's axis."""
    dt = 1.0 / float(sim.sample_rate_hz)
    n = len(clean)
    names, by = [], [[] for _ in range(6)]

    def add(name, c, v):
        if np.any(v != 0.0):
            by[c].append((len(names), v))
        names.append(name)

    for t, (model, sl) in enumerate(((sim.accel, slice(0, 3)), (sim.gyro, slice(3, 6)))):
        x = model.inverse(clean[:, sl] / dt)
        y = x @ model.E.T
        tri = "accel" if t == 0 else "gyro"
        for i in range(3):
            c = sl.start + i
            add(f"{tri}.K[{AXES[i]}]", c, y[:, i] * dt)
            for j in range(3):
                if j != i:
                    add(f"{tri}.E[{AXES[i]},{AXES[j]}]", c, model.K[i] * x[:, j] * dt)
            add(f"{tri}.b[{AXES[i]}]", c, np.full(n, dt))
    return names, ChannelColumns(n, len(names), by)


def _nuisance_columns(sim, clean):
    """The columns of :func:`_nuisance_channels` as (n, 6) arrays (zero outside their channel)."""
    names, ch = _nuisance_channels(sim, clean)
    cols = [np.zeros((ch.n, 6)) for _ in names]
    for c, b in enumerate(ch.by_channel):
        for k, v in b:
            cols[k][:, c] = v
    return names, cols


def _weights(n: int, S) -> np.ndarray:
    """Whittle weights per channel and rfft frequency: 2 (1 at zero and Nyquist) / (n S)."""
    wts = np.full(n // 2 + 1, 2.0)
    wts[0] = 1.0
    if n % 2 == 0:
        wts[-1] = 1.0
    return wts[None, :] / (n * np.asarray(S))


def _spectra(cols: ChannelColumns, c: int):
    """(indices of the columns that touch channel ``c``, their rfft (nf, p_c) in that channel)."""
    use, D = cols.block(c)
    return use, None if D is None else np.fft.rfft(D, axis=0)


def information(cols, S, fixed=None) -> np.ndarray:
    """Whittle Fisher information of columns ``cols`` (list of (n, 6), or :class:`ChannelColumns`) under the
    per-channel spectra ``S``. ``fixed``: columns appended after ``cols`` given by their per-channel spectra
    (:func:`_nuisance_spectra`)."""
    cols = as_channel_columns(cols)
    n = cols.n if cols.p else fixed["n"]
    P = cols.p
    Pn = 0 if fixed is None else fixed["p"]
    J = np.zeros((P + Pn, P + Pn))
    W = _weights(n, S)
    for c in range(6):
        use, F = _spectra(cols, c) if P else ([], None)
        if fixed is not None and fixed["use"][c]:
            fu = [P + k for k in fixed["use"][c]]
            F = fixed["F"][c] if F is None else np.concatenate([F, fixed["F"][c]], axis=1)
            use = use + fu
        if not use:
            continue
        Fw = F * W[c][:, None]
        J[np.ix_(use, use)] += np.real(F.conj().T @ Fw)
    return J


_NUISANCE: dict = {}


def _nuisance_spectra(sim, clean, channels=None) -> dict:
    """The base model's 24 nuisance columns (:func:`_nuisance_channels`) as per-channel spectra, kept for the last
    noise-free session (by content and unit): the single-effect sessions of the proof share them. ``channels``:
    those columns (``(names, ChannelColumns)`` of :func:`_nuisance_channels` for ``sim`` and ``clean``) when the
    caller has them already."""
    key = physical.signal_key(sim, clean)
    if key not in _NUISANCE:
        _NUISANCE.clear()
        names, cols = channels if channels is not None else _nuisance_channels(sim, clean)
        spec = [_spectra(cols, c) for c in range(6)]
        _NUISANCE[key] = {"n": len(clean), "p": cols.p, "names": names, "use": [u for u, _ in spec],
                          "F": [F for _, F in spec]}
    return _NUISANCE[key]


def forget_nuisance_spectra():
    """Drop the nuisance spectra :func:`_nuisance_spectra` keeps (50 MB for a 2.5 h session at its rate): for a
    process that computes no other bound of the same signal."""
    _NUISANCE.clear()


def information_for(cfg: dict, effect_id: str, params: dict | None = None, sim=None, clean=None, temperature=None):
    """Fisher information of the size parameters of ``effect_id`` in the session ``cfg`` (a calibration-session
    configuration; the effect is removed from it and made by the physical path) together with the base model's 24
    nuisance parameters. Returns ``(J, effect parameter names)``: the effect's parameters come first in ``J``."""
    cfg = copy.deepcopy(cfg)
    cfg["effects"] = {k: v for k, v in (cfg.get("effects") or {}).items() if k != effect_id}
    if sim is None:
        sim = build_calibration_simulator(cfg, 0)
        clean = sim.clean_increments()
    n = len(clean)
    if temperature is None:
        dt = 1.0 / float(sim.sample_rate_hz)
        temperature = temperature_profile((np.arange(n) + 0.5) * dt, sim.temperature)
    full = sim_effects.resolve({effect_id: params or {}})[effect_id]
    full = {k: v for k, v in full.items() if k != "enabled"}
    enames, ecols = _effect_columns(cfg, sim, clean, effect_id, full, temperature)
    return information(ecols, noise_spectrum(sim, n), fixed=_nuisance_spectra(sim, clean)), enames


def bounds_from(J: np.ndarray, enames: list, free=None, null_tol: float = 1e-9) -> dict:
    """Bounds (1 sigma) of the effect parameters ``enames`` (the first rows of ``J``) with the nuisances free.
    ``free``: the effect parameters estimated (default all); the others are held at their true values (the bound of
    an estimator that fits only ``free``). ``None`` for a parameter the information does not determine."""
    keep = [k for k, nm in enumerate(enames) if free is None or nm in free]
    idx = keep + list(range(len(enames), J.shape[0]))
    Jk = J[np.ix_(idx, idx)]
    null, inv, s = seen_inverse(Jk, null_tol, var_floor=1e-300)
    out = {}
    for r, k in enumerate(keep):
        if null.size and np.linalg.norm(null[r]) > 1e-6:
            out[enames[k]] = None
        else:
            out[enames[k]] = float(math.sqrt(inv[r, r]) / s[r])
    return out


def bounds(cfg: dict, effect_id: str, params: dict | None = None, sim=None, clean=None, temperature=None,
           free=None) -> dict:
    """Fisher (Cramer-Rao) bounds, 1 sigma, of the size parameters of ``effect_id`` in the session ``cfg``, with the
    base model's 24 parameters as nuisances (:func:`information_for`, :func:`bounds_from`). Returns
    ``{name: bound or None}`` (None: not determined by this session), in the registry's units."""
    J, enames = information_for(cfg, effect_id, params, sim, clean, temperature)
    return bounds_from(J, enames, free)


def information_exact(cols, sim) -> np.ndarray | None:
    """Fisher information of the columns ``cols`` (list of (n, 6), or :class:`ChannelColumns`) under the exact
    covariance of the simulator's noise over the n samples (not Whittle's periodic approximation,
    :func:`information`): per channel
    ``D^T Sigma^-1 D`` with ``Sigma = R + Q``, R the white noise and the pulse counter's carried remainder
    (tridiagonal: ``sigma_w^2 + 1/6`` on the diagonal, ``-1/12`` beside it) and Q the stationary first-order
    Gauss-Markov bias (``v a^|i-j|``, whose inverse T is tridiagonal), so that ``Sigma^-1 = T (R T + I)^-1`` is
    one banded (pentadiagonal) solve per channel. Whittle's form treats the session as periodic: for an effect as
    slow as the session (a warm-up, a temperature) it joins the end of the bias instability to its start and
    overstates the information up to several times. None for a random-walk bias (not stationary)."""
    nz = sim.noise
    if nz["bias_model"] != "gauss_markov":
        return None
    cols = as_channel_columns(cols)
    n = cols.n
    dt = 1.0 / float(sim.sample_rate_hz)
    K = np.concatenate([sim.accel.K, sim.gyro.K])
    sig_w, sig_b, tau = noise_terms(nz, dt)
    P = cols.p
    J = np.zeros((P, P))
    q = 1.0 if nz["quantize"] else 0.0
    for c in range(6):
        use, D = cols.block(c)
        if not use:
            continue
        R = sparse.diags([np.full(n - 1, -q / 12.0), np.full(n, (K[c] * sig_w[c]) ** 2 + q / 6.0),
                          np.full(n - 1, -q / 12.0)], [-1, 0, 1], format="csr")
        v = (K[c] * dt * sig_b[c]) ** 2
        if v > 0.0:
            a = math.exp(-dt / float(tau[c]))
            d = np.full(n, 1.0 + a * a)
            d[0] = d[-1] = 1.0
            T = sparse.diags([np.full(n - 1, -a), d, np.full(n - 1, -a)], [-1, 0, 1], format="csr") / (v * (1 - a * a))
            A, post = (R @ T + sparse.identity(n, format="csr")), T
        else:
            A, post = R, None
        ab = np.zeros((5, n))
        for k in range(-2, 3):
            dg = A.diagonal(k)
            if k >= 0:
                ab[2 - k, k:] = dg
            else:
                ab[2 - k, :n + k] = dg
        X = solve_banded((2, 2), ab, D)
        if post is not None:
            X = post @ X
        J[np.ix_(use, use)] += D.T @ X
        del D, X    # before the next channel's (peak memory)
    return J
