"""Mismatch diagnosis: does the base sensor model fit a calibration recording, and if not, what is missing?

``calib diagnose RECORDING.nc --out DIR`` (:func:`diagnose_recording`, or ``python -m calib.diagnose``) writes
``DIR/report.json``, ``DIR/report.md`` and figures for any ``calib-recording-1`` file that has a segment
table (synthetic, or imported with detected static segments).

Method
------
1. **Base model and goodness of fit.** Observations are window reductions of the rate readings
   (:mod:`calib.signatures`): static-segment means and, for rotation segments cut to whole revolutions with
   the table angle, the mean and the first table-angle harmonics. With nominal attitudes (synthetic
   sessions) the *vector* model is used: ``N = M x + b`` per triad (M = K E, seed 000 eqs. 1-4) with known
   inputs x (f = C_n^b (0, 0, g), omega = table rate + C_n^b omega_ie^n) -- linear, 24 parameters, all
   identified. Without attitudes (real recordings) the *norm* model of the accelerometer is used (seed 000
   eq. 7, identified lower-triangular form, :mod:`calib.objectives`), see :func:`_norm_problem`.
   The fit is generalised least squares with the covariance of the window means from the noise model
   (:func:`calib.signatures.fit_noise`: Allan deviation for white noise and quantisation, restricted ML of
   the base residuals for the slow random-walk part). chi-square per (sensor, axis) block and overall, with
   p-values; standardised residuals per segment.
2. **Locate.** Where the misfit lives: per (sensor, axis); per static phase the harmonics of the table
   angle (positions ``step`` apart) and the disagreement between phase means; per rotation pair the sum and
   the difference of the +/- residuals against |rate|; the phase-quadrature part of the gyro harmonics
   against rate; the time course (residual chi-square in time bins).
3. **Name.** A library of candidate terms (the ids of :mod:`calib.effects`, verbatim), each with its own
   parameters. Before fitting: the fraction of each signature the base parameters absorb
   (``1 - |P_perp s| / |s|``, whitened), the visible rank, and the smallest principal angle between the
   visible signatures of every pair of candidates (alias groups: angle < ``alias_angle_deg``). Then forward
   stepwise selection: the candidate with the largest BIC gain is added if its BIC gain is positive and its
   likelihood-ratio test has p < ``alpha``; repeat until nothing passes. Aliases of a found term: every other
   candidate that, in its place, gives a BIC within ``alias_delta_bic`` of the final model, or whose visible
   signature lies within ``alias_angle_deg`` of it.
4. **Model it.** Refit with the selected terms: chi-square and residual RMS before/after, residual figures,
   estimates with 95 % intervals (``1.96`` standard errors of the GLS fit; the clock offset by Gauss-Newton
   at its profile optimum; the warm-up time constant of a bias drift profiled on a grid and the other drift
   parameters conditional on it), and how the base parameters moved (in their standard errors).
5. **Report.** verdict (``adequate`` | ``missing_physics`` | ``inconclusive``), ``found[]``, ``absent[]``
   (tested, with 95 % upper bounds), ``untestable[]`` (why, and the experiment that would make it testable).

:func:`run_proof` runs the concealed-effect proof (seed 000 path, simulator of :mod:`calib.simulate`) and
:func:`score` compares a report with a truth sidecar.
"""
from __future__ import annotations

import copy
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import linalg, optimize, stats

from . import signatures as sg
from .signatures import SENSORS, AXES, DiagnosisInputError

REPORT_FORMAT = "calib-diagnosis-1"

DEFAULT_SETTINGS = {
    "alpha": 0.001,              # LRT significance for adding a term (per step)
    "alias_delta_bic": 10.0,     # another term within this BIC of the final model is an alias
    "alias_angle_deg": 5.0,      # visible signatures closer than this are aliases
    "absorbed_untestable": 0.999,  # a term whose signature the base absorbs to more than this is untestable
    "visible_rel": 1e-2,         # parameters whose visible signature is below this fraction of the
                                 # candidate's strongest are 'not determined' by the path
    "chi2_p_adequate": 0.01,     # base-model chi-square p below this -> the base model does not fit
    "min_static": 6,             # fewer static segments -> inconclusive
    "min_duration_s": 60.0,      # shorter recordings -> inconclusive
    "max_offset_s": 0.25,        # clock offsets tried [s]
    "max_steps": 6,
    "figures": True,
}


# =====================================================================================================
# problem: observations, whitening, base design, library
# =====================================================================================================
@dataclass
class Problem:
    geom: sg.Geometry
    y: np.ndarray                 # observations
    noise: sg.NoiseFit
    parts: dict                   # covariance parts per sensor
    L: dict                       # Cholesky factors per (sensor index, axis)
    X0: np.ndarray                # base design at zero clock offset (n, 24)
    lib: list                     # candidates
    readings: dict                # per-sample rate readings per sensor
    n_noise_params: int = 12      # noise parameters estimated from the residuals (Tc, sigma per block)
    settings: dict = field(default_factory=dict)
    cache: dict = field(default_factory=dict)   # slow-noise structures per (sensor, Tc)

    @property
    def n(self) -> int:
        return self.y.size

    def whiten(self, A):
        """L^-1 A block by block (A (n,) or (n, k))."""
        A = np.asarray(A, float)
        out = np.empty_like(A)
        for key, idx in self.geom.obs["blocks"].items():
            out[idx] = linalg.solve_triangular(self.L[key], A[idx], lower=True)
        return out

    def sigma(self):
        """Standard deviation of every observation (diagonal of the covariance)."""
        s = np.empty(self.n)
        for (si, a), idx in self.geom.obs["blocks"].items():
            s[idx] = np.sqrt(np.einsum("ij,ij->i", self.L[(si, a)], self.L[(si, a)]))
        return s

    def wcache(self, name, fn):
        """Whitened quantity cached by name (the noise model is fixed once set up)."""
        c = self.__dict__.setdefault("_wc", {})
        if name not in c:
            c[name] = self.whiten(fn())
        return c[name]

    def cand(self, key):
        for c in self.lib:
            if c.key == key:
                return c
        raise KeyError(key)


@dataclass
class Fit:
    """A GLS fit of the base model plus a set of terms."""

    terms: list                   # candidate keys, in order
    theta: np.ndarray
    cov: np.ndarray
    chi2: float
    dof: int
    k: int                        # number of fitted parameters (rank + nonlinear ones)
    names: list
    slices: dict                  # key -> slice into theta
    resid: np.ndarray             # raw residuals y - prediction
    resid_w: np.ndarray           # whitened residuals
    delta: float = 0.0            # clock offset used
    taus: dict = field(default_factory=dict)   # drift tau per drift candidate key
    active: dict = field(default_factory=dict)  # key -> indices of the candidate's determined parameters
    X: np.ndarray | None = None

    @property
    def p(self) -> float:
        return float(stats.chi2.sf(self.chi2, max(self.dof, 1)))

    def bic(self, n) -> float:
        return self.chi2 + self.k * math.log(n)


def _base_estimates(theta):
    M = {"accel": theta[0:9].reshape(3, 3), "gyro": theta[12:21].reshape(3, 3)}
    b = {"accel": theta[9:12].copy(), "gyro": theta[21:24].copy()}
    return M, b


def _lstsq(Aw, yw):
    """Least squares on unit-norm columns by pivoted QR with a rank cut: (theta, cov, rank)."""
    nrm = np.linalg.norm(Aw, axis=0)
    nrm[nrm == 0] = 1.0
    An = Aw / nrm
    Q, R, piv = linalg.qr(An, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > 1e-9 * d[0])) if d.size else 0
    Rk = R[:rank, :rank]
    z = linalg.solve_triangular(Rk, Q[:, :rank].T @ yw)
    theta = np.zeros(Aw.shape[1])
    theta[piv[:rank]] = z
    Ri = linalg.solve_triangular(Rk, np.eye(rank))
    cov = np.zeros((Aw.shape[1], Aw.shape[1]))
    cov[np.ix_(piv[:rank], piv[:rank])] = Ri @ Ri.T
    theta /= nrm
    cov /= np.outer(nrm, nrm)
    return theta, cov, rank


def setup_problem(ds, settings=None, *, library_from=None) -> Problem:
    """Observations, noise model, covariance, base design and effect library of a recording dataset.

    ``library_from``: a previous :class:`Problem` on the same geometry whose library (signatures at its base
    solution) is reused (the proof: every noise seed of a session shares the geometry).
    """
    st = {**DEFAULT_SETTINGS, **(settings or {})}
    if library_from is not None:
        geom = library_from.geom
    else:
        geom = sg.build_geometry(ds, max_offset_s=st["max_offset_s"], min_static=st["min_static"])
    if geom.n_samples / geom.fs < st["min_duration_s"]:
        raise DiagnosisInputError(f"{geom.source}: recording lasts {geom.n_samples / geom.fs:.1f} s, less than "
                                  f"{st['min_duration_s']:.0f} s", "record a longer session")
    if geom.model != "vector":
        raise DiagnosisInputError("no nominal attitudes: the vector model needs them", "use the norm problem")
    y, readings = sg.reduce_data(geom, ds)
    noise = sg.fit_noise(geom, readings)
    if library_from is not None:
        parts = library_from.parts
        xr, ones = None, None
        X0 = library_from.X0
    else:
        parts = {s: sg.covariance_parts(geom, s) for s in SENSORS}
        xr, ones = sg.reduced_inputs(geom)
        X0 = sg.base_design(geom, xr, ones)
    cache = library_from.cache if library_from is not None else {}
    _, L = sg.covariance_blocks(geom, noise, parts, cache)        # first guess (Allan random walk)
    prob = Problem(geom, y, noise, parts, L, X0, [], readings, settings=st, cache=cache)
    if library_from is not None:
        prob.lib = library_from.lib
    else:
        base = fit(prob, [])
        M, b = _base_estimates(base.theta)
        prob.lib = sg.build_library(geom, M, b, xr0=xr, ones0=ones)
        _prepare_library(prob)
    # slow noise by REML on the contrasts orthogonal to the base model and every candidate term
    sg.reml_slow(geom, noise, y, _reml_design(prob), parts, cache)
    _, prob.L = sg.covariance_blocks(geom, noise, parts, cache)
    prob.__dict__.pop("_wc", None)
    _prepare_library(prob)
    return prob


def _reml_design(prob: Problem):
    """Base design plus every candidate's columns (drift at two time constants, the clock offset to second
    order): the fixed effects REML integrates out."""
    cols = [prob.X0]
    for c in prob.lib:
        if c.untestable:
            continue
        if c.kind == "drift":
            cols += [c.S_by_tau[300.0], c.S_by_tau[3600.0]]
        elif c.kind == "offset":
            M, _ = _base_estimates(fit(prob, []).theta)
            cols += [c.offset.design_delta(0.0, M, deriv=1)[:, None], c.offset.design_delta(0.0, M, deriv=2)[:, None]]
        else:
            cols.append(c.S)
    return np.hstack(cols)


def _prepare_library(prob: Problem):
    """Visible (determined) parameters of every candidate against the base model, whitened."""
    vr = prob.settings["visible_rel"]
    Xw = prob.whiten(prob.X0)
    Q, _ = np.linalg.qr(Xw)
    for c in prob.lib:
        if c.untestable or c.S is None:
            c.active = np.arange(c.p)
            c.visible = np.zeros(c.p)
            c.absorbed = np.ones(c.p)
            continue
        Sw = prob.whiten(c.S)
        P = Sw - Q @ (Q.T @ Sw)
        nrm = np.linalg.norm(Sw, axis=0)
        vis = np.linalg.norm(P, axis=0)
        c.visible = vis
        c.absorbed = 1.0 - np.divide(vis, nrm, out=np.zeros_like(vis), where=nrm > 0)
        keep = np.flatnonzero(vis > vr * max(vis.max(), 1e-300))
        # drop columns that are linear combinations of the others (pivoted QR on the visible parts)
        if keep.size > 1:
            _, R, piv = linalg.qr(P[:, keep], mode="economic", pivoting=True)
            d = np.abs(np.diag(R))
            rank = int(np.sum(d > 1e-6 * d[0]))
            keep = np.sort(keep[piv[:rank]])
        c.active = keep if vis.max() > 0 else np.arange(0)


# =====================================================================================================
# fitting
# =====================================================================================================
def _columns(prob: Problem, key, taus):
    c = prob.cand(key)
    if c.kind == "drift":
        S = c.S_by_tau[taus.get(key, 900.0)]
    else:
        S = c.S
    return S[:, c.active]


def fit(prob: Problem, terms, *, delta=None, taus=None, keep_X=False, offset_column=True) -> Fit:
    """GLS fit of the base model plus ``terms`` (candidate keys). Nonlinear parameters (clock offset, drift
    time constants) are optimised by profile likelihood unless given."""
    terms = list(terms)
    taus = dict(taus or {})
    drift_keys = [k for k in terms if prob.cand(k).kind == "drift"]
    has_off = "time_offset" in terms
    if has_off and delta is None:
        return _fit_offset(prob, terms, taus)
    missing = [k for k in drift_keys if k not in taus]
    if missing:
        return _fit_drift_taus(prob, terms, taus, delta, missing, offset_column)
    d = float(delta or 0.0) if has_off else 0.0
    if has_off:
        X = prob.cand("time_offset").offset.patch_design(prob.X0, d)
        Xw = prob.whiten(X)
    else:
        X = prob.X0
        Xw = prob.wcache("X0", lambda: prob.X0)
    yw = prob.wcache("y", lambda: prob.y)
    cols, wcols, names, slices, active = [X], [Xw], list(sg.BASE_NAMES), {}, {}
    pos = X.shape[1]
    for k in terms:
        if k == "time_offset":
            continue
        c = prob.cand(k)
        tau = taus.get(k, 900.0) if c.kind == "drift" else None
        S = _columns(prob, k, taus)
        Sw = prob.wcache(("S", k, tau), lambda: S)
        cols.append(S)
        wcols.append(Sw)
        slices[k] = slice(pos, pos + S.shape[1])
        active[k] = c.active
        names += [f"{k}:{c.names[j]}" for j in c.active]
        pos += S.shape[1]
    if has_off and offset_column:
        # Gauss-Newton column of the offset at d (with the base M of a first solve): the linear correction
        # is ~0 at the profile optimum and the joint covariance includes the offset
        th0, _, _ = _lstsq(np.hstack(wcols), yw)
        M, _ = _base_estimates(th0)
        J = prob.cand("time_offset").offset.design_delta(d, M, deriv=1)
        cols.append(J[:, None])
        wcols.append(prob.whiten(J[:, None]))
        slices["time_offset"] = slice(pos, pos + 1)
        active["time_offset"] = np.array([0])
        names.append("time_offset:offset_s")
    Aw = np.hstack(wcols)
    theta, cov, rank = _lstsq(Aw, yw)
    rw = yw - Aw @ theta
    A = np.hstack(cols)
    resid = prob.y - A @ theta
    if has_off and offset_column:
        theta = theta.copy()
        theta[slices["time_offset"]] += d   # the column is a correction about d: report the offset itself
    chi2 = float(rw @ rw)
    k = rank + len(drift_keys) + (1 if has_off and not offset_column else 0)
    dof = prob.n - k - prob.n_noise_params
    return Fit(terms, theta, cov, chi2, dof, k, names, slices, resid, rw, delta=d, taus=dict(taus),
               active=active, X=A if keep_X else None)


def _fit_offset(prob: Problem, terms, taus):
    """Profile the clock offset: coarse scan on the library grid, then bounded Brent."""
    om = prob.cand("time_offset").offset
    lo, hi = om.bounds
    grid = np.linspace(lo, hi, 21)

    def f(d):
        return fit(prob, terms, delta=float(d), taus=taus, offset_column=False).chi2

    vals = np.array([f(d) for d in grid])
    j = int(np.argmin(vals))
    a, b = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
    r = optimize.minimize_scalar(f, bounds=(a, b), method="bounded", options={"xatol": 1e-6})
    return fit(prob, terms, delta=float(r.x), taus=taus)


def _fit_drift_taus(prob: Problem, terms, taus, delta, missing, offset_column=True):
    """Profile the warm-up time constant of each drift term over the grid (coordinate-wise, two sweeps)."""
    cur = dict(taus)
    for k in missing:
        cur[k] = 900.0
    best = None
    for _ in range(2 if len(missing) > 1 else 1):
        for k in missing:
            res = []
            for tau in sg.DRIFT_TAUS:
                t2 = dict(cur)
                t2[k] = tau
                res.append((fit(prob, terms, delta=delta, taus=t2, offset_column=False).chi2, tau))
            cur[k] = min(res)[1]
    best = fit(prob, terms, delta=delta, taus=cur, offset_column=offset_column)
    return best


# =====================================================================================================
# identifiability of the library: absorbed fractions, angles, alias groups
# =====================================================================================================
def _visible_basis(prob: Problem, Q, key, taus=None, rows=None):
    c = prob.cand(key)
    if c.kind == "offset":
        S = c.S
    else:
        S = _columns(prob, key, taus or {})
    Sw = prob.whiten(S)
    if rows is not None:
        Sw = Sw[rows]
    P = Sw - Q @ (Q.T @ Sw)
    U, s, _ = np.linalg.svd(P, full_matrices=False)
    if s.size == 0 or s[0] <= 0:
        return np.zeros((P.shape[0], 0))
    return U[:, s > 1e-6 * s[0]]


def principal_angle_deg(A, B) -> float:
    """Smallest principal angle [deg] between the column spaces of orthonormal A and B."""
    if A.shape[1] == 0 or B.shape[1] == 0:
        return float("nan")
    s = np.linalg.svd(A.T @ B, compute_uv=False)
    return float(np.degrees(np.arccos(np.clip(s.max(), -1.0, 1.0))))


def library_geometry(prob: Problem, rows=None, terms=()):
    """Absorbed fraction, visible rank and pairwise smallest principal angles of the testable candidates,
    against the base model plus ``terms`` (whitened; optionally on a subset of observation ``rows``)."""
    X = prob.X0
    extra = [_columns(prob, k, {}) for k in terms if prob.cand(k).kind != "offset"]
    A = np.hstack([X] + extra) if extra else X
    Aw = prob.whiten(A)
    if rows is not None:
        Aw = Aw[rows]
    Q, R = np.linalg.qr(Aw)
    d = np.abs(np.diag(R))
    Q = Q[:, d > 1e-10 * d.max()]
    keys = [c.key for c in prob.lib if not c.untestable and c.key not in terms]
    info, bases = {}, {}
    for k in keys:
        c = prob.cand(k)
        S = c.S if c.kind == "offset" else _columns(prob, k, {})
        Sw = prob.whiten(S)
        if rows is not None:
            Sw = Sw[rows]
        nrm = np.linalg.norm(Sw)
        P = Sw - Q @ (Q.T @ Sw)
        vis = np.linalg.norm(P)
        bases[k] = _visible_basis(prob, Q, k, rows=rows)
        info[k] = {"absorbed_fraction": float(1.0 - vis / nrm) if nrm > 0 else 1.0,
                   "visible_rank": int(bases[k].shape[1]), "n_parameters": int(c.p),
                   "determined_parameters": [c.names[j] for j in c.active] if c.kind != "offset" else c.names}
    angles = []
    for i, a in enumerate(keys):
        for b in keys[i + 1:]:
            ang = principal_angle_deg(bases[a], bases[b])
            angles.append((a, b, ang))
    return info, angles


# =====================================================================================================
# stepwise selection
# =====================================================================================================
def testable_keys(prob: Problem):
    thr = prob.settings["absorbed_untestable"]
    out = []
    for c in prob.lib:
        if c.untestable:
            continue
        if c.kind == "offset":
            out.append(c.key)
            continue
        if c.active.size == 0 or np.all(c.absorbed[c.active] > thr):
            continue
        out.append(c.key)
    return out


def stepwise(prob: Problem, base: Fit | None = None):
    """Forward selection by BIC with a likelihood-ratio test. Returns (final fit, steps, candidate table of
    the last step)."""
    st = prob.settings
    n = prob.n
    cur = base or fit(prob, [])
    steps = []
    keys = testable_keys(prob)
    last_table = []
    for _ in range(st["max_steps"]):
        table = []
        for k in keys:
            if k in cur.terms:
                continue
            f = fit(prob, cur.terms + [k])
            dchi = cur.chi2 - f.chi2
            dk = f.k - cur.k
            if dk <= 0:
                continue
            dbic = dchi - dk * math.log(n)
            p = float(stats.chi2.sf(max(dchi, 0.0), dk))
            table.append({"term": k, "delta_chi2": dchi, "delta_k": dk, "delta_bic": dbic, "p_lrt": p, "fit": f})
        table.sort(key=lambda r: -r["delta_bic"])
        last_table = table
        ok = [r for r in table if r["delta_bic"] > 0 and r["p_lrt"] < st["alpha"]]
        if not ok:
            break
        best = ok[0]
        steps.append({k: v for k, v in best.items() if k != "fit"} | {"chi2_after": best["fit"].chi2})
        cur = best["fit"]
    return cur, steps, last_table


# =====================================================================================================
# synthetic sessions for the proof and the tests
# =====================================================================================================
SESSION_BASE = {"site": {"latitude_deg": 30.58, "height_m": 0.0}}


class FastSession:
    """Noise seeds of one synthetic session configuration without re-running the kinematics.

    The clean increments of :func:`calib.simulate.simulate_calibration_session` do not depend on the seed,
    so they are computed once (the simulator's own ``CountsEngine._clean``); each seed then runs the
    simulator's own noise and pulse-counter kernel (``CountsEngine.next``) on them and the counts replace
    those of a template dataset (same segment table, table angle and temperature). The result is
    bit-identical to the file the simulator writes for that seed (checked in the tests). The truth stays in
    ``self.truth`` (the sidecar content), which only :func:`score` reads.
    """

    def __init__(self, cfg: dict, workdir=None, template_seed: int = 0):
        from . import recording, simulate

        self.cfg = copy.deepcopy(cfg)
        self._tmp = None
        if workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="calib-diag-")
            workdir = self._tmp.name
        workdir = Path(workdir)
        self.path = workdir / "template.nc"
        self.truth_path = workdir / "template.truth.json"
        simulate.simulate_calibration_session(self.cfg, template_seed, self.path, self.truth_path)
        self.template = recording.load(self.path)
        self.truth = json.loads(self.truth_path.read_text())
        self.sim = simulate.build_calibration_simulator(self.cfg, template_seed)
        n = self.sim.n_samples
        eng = self.sim.engine()
        self.clean = np.empty((n, 6))
        for i0 in range(0, n, simulate.NOISE_BLOCK):
            k = min(simulate.NOISE_BLOCK, n - i0)
            self.clean[i0:i0 + k] = eng._clean(i0, k)
        self.n = n

    def counts(self, seed: int):
        from . import simulate

        s = self.sim
        eng = simulate.CountsEngine(s.accel, s.gyro, s.noise, s.effects, s.site, s.sample_rate_hz, int(seed),
                                    s.inputs, s.temperature, n_nodes=3)
        clean = self.clean
        eng._clean = lambda i0, k: clean[i0:i0 + k]
        dtype = np.int32 if s.noise["quantize"] else np.float64
        acc = np.empty((self.n, 3), dtype=dtype)
        gyr = np.empty((self.n, 3), dtype=dtype)
        for i0 in range(0, self.n, simulate.NOISE_BLOCK):
            ch = eng.next(min(simulate.NOISE_BLOCK, self.n - i0))
            acc[i0:i0 + len(ch.accel)] = ch.accel
            gyr[i0:i0 + len(ch.gyro)] = ch.gyro
        return acc, gyr

    def dataset(self, seed: int):
        acc, gyr = self.counts(seed)
        ds = self.template.copy()
        ds["accel"] = (ds["accel"].dims, acc, ds["accel"].attrs)
        ds["gyro"] = (ds["gyro"].dims, gyr, ds["gyro"].attrs)
        ds.attrs["_path"] = f"<{self.path.name} seed {seed}>"
        return ds

    def truth_for(self, seed: int) -> dict:
        t = copy.deepcopy(self.truth)
        t["seed"] = int(seed)
        return t
