"""The diagnosis problem and a fit on it: settings, :class:`Problem`, :class:`Fit` and the least-squares core."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import special

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
        out = np.empty_like(A)
        for key, idx in self.geom.obs["blocks"].items():
            out[idx] = solve_lower(L[key], A[idx])
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


def chi2_sf(x, df) -> float:
    """Upper tail of the chi-square distribution, ``scipy.stats.chi2.sf(x, df)`` to the bit: the special function
    that method evaluates (``scipy.special.chdtrc``), without the distribution object's argument handling, which
    costs 40 times the evaluation (the diagnosis asks for thousands). Below the support (x < 0): 1."""
    return 1.0 if x < 0 else float(special.chdtrc(df, x))


def f_sf(x, dfn, dfd) -> float:
    """Upper tail of the F distribution, ``scipy.stats.f.sf(x, dfn, dfd)`` to the bit (``scipy.special.fdtrc``)."""
    return 1.0 if x < 0 else float(special.fdtrc(dfn, dfd, x))


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
