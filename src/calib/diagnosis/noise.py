"""Noise of the window means of the mismatch diagnosis: model, covariance and its restricted-ML estimate.

Noise of a window mean (per sensor axis)
-----------------------------------------
From the Allan deviation pooled over the static segments (``allan.adev_pooled``), a model
``AVAR(tau) = 3 Q^2/tau^2 + N^2/tau + K^2 tau/3`` (quantisation, white rate noise, rate random walk; terms
chosen by a penalised fit, :func:`fit_noise`). For observation weights w (:mod:`calib.diagnosis.geometry`)
the covariance is

    Cov_N(o, p) = N^2 / dt * sum_k w_ok w_pk                               (same window)
    Cov_Q(o, p) = Q^2 / dt^2 * sum_k (w_o,k-1 - w_ok)(w_p,k-1 - w_pk)      (same window; phase quantisation)
    Cov_K(o, p) = K^2 * int_0^inf W_o(u) W_p(u) du,  W_o(u) = sum_{k: t_k > u} w_ok   (all windows)

the last one the Brownian (random-walk) covariance ``K^2 min(s, t)``. A bias instability of correlation time
T_c looks like a random walk at tau << T_c (K^2 = 2 sigma_b^2 / T_c); modelling it as one over the whole
session overstates its long-lag variance, so the test is conservative for slow (time-smooth) effects
(bias drift, temperature bias), exact for white noise.

The level of the fast part and a Gauss-Markov bias instability are then estimated by restricted maximum
likelihood from the window means themselves (:func:`profile_noise`, :func:`reml_slow`); the Gauss-Markov
covariance of the window means is the closed form of :func:`calib.signal.noisecov.gm_mean_cov` (the one
implementation of that noise model), used by :func:`gm_part`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy import linalg

from calib.diagnosis.blas import solve_lower
from calib.diagnosis.geometry import SENSORS, DiagnosisInputError, Geometry, rows_of
from calib.signal import allan, noisecov

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
    scale: dict = field(default_factory=dict)     # level of the Allan shape per sensor axis (1: the Allan fit)
    N_shape: dict = field(default_factory=dict)   # white-noise shape (the Allan fit), scaled by sqrt(scale)
    Q_shape: dict = field(default_factory=dict)   # quantisation shape
    # rate random walk K per axis of the Allan fit of the static segments [unit s^-1/2], before any level or slow part
    # is estimated from the window means: the slow part the adequacy tests extend across a session without a long
    # static record (:func:`calib.diagnosis.vector.setup_problem`)
    K_allan: dict = field(default_factory=dict)
    # factorisations of the noise *shape* per axis block (:func:`shape_eig`), keyed by the shape values they
    # were computed for; set_level never changes the shape, so they stay valid for the whole diagnosis
    shape_cache: dict = field(default_factory=dict, repr=False, compare=False)

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
                c = allan.nnls(B * w[:, None], av * w)
                for _ in range(2):
                    w = np.sqrt(edf / 2.0) / np.maximum(B @ c + 3.0 * q**2 / tau**2, 1e-300)
                    c = allan.nnls(B * w[:, None], av * w)
                if not c[0] > 0:
                    # short static segments: few taus above 1 s, and the rate random walk took all of the
                    # excess over quantisation; the white level is then fitted alone (K = 0) -- a channel is
                    # flat only when its Allan variance never exceeds the quantisation's
                    c1 = allan.nnls(B[:, :1] * w[:, None], av * w)
                    c = np.array([c1[0], 0.0])
                if not c[0] > 0:
                    # white noise below what the quantisation lets the Allan deviation resolve: its upper bound
                    # (the upper 95 % Allan band less quantisation, the largest over tau) -- a larger sigma, never
                    # an absent one
                    hi = np.asarray(A.hi, float)[sel, a] ** 2 - 3.0 * q**2 / tau**2
                    c = np.array([max(float(np.max(hi * tau)), 0.0), 0.0])
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
    nf.K_allan = {s: np.array([slow[s][a][1] for a in range(3)]) for s in SENSORS}
    return nf


def gm_part(geom: Geometry, sensor: str, tc: float):
    """Covariance structure (unit variance) of a Gauss-Markov bias of correlation time ``tc`` over one axis'
    observations: exact for the window means (closed form of the double integral of exp(-|s-t|/tc)), its
    high-frequency (random-walk, K^2 = 2/tc) equivalent for the harmonic rows within their window."""
    ws = geom.windows
    rows = [rows_of(sensor, w) for w in ws]
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


@numba.njit(cache=True, nogil=True)
def _chol_grid(A, B, yy, reml, rr, ld):  # pragma: no cover - compiled
    """The design-dependent terms of one axis block in the profile likelihood of :func:`profile_noise`, for every
    grid point g: ``rr[g] += y' W y - y' W X (X' W X)^-1 X' W y`` and, for REML, ``ld[g] += ln det X' W X``, from
    the weighted Gram matrices ``A[g]`` (lower triangle, row by row: r (r + 1) / 2 entries), ``B[g] = X' W y`` and
    ``yy[g] = y' W y`` (``W`` the grid point's weights): the Cholesky factor of each Gram matrix and a forward
    solve."""
    G, r = B.shape
    L = np.empty((r, r))
    z = np.empty(r)
    for g in range(G):
        t = 0
        for p in range(r):
            for q in range(p + 1):
                L[p, q] = A[g, t]
                t += 1
        logdet = 0.0
        zz = 0.0
        for p in range(r):                      # Cholesky A = L L' in place (lower), then L z = b
            for q in range(p + 1):
                acc = L[p, q]
                for k in range(q):
                    acc -= L[p, k] * L[q, k]
                if p == q:
                    L[p, p] = math.sqrt(acc) if acc > 0.0 else 1e-300
                else:
                    L[p, q] = acc / L[q, q]
            acc = B[g, p]
            for k in range(p):
                acc -= L[p, k] * z[k]
            z[p] = acc / L[p, p]
            zz += z[p] * z[p]
            logdet += 2.0 * math.log(L[p, p])
        rr[g] += yy[g] - zz
        if reml:
            ld[g] += logdet


@numba.njit(cache=True, nogil=True)
def _profile_sensor(Xpad, ncols, ypad, L0s, Vs, Ws, lsums, reml, rr, ld, ranks):  # pragma: no cover - compiled
    """The grid of :func:`profile_noise` for one sensor's axis blocks in one call: per block b the design
    ``Xpad[b, :, :ncols[b]]`` and observations ``ypad[b]`` whitened by the fast-noise factor ``L0s[b]``, the design's
    column space (SVD, singular values above 1e-9 of the largest: its rank into ``ranks[b]``), the observations less
    their projection on it; then for every Tc index t the eigen-coordinates ``Vs[t, b]`` and the grid's weights
    ``Ws[t, b]`` (G, m): ``rr[t] += y'Wy - y'WX (X'WX)^-1 X'Wy``, ``ld[t] += sum ln d (+ ln det X'WX for REML)``
    (:func:`_chol_grid`, ``lsums[t, b]`` the weights' log-sums)."""
    B, m, _ = Xpad.shape
    T = Ws.shape[0]
    for b in range(B):
        c = ncols[b]
        X1 = np.empty((m, c))
        y1 = np.empty(m)
        for j in range(c):
            for i in range(m):
                acc = Xpad[b, i, j]
                for k in range(i):
                    acc -= L0s[b, i, k] * X1[k, j]
                X1[i, j] = acc / L0s[b, i, i]
        for i in range(m):
            acc = ypad[b, i]
            for k in range(i):
                acc -= L0s[b, i, k] * y1[k]
            y1[i] = acc / L0s[b, i, i]
        r = 0
        if c > 0:
            U, sv, _ = np.linalg.svd(X1, full_matrices=False)
            for k in range(sv.size):
                if sv[k] > 1e-9 * sv[0]:
                    r += 1
            Ur = np.ascontiguousarray(U[:, :r])
            for _ in range(2):
                coef = np.dot(Ur.T, y1)
                y1 -= np.dot(Ur, coef)
        ranks[b] = r
        nT = r * (r + 1) // 2
        for t in range(T):
            W = Ws[t, b]
            V = Vs[t, b]
            yt = np.dot(V.T, y1)
            y2 = yt * yt
            yy = np.dot(W, y2)
            if r == 0:
                for g in range(W.shape[0]):
                    rr[t, g] += yy[g]
                    ld[t, g] += lsums[t, b, g]
                continue
            Xt = np.dot(V.T, Ur)
            P = np.empty((m, nT))
            Py = np.empty((m, r))
            for i in range(m):
                q = 0
                for p_ in range(r):
                    xp = Xt[i, p_]
                    Py[i, p_] = xp * yt[i]
                    for j in range(p_ + 1):
                        P[i, q] = xp * Xt[i, j]
                        q += 1
            A = np.dot(W, P)
            Bm = np.dot(W, Py)
            rr_t = np.zeros(W.shape[0])
            ld_t = np.zeros(W.shape[0])
            _chol_grid(A, Bm, yy, reml, rr_t, ld_t)
            for g in range(W.shape[0]):
                rr[t, g] += rr_t[g]
                ld[t, g] += ld_t[g] + lsums[t, b, g]


#: the relative variances of the slow part tried by :func:`profile_noise`, in units of 1 / max(lam) (and rho = 0)
RHO_GRID = np.logspace(-4, 3, 71)
def _grid_stack(geom: Geometry, noise: NoiseFit, parts, s: str, axes, tcs, cache):
    """What :func:`_profile_sensor` needs of the noise shape of sensor ``s`` on ``axes`` for the correlation times
    ``tcs``: fast-noise factors (B, m, m), eigen-coordinates (T, B, m, m), grid weights (T, B, G, m) and their
    log-sums (T, B, G), the grid (T, G: rho in units of 1 / max lam of the first axis). Kept with the noise shape."""
    nq = tuple((float(noise.N_shape[s][a]), float(noise.Q_shape[s][a])) for a in axes)
    key = ("stack", s, tuple(axes), tuple(tcs)) + nq
    if key not in noise.shape_cache:
        L0s = np.stack([shape_factor(noise, parts, s, a) for a in axes])
        Vs, Ws, lsums, rhos = [], [], [], []
        for tc in tcs:
            eig = [shape_eig(geom, noise, parts, s, a, tc, cache) for a in axes]
            rho = np.concatenate([[0.0], (1.0 / max(eig[0][1].max(), 1e-300)) * RHO_GRID])
            d = [1.0 + rho[:, None] * lam[None, :] for _, lam, _ in eig]
            Vs.append(np.stack([V for _, _, V in eig]))
            Ws.append(np.stack([1.0 / x for x in d]))
            lsums.append(np.stack([np.sum(np.log(x), axis=1) for x in d]))
            rhos.append(rho)
        noise.shape_cache[key] = (L0s, np.ascontiguousarray(np.stack(Vs)), np.ascontiguousarray(np.stack(Ws)),
                                  np.stack(lsums), np.stack(rhos))
    return noise.shape_cache[key]


def shape_factor(noise: NoiseFit, parts, sensor: str, a: int) -> np.ndarray:
    """Cholesky factor L0 of the fast-noise shape of one axis block, ``C_fast = N_shape^2 A_N + Q_shape^2 A_Q``.

    Cached on ``noise`` (key: sensor, axis and the shape values): it depends on the geometry (``parts``) and the
    Allan shape only, not on the level or the slow part that :func:`profile_noise` and the search vary."""
    nq = (float(noise.N_shape[sensor][a]), float(noise.Q_shape[sensor][a]))
    key = ("L0", sensor, a) + nq
    if key not in noise.shape_cache:
        AN, AQ, _ = parts[sensor]
        noise.shape_cache[key] = np.linalg.cholesky(nq[0] ** 2 * AN + nq[1] ** 2 * AQ)
    return noise.shape_cache[key]


def shape_eig(geom: Geometry, noise: NoiseFit, parts, sensor: str, a: int, tc: float, cache=None):
    """``(L0, lam, V)`` of one axis block: ``C_fast = L0 L0^T`` (:func:`shape_factor`) and the eigen-decomposition
    ``L0^-1 A_slow(tc) L0^-T = V diag(lam) V^T`` (lam clipped at 0), so that every covariance of the family
    ``lam_level (C_fast + rho A_slow(tc))`` is ``lam_level L0 V (I + rho diag(lam)) V^T L0^T``.

    Cached on ``noise`` like :func:`shape_factor` (geometry and noise shape only: valid for every level, rho and
    design the diagnosis tries)."""
    nq = (float(noise.N_shape[sensor][a]), float(noise.Q_shape[sensor][a]))
    key = ("eig", sensor, a, tc) + nq
    if key not in noise.shape_cache:
        L0 = shape_factor(noise, parts, sensor, a)
        A = slow_structure(parts, geom, sensor, tc, cache)
        B = linalg.solve_triangular(L0, linalg.solve_triangular(L0, A, lower=True).T, lower=True)
        lam, V = np.linalg.eigh(0.5 * (B + B.T))
        noise.shape_cache[key] = (L0, np.clip(lam, 0.0, None), V)
    return noise.shape_cache[key]


def profile_noise(geom: Geometry, noise: NoiseFit, y, X, parts, cache=None, tcs=SLOW_TCS, *, blocks=None,
                  method: str = "reml", update: bool = True, grid_out: dict | None = None):
    """Profile likelihood of the noise of each sensor given the fixed-effect design ``X``, pooled over the
    sensor's three axis blocks (one level, one bias instability for the triad):

        C_axis = lam (C_fast,axis + rho A_GM(Tc)),   C_fast,axis = N_a^2 A_N + Q_a^2 A_Q  (Allan shape)

    ``lam`` profiled analytically, ``rho`` on a log grid (plus 0) for every Tc in ``tcs`` (per block
    C_fast = L L^T, L^-1 A L^-T = V Lam V^T, cached per block and Tc by :func:`shape_eig`, so every rho costs
    O(m)). ``method='reml'``: restricted likelihood of
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
        axes = [a for _, a in mine]
        L0s, Vs, Ws, lsums, rhos = _grid_stack(geom, noise, parts, s, axes, tcs, cache)
        idxs = [geom.obs["blocks"][(si, a)] for a in axes]
        m = len(idxs[0])
        if any(len(i) != m for i in idxs):
            raise ValueError("profile_noise: the axis blocks of a sensor must have as many observations")
        nzc = [np.flatnonzero(np.any(X[i] != 0, axis=0)) for i in idxs]
        Xpad = np.zeros((len(axes), m, max(max((c.size for c in nzc), default=0), 1)))
        for b, (i, c) in enumerate(zip(idxs, nzc)):
            Xpad[b, :, :c.size] = X[i][:, c]
        ypad = np.stack([np.asarray(y, float)[i] for i in idxs])
        rr = np.zeros(rhos.shape)
        ld = np.zeros(rhos.shape)
        ranks = np.zeros(len(axes), np.int64)
        _profile_sensor(Xpad, np.array([c.size for c in nzc], np.int64), ypad, L0s, Vs, Ws, lsums,
                        method == "reml", rr, ld, ranks)
        m_tot = m * len(axes)
        nfree = m_tot - (int(ranks.sum()) if method == "reml" else 0)
        lam_hat = rr / nfree
        nll = nfree * np.log(lam_hat) + ld
        if grid_out is not None:
            for t, tc in enumerate(tcs):
                grid_out.setdefault(s, []).extend(
                    (float(v), tc, float(r), float(lh)) for v, r, lh in zip(nll[t], rhos[t], lam_hat[t]))
        white = (float(nll[0, 0]), math.inf, 0.0, float(lam_hat[0, 0]))
        best = None
        for t, tc in enumerate(tcs):
            j = int(np.argmin(nll[t]))
            if best is None or nll[t, j] < best[0]:
                best = (float(nll[t, j]), tc, float(rhos[t, j]), float(lam_hat[t, j]))
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
    covariance is ``N^2 A_N + Q^2 A_Q + K^2 A_K`` (formulas in the module docstring). ``rw_within_only``: A_K
    within each window alone (no cross-window random-walk terms). The within-window parts are derived once per
    geometry and sensor (:meth:`Geometry.derived`) and shared by both forms; the callers only read them."""
    AN, AQ, AK_within, S, I, tmid0, starts, rows = geom.derived(("covariance_parts_within", sensor),
                                                               lambda: _within_window_parts(geom, sensor))
    if rw_within_only:
        return AN, AQ, AK_within
    ws = geom.windows
    AK = AK_within.copy()
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


def _within_window_parts(geom: Geometry, sensor: str):
    """:func:`covariance_parts` within each window, and what its cross-window terms need: per observation row the
    sum of weights S, int_0^inf W(u) du I, the window's first mid-time; the windows' row offsets and counts."""
    dt = geom.dt
    ws = geom.windows
    rows = [rows_of(sensor, w) for w in ws]
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
    return AN, AQ, AK, S, I, tmid0, starts, rows


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


def within_segment_blocks(geom: Geometry, noise: NoiseFit):
    """Per (sensor index, axis) covariance blocks and Cholesky factors of the noise the session measures within
    its segments, with no slow part: white noise and quantisation of the Allan shape (before any level is estimated
    from the window means), ``N^2 A_N + Q^2 A_Q``. Left out: every slow part -- a bias instability between the
    segments, which the static samples of the session (taus up to one segment) do not measure."""
    C, L = {}, {}
    for si, s in enumerate(SENSORS):
        AN, AQ, _ = covariance_parts(geom, s, rw_within_only=True)
        for a in range(3):
            c = noise.N_shape[s][a] ** 2 * AN + noise.Q_shape[s][a] ** 2 * AQ
            C[(si, a)] = c
            L[(si, a)] = np.linalg.cholesky(c)
    return C, L


# ----------------------------------------------------------------------------------------------------------
# measured slow noise: a long static record of the same unit
# ----------------------------------------------------------------------------------------------------------
_RECORD_MODELS: dict = {}
_RECORD_POINT: dict = {}
_RECORD_MINUTES: dict = {}


def _record_key(path):
    from pathlib import Path

    p = Path(path)
    return (str(p.resolve()), p.stat().st_mtime_ns)


def record_point_models(path) -> dict:
    """Per sensor, the noise model fitted to the *point estimate* of the Allan deviation of the long static record
    ``path`` (the level the record measures; :func:`record_noise_models` fits the upper end of its 95 % band, the
    level no record of that length excludes), fitted with it and cached alike."""
    key = _record_key(path)
    if key not in _RECORD_POINT:
        _RECORD_MODELS.pop(key, None)
        record_noise_models(path)
    return _RECORD_POINT[key]


def record_minutes(path) -> float:
    """Length of the long static record ``path`` [min] (read with its noise models)."""
    key = _record_key(path)
    if key not in _RECORD_MINUTES:
        _RECORD_MODELS.pop(key, None)
        record_noise_models(path)
    return _RECORD_MINUTES[key]


def record_noise_models(path) -> dict:
    """Per sensor, the noise model (:class:`calib.signal.noisecov.MeanNoiseModel`: white, quantisation and a
    Gauss-Markov or random-walk slow part) fitted to the Allan deviation of a long static record of the same
    unit (tau up to half its length), cached by path and modification time."""
    from pathlib import Path

    from calib.io import recording

    p = Path(path)
    key = (str(p.resolve()), p.stat().st_mtime_ns)
    if key not in _RECORD_MODELS:
        ds = recording.load_arrays(p)   # numpy arrays: no xarray in calib diagnose's process
        models, points = {}, {}
        for s in SENSORS:
            la = noisecov.long_record_allan(ds, s)
            # the slow noise at the upper end of the record's 95 % Allan intervals: a record too short to resolve
            # the bias instability must not make noise look like physics
            hi = dataclasses.replace(la, adev=np.asarray(la.hi, float), lo=np.asarray(la.adev, float),
                                     hi=np.asarray(la.hi, float) ** 2 / np.asarray(la.adev, float))
            pc = noisecov.is_pulse_counter(ds, s)
            models[s] = noisecov.fit_mean_noise([hi], Q=noisecov.PULSE_COUNTER_Q if pc else None, unit=la.unit,
                                                source=f"upper 95 % Allan band of the long static record {p.name} "
                                                       f"({la.n_samples / la.fs / 3600:.3g} h)")
            points[s] = noisecov.fit_mean_noise([la], Q=noisecov.PULSE_COUNTER_Q if pc else None, unit=la.unit,
                                                source=f"Allan deviation (point estimate) of the long static record "
                                                       f"{p.name} ({la.n_samples / la.fs / 3600:.3g} h)")
        for cache in (_RECORD_MODELS, _RECORD_POINT, _RECORD_MINUTES):
            cache.clear()
        _RECORD_MODELS[key] = models
        _RECORD_POINT[key] = points
        _RECORD_MINUTES[key] = la.n_samples / la.fs / 60.0
    return _RECORD_MODELS[key]


def with_measured_slow(noise: NoiseFit, geom: Geometry, path) -> NoiseFit:
    """A copy of ``noise`` (fast noise from the session's own static segments) whose slow part per axis is the
    one measured on the long static record ``path`` (never estimated from the window means)."""
    import copy

    models = record_noise_models(path)
    # the factorisations of the noise shape (shape_cache) hold for the copy too (it changes the slow part only) and
    # are never changed in place: the copy gets its own dict of the same entries, not copies of every array
    out = copy.deepcopy(dataclasses.replace(noise, shape_cache={}))
    out.shape_cache = dict(noise.shape_cache)
    for s in SENSORS:
        m = models[s]
        if m.unit != geom.units_out[s]:
            raise DiagnosisInputError(f"noise record {path}: '{s}' rate unit {m.unit!r} differs from the session's "
                                      f"{geom.units_out[s]!r}", "give a long static record of the same unit")
        for a in range(3):
            if m.slow[a] == "gm":
                out.slow[s][a] = (float(m.tc[a]), float(m.sigma[a]))
            elif m.slow[a] == "rw":
                out.slow[s][a] = (math.inf, float(m.K[a]))
            else:
                out.slow[s][a] = (math.inf, 0.0)
    out.method = (noise.method.split(";")[0] + f"; slow part measured on the long static record {path}")
    return out
