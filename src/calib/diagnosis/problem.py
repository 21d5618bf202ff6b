"""The diagnosis problem and a fit on it: settings, :class:`Problem`, :class:`Fit` and the least-squares core."""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from calib.core.distributions import chi2_sf
from calib.core.errors import InputError
from calib.diagnosis import kernels
from calib.diagnosis.blas import pivoted_qr, solve_lower, solve_tri
from calib.diagnosis.geometry import BASE_NAMES, Geometry
from calib.diagnosis.noise import NoiseFit

REPORT_FORMAT = "calib-diagnosis-1"

DEFAULT_SETTINGS = {
    "alpha": 0.001,              # LRT significance for adding a term (per step)
    "min_delta_bic": 2.0,        # and its BIC gain must exceed this ("positive evidence")
    "alias_delta_bic": 10.0,     # another term within this BIC of the final model is an alias
    "alias_angle_deg": 5.0,      # visible signatures closer than this are aliases
    "generic_delta_bic": 6.0,    # a found term must beat a generic basis (no physics) in its place by more than this
                                 # BIC ("strong" evidence, Kass & Raftery 1995), else it is not established
    "alias_noncentrality": 13.0,  # found term beats the other by less than this expected chi2: aliases
                                  # ((1.96 + 1.645)^2: a 5 % test with 95 % power)
    "absorbed_untestable": 0.999,  # a term whose signature the base absorbs to more than this is untestable
    "visible_rel": 1e-4,         # parameters whose visible signature is below this fraction of the
                                 # candidate's strongest are 'not determined' by the path (weakly visible
                                 # ones are kept when their standard error is not hopeless: dropping them
                                 # biased the lever-arm diagonal by their leakage, coverage 0.91 at 1e-2)
    "chi2_p_adequate": 0.01,     # base-model chi-square p below this -> the base model does not fit
    "adequacy_alpha": 0.01,      # family-wise level of the adequacy tests (Holm over global, per sensor axis,
                                 # per segment class, first/last third): a rejection leaves the data unexplained
    "min_static": 6,             # fewer static segments -> inconclusive
    "min_duration_s": 60.0,      # shorter recordings -> inconclusive
    "max_offset_s": 0.25,        # clock offsets tried [s]
    "max_steps": 6,
    "figures": True,
    "noise_record": None,        # long static record of the same unit: the slow noise of the adequacy tests
    "absent_bounds": True,       # 95 % upper bounds of the tested-and-absent terms (a refit per term; nothing
                                 # else in the report depends on them: the proof's per-seed runs skip them)
    "report_detail": True,       # the parts of the report no verdict or finding depends on: where the misfit lies
                                 # (locate), the absorbed fractions and the angles of pairs without a found term,
                                 # the separations (the proof's per-seed runs, scored on verdicts and findings, skip
                                 # them; a test shows the rest of a report unchanged)
}


#: the settings whose value is a probability or fraction (0 < v <= 1)
_FRACTIONS = {"alpha", "chi2_p_adequate", "adequacy_alpha", "absorbed_untestable", "visible_rel"}


def settings_of(settings: dict | None, file=None) -> dict:
    """:data:`DEFAULT_SETTINGS` with the overrides ``settings``, each checked against its default: an unknown name, a
    value of another type (true/false for the switches, a number for the numbers, a whole number for the counts, a
    path or nothing for ``noise_record``) or out of range (fractions in (0, 1], the rest >= 0) is refused by an
    :class:`calib.core.errors.InputError` naming ``file`` (the settings file, when there is one) and the setting."""
    out = dict(DEFAULT_SETTINGS)
    for key, v in (settings or {}).items():
        if key not in DEFAULT_SETTINGS:
            raise InputError(f"unknown setting {key!r}", file=file, field=str(key),
                             fix=f"use one of {', '.join(sorted(DEFAULT_SETTINGS))}")
        d = DEFAULT_SETTINGS[key]
        if isinstance(d, bool):
            ok, want = isinstance(v, (bool, np.bool_)), "true or false"
        elif d is None:
            ok, want = v is None or isinstance(v, (str, os.PathLike)), "a file path or null"
        elif isinstance(d, int):
            ok, want = isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)) and v >= 0, \
                "a whole number >= 0"
        else:
            ok = (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
                  and math.isfinite(v) and (0 < v <= 1 if key in _FRACTIONS else v >= 0))
            want = "a number in (0, 1]" if key in _FRACTIONS else "a number >= 0"
        if not ok:
            raise InputError(f"{json.dumps(v, default=str)} is not {want}", file=file, field=str(key),
                             fix=f"the default is {json.dumps(d)}")
        out[key] = v
    return out


@dataclass
class Problem:
    """A recording set up for the diagnosis: observations, noise model and its whitening, base design and
    effect library (:func:`calib.diagnosis.vector.setup_problem`, :func:`calib.diagnosis.norm.setup_norm_problem`).
    """

    geom: Geometry
    y: np.ndarray                 # observations (norm model: base residuals at the base solution)
    noise: NoiseFit
    parts: dict                   # covariance parts per sensor
    L: dict                       # Cholesky factors per (sensor index, axis)
    X0: np.ndarray                # base design at zero clock offset (n, 24)
    lib: list                     # candidates
    readings: dict                # per-sample rate readings per sensor
    n_noise_params: int = 18      # noise parameters estimated from the residuals (level, Tc, sigma per block)
    kind: str = "vector"          # 'vector' | 'norm'
    base_names: tuple = BASE_NAMES
    settings: dict = field(default_factory=dict)
    cache: dict = field(default_factory=dict)   # slow-noise structures per (sensor, Tc)
    # norm model only: the base solution the observations are linearised at, how the noise was estimated,
    # the reduced chi-square the sigmas were scaled by, (chi2, dof, p) before that scaling, the Allan result
    base_theta: np.ndarray | None = None
    noise_method: str = ""
    overdispersion: float | None = None
    raw_chi2: tuple | None = None
    norm_allan: object = None
    source_kind: str = ""
    last_fits: tuple | None = None              # (base, final) fits of the last analysis
    L_measured: dict | None = None              # Cholesky factors of the measured noise (adequacy tests)
    noise_basis: str = ""                       # what the measured noise rests on
    norm_generic: dict | None = None            # norm model: dr/dd per segment ("G") and segment times ("t")

    @property
    def n(self) -> int:
        return self.y.size

    def whiten(self, A, L=None):
        """L^-1 A block by block (A (n,) or (n, k)); ``L``: other Cholesky factors than the problem's."""
        A = np.asarray(A, float)
        L = self.L if L is None else L
        Lpad = self.padded(L)
        if Lpad is not None:       # one compiled call for every block
            starts, sizes = self.__dict__["_row_layout"]
            A2 = np.ascontiguousarray(A.reshape(A.shape[0], -1))
            out = np.empty_like(A2)
            kernels.whiten_blocks(Lpad, starts, sizes, A2, out)
            return out.reshape(A.shape)
        out = np.empty_like(A)
        for key, idx in self.geom.obs["blocks"].items():
            out[idx] = solve_lower(L[key], A[idx])
        return out

    def padded(self, L=None):
        """The Cholesky factors ``L`` (default: the problem's) of the observation blocks in one zero-padded array
        (blocks, m, m) for the compiled calls, kept until the noise model changes; None when the blocks are not
        runs of rows that together cover every observation."""
        if "_row_layout" not in self.__dict__:
            idxs = [np.asarray(i) for i in self.geom.obs["blocks"].values()]
            ok = (all(i.size and np.all(np.diff(i) == 1) for i in idxs)
                  and np.array_equal(np.sort(np.concatenate(idxs)), np.arange(self.n)))
            self.__dict__["_row_layout"] = ((np.array([i[0] for i in idxs], np.int64),
                                             np.array([i.size for i in idxs], np.int64)) if ok else None)
        if self.__dict__["_row_layout"] is None:
            return None
        L = self.L if L is None else L
        c = self.__dict__.setdefault("_wc", {})
        got = c.get(("Lpad", id(L)))
        if got is None or got[0] is not L:
            sizes = self.__dict__["_row_layout"][1]
            mmax = int(sizes.max())
            Lpad = np.zeros((len(sizes), mmax, mmax))
            for b, key in enumerate(self.geom.obs["blocks"]):
                m = int(sizes[b])
                Lpad[b, :m, :m] = L[key]
            got = c[("Lpad", id(L))] = (L, Lpad)
        return got[1]

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

    def base_qr(self, X=None):
        """The base design ``X`` (default: ``X0``, whose factors are kept until the noise model changes) whitened and
        factorised block by block (:class:`BaseQR`); None when the base does not split into blocks or a block is rank
        deficient (the fits then solve the whole design with :func:`lstsq`)."""
        layout = base_blocks(self)
        if layout is None:
            return None
        c = self.__dict__.setdefault("_wc", {})
        Lpad = self.padded()
        if X is None:
            if "base_qr" not in c:
                c["base_qr"] = BaseQR(self.X0, Lpad, layout, self.X0.shape[1])
            b = c["base_qr"]
        else:
            b = BaseQR(X, Lpad, layout, X.shape[1])
        return b if b.full_rank else None

    def forget_whitened(self):
        """Drop the cached whitened quantities (after the noise model or the library changed)."""
        self.__dict__.pop("_wc", None)

    def cand(self, key):
        """The candidate ``key`` of the library (an index by key, rebuilt when the library list is replaced)."""
        index = self.__dict__.get("_cand_index")
        if index is None or index[0] is not self.lib or index[1] != len(self.lib):
            by_key = {}
            for c in self.lib:
                by_key.setdefault(c.key, c)
            index = self.__dict__["_cand_index"] = (self.lib, len(self.lib), by_key)
        return index[2][key]


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
        return chi2_sf(self.chi2, max(self.dof, 1))

    def bic(self, n) -> float:
        return self.chi2 + self.k * math.log(n)


def base_estimates(theta):
    """Base K E (``M``) and bias ``b`` per sensor from the first 24 parameters of a vector-model fit."""
    M = {"accel": theta[0:9].reshape(3, 3), "gyro": theta[12:21].reshape(3, 3)}
    b = {"accel": theta[9:12].copy(), "gyro": theta[21:24].copy()}
    return M, b


def lstsq(Aw, yw, want_cov: bool = True):
    """Least squares on unit-norm columns by pivoted QR with a rank cut: (theta, cov, rank); ``want_cov`` False:
    cov is None (the same theta, for a chi-square alone)."""
    nrm = np.linalg.norm(Aw, axis=0)
    nrm[nrm == 0] = 1.0
    An = Aw / nrm
    Q, R, piv = pivoted_qr(An)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > 1e-9 * d[0])) if d.size else 0
    Rk = R[:rank, :rank]
    z = solve_tri(Rk, Q[:, :rank].T @ yw, lower=False)
    theta = np.zeros(Aw.shape[1])
    theta[piv[:rank]] = z
    if not want_cov:
        return theta / nrm, None, rank
    Ri = solve_tri(Rk, np.eye(rank), lower=False)
    cov = np.zeros((Aw.shape[1], Aw.shape[1]))
    cov[np.ix_(piv[:rank], piv[:rank])] = Ri @ Ri.T
    theta /= nrm
    cov /= np.outer(nrm, nrm)
    return theta, cov, rank


# ----------------------------------------------------------------------------------------------------------
# the base model eliminated block by block: every fit of the diagnosis is "base + a few columns"
# ----------------------------------------------------------------------------------------------------------

#: the rank cut of :func:`lstsq` on unit-norm columns (relative to the first pivot, whose norm is 1)
RANK_TOL = 1e-9
#: the smallest diagonal of an unpivoted factor (unit-norm columns) that the compiled fits accept; at or below it a
#: column is nearly dependent and the pivoted solve, with its rank cut, decides instead
UNPIVOTED_TOL = 1e3 * RANK_TOL


def base_blocks(prob: "Problem"):
    """The block structure of the base design as ``(starts, sizes, cols)`` (int arrays: first row and number of rows
    of every observation block -- sensor, axis --, and its base columns (blocks, c)) when every block is a run of
    rows with base columns of its own, as many for each (the vector model: 3 inputs and a bias per block; the norm
    model: one block), so that the base can be eliminated block by block; None otherwise. Geometry only (cached
    on the problem)."""
    got = prob.__dict__.get("_base_blocks", False)
    if got is not False:
        return got
    starts, sizes, cols, used = [], [], [], np.zeros(prob.X0.shape[1], bool)
    out = None
    for key, idx in prob.geom.obs["blocks"].items():
        idx = np.asarray(idx)
        cb = np.flatnonzero(np.any(prob.X0[idx] != 0, axis=0))
        if (not idx.size or np.any(np.diff(idx) != 1) or used[cb].any() or (cols and cb.size != cols[0].size)
                or key != list(prob.geom.obs["blocks"])[len(starts)]):
            break
        used[cb] = True
        starts.append(int(idx[0]))
        sizes.append(int(idx.size))
        cols.append(cb)
    else:
        if used.all() and sum(sizes) == prob.n and cols:
            out = (np.array(starts, np.int64), np.array(sizes, np.int64), np.array(cols, np.int64))
    prob.__dict__["_base_blocks"] = out
    return out


class BaseQR:
    """The whitened base design factorised block by block (``B_b = Q_b R_b diag(n_b)``, unit-norm columns), so that
    a fit of the base plus extra columns S solves only for S on what the base leaves (``P S``, ``P y``, P the
    projection off the base) and recovers the base parameters block by block: the same estimates, covariance and
    chi-square as :func:`lstsq` of the whole design (the normal equations of a partitioned least-squares problem),
    at the cost of the extra columns. The factors are computed by one compiled call
    (:func:`calib.diagnosis.kernels.whiten_factor_blocks`: the profile of the clock offset refactorises the patched
    base at every offset it tries). ``full_rank``: False when a block is rank deficient at :data:`RANK_TOL` (then the
    whole design goes through :func:`lstsq`)."""

    def __init__(self, X, Lpad, layout, k):
        starts, sizes, bcols = layout
        nb, c = bcols.shape
        self.k = int(k)
        self.starts, self.sizes, self.bcols = starts, sizes, bcols
        self.Q = np.zeros((nb, Lpad.shape[1], c))
        self.R = np.zeros((nb, c, c))
        self.nrm = np.ones((nb, c))
        dmin = kernels.whiten_factor_blocks(np.ascontiguousarray(X, dtype=float), Lpad, starts, sizes, bcols,
                                            self.Q, self.R, self.nrm)
        self.full_rank = bool(dmin > RANK_TOL)

    def project(self, A):
        """``A`` ((n,) or (n, p)) less its part in the span of the base (block by block)."""
        A = np.asarray(A, dtype=float)
        A2 = A.reshape(A.shape[0], -1)
        out = np.empty_like(A2)
        kernels.project_blocks(self.Q, self.starts, self.sizes, np.ascontiguousarray(A2), out)
        return out.reshape(A.shape)

    def unpivoted_chi2(self, Sw, yp):
        """``(chi2, ok)``: the chi-square of the whitened observations on ``[base, Sw]`` by one compiled call on what
        the base leaves of them (``yp``, :meth:`project`) and of ``Sw``, without pivoting; ok False when a column of
        ``Sw`` is nearly dependent (a diagonal of its factor at or below :data:`UNPIVOTED_TOL`), where the rank cut of a
        pivoted solve (:meth:`solve`, :func:`lstsq`) decides instead. ``Sw`` without columns: ``(|yp|^2, True)``."""
        if Sw is None or Sw.shape[1] == 0:
            return float(yp @ yp), True
        Sw = np.ascontiguousarray(Sw)        # (the norms' summation order follows the memory layout)
        nS = np.linalg.norm(Sw, axis=0)
        nS[nS == 0] = 1.0
        ss, dmin = kernels.residual_ss(self.project(Sw), nS, yp, UNPIVOTED_TOL)
        return float(ss), bool(dmin > UNPIVOTED_TOL)

    def chi2(self, yw, Sw=None, yp=None) -> float:
        """The chi-square of :meth:`solve` (``yw`` on ``[base, Sw]``) alone (:meth:`unpivoted_chi2`); through
        :meth:`solve` (pivoted, with its rank cut) when a column of ``Sw`` is nearly dependent."""
        yp = self.project(yw) if yp is None else yp
        ss, ok = self.unpivoted_chi2(Sw, yp)
        if ok:
            return ss
        rw = self.solve(yw, Sw, want_cov=False, yp=yp)[3]
        return float(rw @ rw)

    def solve(self, yw, Sw=None, want_cov: bool = True, yp=None):
        """Least squares of ``yw`` on ``[base, Sw]`` (whitened): ``(theta, cov, rank, residual)``, theta ordered as
        the base columns then those of ``Sw``; cov None when not wanted. ``yp``: ``project(yw)`` if known."""
        k0 = self.k
        p = 0 if Sw is None else Sw.shape[1]
        yp = self.project(yw) if yp is None else yp
        thS = np.zeros(p)
        rankS = 0
        covS = np.zeros((p, p))
        if p:
            Sp = self.project(Sw)
            nS = np.linalg.norm(Sw, axis=0)
            nS[nS == 0] = 1.0
            Q, R, piv = pivoted_qr(Sp / nS)
            d = np.abs(np.diag(R))
            rankS = int(np.sum(d > RANK_TOL))
            Rk = R[:rankS, :rankS]
            z = solve_tri(Rk, Q[:, :rankS].T @ yp, lower=False)
            thS[piv[:rankS]] = z
            thS /= nS
            if want_cov:
                Ri = solve_tri(Rk, np.eye(rankS), lower=False)
                covS[np.ix_(piv[:rankS], piv[:rankS])] = Ri @ Ri.T
                covS /= np.outer(nS, nS)
            resid = yp - Sp @ thS
            rest = yw - Sw @ thS
        else:
            resid = yp
            rest = yw
        theta = np.zeros(k0 + p)
        theta[k0:] = thS
        cov = np.zeros((k0 + p, k0 + p)) if want_cov else np.zeros((0, 0))
        G = np.zeros((k0, p))
        kernels.base_backsolve(self.Q, self.R, self.nrm, self.starts, self.sizes, self.bcols,
                               np.ascontiguousarray(rest, dtype=float),
                               np.ascontiguousarray(Sw, dtype=float) if p else np.zeros((rest.size, 0)),
                               bool(want_cov), theta, cov, G)
        if not want_cov:
            cov = None
        else:
            cov[k0:, k0:] = covS
        if want_cov and p:
            GC = G @ covS
            cov[:k0, :k0] += GC @ G.T
            cov[:k0, k0:] = -GC
            cov[k0:, :k0] = -GC.T
        return theta, cov, k0 + rankS, resid
