"""Objective functions of the norm-observed calibration (Liu 2021), vectorised over a population.

Every objective maps a population ``theta`` (P, p) to values (P,) (a single vector (p,) gives a scalar), and
offers the residual vector and its analytic Jacobian for least squares.

Model (Liu 2021 eqs. 1-4): N = K E x + b, with N the rate reading [output unit, count s-1 for the synthetic
unit], x the input in the body frame [input unit: g for accelerometers, deg/h for gyros], K diagonal,
E with unit diagonal. ``M = K E`` is a general 3x3 matrix with ``M_ii = K_i`` and ``M_ij = K_i E_ij``.

Parameterisations ("forms"):

* ``paper12`` — Liu 2021 eq. 8 / 19: [Kx Ky Kz Exy Exz Eyx Eyz Ezx Ezy bx by bz].
* ``tri9`` — the same with ``Exy = Exz = Eyz = 0`` (``M`` lower triangular): [Kx Ky Kz Eyx Ezx Ezy bx by bz].
  This is the parameterisation the *norm* identifies. The norm ``|M^-1 (N - b)|`` is unchanged when
  M -> M R for any rotation R (a rotation of the whole triad in the body frame: the input is rotated,
  its norm is not), so only ``M M^T`` and b are determined (6 + 3 = 9 numbers, rank 9 of 12 for paper12).
  Every ``M M^T`` has exactly one lower-triangular factor with positive diagonal (Cholesky), which fixes
  the gauge: the x sensitive axis is the frame's x axis and the y sensitive axis lies in its x-y plane.
* ``ke9`` — [Kx Ky Kz Exy Exz Eyx Eyz Ezx Ezy] without biases (L_gm of eq. 26 does not see the bias).
* ``bias3`` — [bx by bz] with ``K E`` held fixed (Liu 2021 §3.3: gyro drifts from eq. 7 after eq. 26).

Objectives:

* :class:`NormObjective` — L_a / L_g of Liu 2021 eq. 7 on static means; the fitness of eqs. 10 and 20 is
  ``1 / L``. Residual ``r_m = ref^2 - |M^-1 (N_m - b)|^2`` with ``ref`` = g (local normal gravity in the
  input unit: gamma / 9.80665 for the synthetic unit's accelerometers) or Omega (Earth rate, 15.041 deg/h).
  L is in input-unit^2 (g^2 or (deg/h)^2).
* :class:`LgmObjective` — L_gm of Liu 2021 eq. 26 on rotation pairs:
  ``r_j = |N+_j - N-_j|^2 - |K E (2 omega_0^b)_j|^2``. Because ``|M a|^2`` for rotation axes ``a`` along the
  body axes only involves the column norms of M, L_gm constrains 3 of the 9 K/E parameters (rank 3).
  ``relative=True`` (default) divides each term by the measured ``|N+_j - N-_j|^2`` so L_gm is
  dimensionless (the literal eq. 26 is in (count s-1)^2, about 1e17 for the synthetic gyros, which would pin
  the adaptive F of eq. 17 at F_max); ``relative=False`` gives the literal value.

The linear (vector) estimators, eq. 25 in component form and the classical separate calibration, are in
:mod:`calib.calibration.linear`.
"""
from __future__ import annotations

import numba
import numpy as np

from calib.core.triad import OFFDIAG, PARAM_NAMES

EPS_DET = 1e-300
FORM_CODE = {"paper12": 0, "tri9": 1, "ke9": 2, "bias3": 3}

FORM_NAMES = {
    "paper12": PARAM_NAMES,
    "tri9": ("Kx", "Ky", "Kz", "Eyx", "Ezx", "Ezy", "bx", "by", "bz"),
    "ke9": PARAM_NAMES[:9],
    "bias3": ("bx", "by", "bz"),
}


class Form:
    """Map between a parameter vector of one form and (K E, b); vectorised over a population."""

    def __init__(self, name: str, KE=None, b=None):
        if name not in FORM_NAMES:
            raise ValueError(f"unknown form {name!r}; one of {', '.join(FORM_NAMES)}")
        self.name = name
        self.names = FORM_NAMES[name]
        self.dim = len(self.names)
        self.KE_fixed = None if KE is None else np.asarray(KE, dtype=float)
        self.b_fixed = None if b is None else np.asarray(b, dtype=float)
        if name == "bias3" and self.KE_fixed is None:
            raise ValueError("form 'bias3' needs the fixed K E matrix (KE=...)")

    # entries of M (9 arrays (P,)) and b (3 arrays (P,) or scalars)
    def entries(self, th):
        n = self.name
        if n == "paper12" or n == "ke9":
            K0, K1, K2 = th[:, 0], th[:, 1], th[:, 2]
            m = (K0, K0 * th[:, 3], K0 * th[:, 4],
                 K1 * th[:, 5], K1, K1 * th[:, 6],
                 K2 * th[:, 7], K2 * th[:, 8], K2)
            if n == "paper12":
                b = (th[:, 9], th[:, 10], th[:, 11])
            else:
                b = (0.0, 0.0, 0.0) if self.b_fixed is None else tuple(self.b_fixed)
        elif n == "tri9":
            K0, K1, K2 = th[:, 0], th[:, 1], th[:, 2]
            z = np.zeros_like(K0)
            m = (K0, z, z, K1 * th[:, 3], K1, z, K2 * th[:, 4], K2 * th[:, 5], K2)
            b = (th[:, 6], th[:, 7], th[:, 8])
        else:  # bias3
            M = self.KE_fixed
            one = np.ones(th.shape[0])
            m = tuple(M[i, j] * one for i in range(3) for j in range(3))
            b = (th[:, 0], th[:, 1], th[:, 2])
        return m, b

    def KE_b(self, theta):
        """(K E (3, 3), b (3,)) of one parameter vector."""
        th = np.atleast_2d(np.asarray(theta, dtype=float))
        m, b = self.entries(th)
        M = np.array([np.broadcast_to(v, (th.shape[0],))[0] for v in m]).reshape(3, 3)
        bb = np.array([np.broadcast_to(v, (th.shape[0],))[0] for v in b])
        return M, bb

    def derivatives(self, theta):
        """dM/dtheta (9, p) (row-major flattening of M) and db/dtheta (3, p) at one parameter vector."""
        th = np.asarray(theta, dtype=float)
        p = self.dim
        dM = np.zeros((9, p))
        db = np.zeros((3, p))
        if self.name in ("paper12", "ke9"):
            K = th[:3]
            E = np.eye(3)
            for k, (i, j) in enumerate(OFFDIAG):
                E[i, j] = th[3 + k]
            for i in range(3):
                for j in range(3):
                    dM[3 * i + j, i] = E[i, j]
            for k, (i, j) in enumerate(OFFDIAG):
                dM[3 * i + j, 3 + k] = K[i]
            if self.name == "paper12":
                db[:, 9:12] = np.eye(3)
        elif self.name == "tri9":
            K = th[:3]
            E = np.eye(3)
            E[1, 0], E[2, 0], E[2, 1] = th[3], th[4], th[5]
            for i in range(3):
                for j in range(3):
                    dM[3 * i + j, i] = E[i, j]
            for k, (i, j) in enumerate(((1, 0), (2, 0), (2, 1))):
                dM[3 * i + j, 3 + k] = K[i]
            db[:, 6:9] = np.eye(3)
        else:
            db[:, :] = np.eye(3)
        return dM, db

    def to_paper(self, theta):
        """The paper's 12-vector (Liu 2021 eq. 8) of one parameter vector of this form."""
        M, b = self.KE_b(theta)
        return paper_vector(M, b)

    def from_KE_b(self, M, b=None):
        """Parameter vector of this form from K E and b (for tri9, M must be lower triangular)."""
        M = np.asarray(M, dtype=float)
        K = np.diag(M).copy()
        E = M / K[:, None]
        if self.name == "paper12":
            return np.concatenate([K, [E[i, j] for i, j in OFFDIAG], b])
        if self.name == "ke9":
            return np.concatenate([K, [E[i, j] for i, j in OFFDIAG]])
        if self.name == "tri9":
            if max(abs(M[0, 1]), abs(M[0, 2]), abs(M[1, 2])) > 1e-12 * np.abs(M).max():
                raise ValueError("tri9 needs a lower-triangular K E (use lower_triangular_gauge first)")
            return np.concatenate([K, [E[1, 0], E[2, 0], E[2, 1]], b])
        return np.asarray(b, dtype=float).copy()


def paper_vector(M, b):
    """[K, E offdiagonals, b] (Liu 2021 eq. 8) from K E = M and b."""
    M = np.asarray(M, dtype=float)
    K = np.diag(M).copy()
    E = M / K[:, None]
    return np.concatenate([K, [E[i, j] for i, j in OFFDIAG], np.asarray(b, dtype=float)])


def paper_jacobian(M):
    """d(K, E offdiag)/d(vec M) (9, 9) at M (row-major vec) for the delta-method covariance."""
    M = np.asarray(M, dtype=float)
    K = np.diag(M)
    G = np.zeros((9, 9))
    for i in range(3):
        G[i, 4 * i] = 1.0
    for k, (i, j) in enumerate(OFFDIAG):
        G[3 + k, 3 * i + j] = 1.0 / K[i]
        G[3 + k, 4 * i] = -M[i, j] / K[i] ** 2
    return G


def lower_triangular_gauge(M):
    """The lower-triangular factor L (positive diagonal) with L L^T = M M^T, and R with M = L R.

    L is what the norm identifies (tri9 gauge); R is the rotation of the triad the norm cannot see.
    """
    M = np.asarray(M, dtype=float)
    L = np.linalg.cholesky(M @ M.T)
    R = np.linalg.solve(L, M)
    return L, R


def align_to_reference(L, M_ref):
    """Rotation R minimising ||L R - M_ref||_F (orthogonal Procrustes, det R = +1) and L R.

    Used to map a norm-identified (tri9) K E back to the paper's form: the result is the paper form *up to
    the unidentified rotation*, chosen to be closest to ``M_ref`` (e.g. a prior separate calibration, or
    diag(K) for "no preferred rotation").
    """
    U, _, Vt = np.linalg.svd(np.asarray(L).T @ np.asarray(M_ref))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    return R, np.asarray(L) @ R


def _inv_entries(m):
    """Adjugate entries c_ij (inverse = c / det) and det of a population of 3x3 matrices given entrywise."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m
    c00 = m11 * m22 - m12 * m21
    c01 = m02 * m21 - m01 * m22
    c02 = m01 * m12 - m02 * m11
    c10 = m12 * m20 - m10 * m22
    c11 = m00 * m22 - m02 * m20
    c12 = m02 * m10 - m00 * m12
    c20 = m10 * m21 - m11 * m20
    c21 = m01 * m20 - m00 * m21
    c22 = m00 * m11 - m01 * m10
    det = m00 * c00 + m01 * c10 + m02 * c20
    return (c00, c01, c02, c10, c11, c12, c20, c21, c22), det


# ---------------------------------------------------------------------------------------------------------
# numba kernels (hot loops of the population evaluation); 3x3 algebra written out
# ---------------------------------------------------------------------------------------------------------
@numba.njit(cache=True, inline="always")
def _k_entries(t, code, fm, fb):
    if code == 0 or code == 2:
        k0, k1, k2 = t[0], t[1], t[2]
        m = (k0, k0 * t[3], k0 * t[4], k1 * t[5], k1, k1 * t[6], k2 * t[7], k2 * t[8], k2)
        if code == 0:
            b = (t[9], t[10], t[11])
        else:
            b = (fb[0], fb[1], fb[2])
    elif code == 1:
        k0, k1, k2 = t[0], t[1], t[2]
        m = (k0, 0.0, 0.0, k1 * t[3], k1, 0.0, k2 * t[4], k2 * t[5], k2)
        b = (t[6], t[7], t[8])
    else:
        m = (fm[0], fm[1], fm[2], fm[3], fm[4], fm[5], fm[6], fm[7], fm[8])
        b = (t[0], t[1], t[2])
    return m, b


@numba.njit(cache=True, inline="always")
def _adjugate(m):
    """Adjugate entries (row-major) of a 3x3 matrix given as a 9-tuple and 1/det (det floored at 1e-300):
    M^-1 = adj(M) / det, written out for the kernels."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m
    c00 = m11 * m22 - m12 * m21
    c01 = m02 * m21 - m01 * m22
    c02 = m01 * m12 - m02 * m11
    c10 = m12 * m20 - m10 * m22
    c11 = m00 * m22 - m02 * m20
    c12 = m02 * m10 - m00 * m12
    c20 = m10 * m21 - m11 * m20
    c21 = m01 * m20 - m00 * m21
    c22 = m00 * m11 - m01 * m10
    det = m00 * c00 + m01 * c10 + m02 * c20
    if abs(det) < 1e-300:
        det = 1e-300
    return c00, c01, c02, c10, c11, c12, c20, c21, c22, 1.0 / det


@numba.njit(cache=True)
def _k_norm_residuals(th, code, fm, fb, N, T2, w, use_w, out):
    """out[p, m] = (T2 - |M_p^-1 (N_m - b_p)|^2) * w[m] (Liu 2021 eq. 7 terms)."""
    P = th.shape[0]
    nm = N.shape[0]
    for p in range(P):
        m, b = _k_entries(th[p], code, fm, fb)
        c00, c01, c02, c10, c11, c12, c20, c21, c22, inv = _adjugate(m)
        for k in range(nm):
            v0 = N[k, 0] - b[0]
            v1 = N[k, 1] - b[1]
            v2 = N[k, 2] - b[2]
            x0 = (c00 * v0 + c01 * v1 + c02 * v2) * inv
            x1 = (c10 * v0 + c11 * v1 + c12 * v2) * inv
            x2 = (c20 * v0 + c21 * v1 + c22 * v2) * inv
            r = T2 - (x0 * x0 + x1 * x1 + x2 * x2)
            if use_w:
                r *= w[k]
            out[p, k] = r


@numba.njit(cache=True)
def _k_norm_L(th, code, fm, fb, N, T2, w, use_w, dof, out):
    """out[p] = sqrt(sum_m r_pm^2 / dof), r of :func:`_k_norm_residuals` (Liu 2021 eq. 7), inf if not finite."""
    P = th.shape[0]
    nm = N.shape[0]
    for p in range(P):
        m, b = _k_entries(th[p], code, fm, fb)
        c00, c01, c02, c10, c11, c12, c20, c21, c22, inv = _adjugate(m)
        acc = 0.0
        for k in range(nm):
            v0 = N[k, 0] - b[0]
            v1 = N[k, 1] - b[1]
            v2 = N[k, 2] - b[2]
            x0 = (c00 * v0 + c01 * v1 + c02 * v2) * inv
            x1 = (c10 * v0 + c11 * v1 + c12 * v2) * inv
            x2 = (c20 * v0 + c21 * v1 + c22 * v2) * inv
            r = T2 - (x0 * x0 + x1 * x1 + x2 * x2)
            if use_w:
                r *= w[k]
            acc += r * r
        v = np.sqrt(acc / dof)
        out[p] = v if np.isfinite(v) else np.inf


@numba.njit(cache=True)
def _k_rms(r, dof, out):
    P, n = r.shape
    for p in range(P):
        acc = 0.0
        for k in range(n):
            acc += r[p, k] * r[p, k]
        v = np.sqrt(acc / dof)
        out[p] = v if np.isfinite(v) else np.inf


@numba.njit(cache=True)
def _k_lgm_residuals(th, code, fm, fb, wv, d2, scale, out):
    """out[p, j] = (|d_j|^2 - |M_p w_j|^2) / scale_j (Liu 2021 eq. 26 terms)."""
    P = th.shape[0]
    J = wv.shape[0]
    for p in range(P):
        m, _ = _k_entries(th[p], code, fm, fb)
        m00, m01, m02, m10, m11, m12, m20, m21, m22 = m
        for j in range(J):
            w0, w1, w2 = wv[j, 0], wv[j, 1], wv[j, 2]
            y0 = m00 * w0 + m01 * w1 + m02 * w2
            y1 = m10 * w0 + m11 * w1 + m12 * w2
            y2 = m20 * w0 + m21 * w1 + m22 * w2
            out[p, j] = (d2[j] - (y0 * y0 + y1 * y1 + y2 * y2)) / scale[j]



class NormObjective:
    """L_a / L_g of Liu 2021 eq. 7 on M static means, vectorised; fitness f = 1 / L (eqs. 10, 20).

    Parameters
    ----------
    N : (M, 3) static means of the rate reading [output unit].
    reference : |input| at rest in the input unit (g in standard g = gamma / 9.80665, or Omega = 15.041 deg/h).
    form : 'paper12' | 'tri9' | 'bias3' (with ``KE``).
    sigma : (M, 3) std of each mean [output unit] (for residual sigmas / standard errors / weighting).
    weighted : minimise sum((r / sigma_r)^2) instead of eq. 7's unweighted sum (weights fixed by
        :meth:`set_weights`, default at the first call of :meth:`set_weights`).
    """

    kind = "norm"

    def __init__(self, N, reference, *, form="paper12", sigma=None, KE=None, b=None, weighted=False, name=None):
        self.N = np.asarray(N, dtype=float)
        if self.N.ndim != 2 or self.N.shape[1] != 3:
            raise ValueError(f"static means must be (M, 3), got {self.N.shape}")
        self.M = self.N.shape[0]
        self.reference = float(reference)
        self.T2 = self.reference ** 2
        self.form = form if isinstance(form, Form) else Form(form, KE=KE, b=b)
        self.names = self.form.names
        self.dim = self.form.dim
        self.sigma = None if sigma is None else np.broadcast_to(np.asarray(sigma, float), self.N.shape).copy()
        self.weighted = bool(weighted)
        self.w = None
        self.name = name or "L"
        self.l_unit = 1.0
        self._N0, self._N1, self._N2 = (self.N[:, 0].copy(), self.N[:, 1].copy(), self.N[:, 2].copy())
        self._code = FORM_CODE[self.form.name]
        self._fm = np.zeros(9) if self.form.KE_fixed is None else self.form.KE_fixed.ravel().copy()
        self._fb = np.zeros(3) if self.form.b_fixed is None else self.form.b_fixed.copy()
        self._ones = np.ones(self.M)
        if self.M < 2:
            raise ValueError("eq. 7 needs at least 2 static positions")

    # --- population evaluation ----------------------------------------------------------------------------
    def _x(self, th):
        m, b = self.form.entries(th)
        c, det = _inv_entries(m)
        det = np.where(np.abs(det) < EPS_DET, EPS_DET, det)
        v0 = self._N0[None, :] - np.reshape(b[0], (-1, 1))
        v1 = self._N1[None, :] - np.reshape(b[1], (-1, 1))
        v2 = self._N2[None, :] - np.reshape(b[2], (-1, 1))
        inv = (1.0 / det)[:, None]
        x0 = (c[0][:, None] * v0 + c[1][:, None] * v1 + c[2][:, None] * v2) * inv
        x1 = (c[3][:, None] * v0 + c[4][:, None] * v1 + c[5][:, None] * v2) * inv
        x2 = (c[6][:, None] * v0 + c[7][:, None] * v1 + c[8][:, None] * v2) * inv
        return x0, x1, x2

    def inputs(self, theta):
        """Estimated inputs x = (K E)^-1 (N - b) (P, M, 3) [input unit] (Liu 2021 eq. 6)."""
        th = np.atleast_2d(np.asarray(theta, dtype=float))
        return np.stack(self._x(th), axis=-1)

    def residuals_pop(self, th):
        """r = ref^2 - |x|^2 (P, M) (Liu 2021 eq. 7 terms), multiplied by 1/sigma_r if weighted."""
        th = np.ascontiguousarray(np.atleast_2d(th), dtype=np.float64)
        out = np.empty((th.shape[0], self.M))
        w = self._weights() if self.weighted else self._ones
        _k_norm_residuals(th, self._code, self._fm, self._fb, self.N, self.T2, w, self.weighted, out)
        return out

    def residuals_pop_numpy(self, th):
        """Reference (pure numpy) implementation of :meth:`residuals_pop`, used to test the kernel."""
        x0, x1, x2 = self._x(np.atleast_2d(np.asarray(th, dtype=float)))
        r = self.T2 - (x0 * x0 + x1 * x1 + x2 * x2)
        if self.weighted:
            r = r * self._weights()
        return r

    def __call__(self, theta):
        """L (Liu 2021 eq. 7): sqrt(sum_m r_m^2 / (M - 1)); (P,) for (P, p), scalar for (p,)."""
        th = np.asarray(theta, dtype=np.float64)
        single = th.ndim == 1
        if single or not th.flags.c_contiguous:
            th = np.ascontiguousarray(np.atleast_2d(th))
        L = np.empty(th.shape[0])
        w = self._weights() if self.weighted else self._ones
        _k_norm_L(th, self._code, self._fm, self._fb, self.N, self.T2, w, self.weighted, float(self.M - 1), L)
        return float(L[0]) if single else L

    def eq7(self, theta):
        """Literal (unweighted) eq. 7 value whatever ``weighted`` says."""
        w, self.weighted = self.weighted, False
        try:
            return self(theta)
        finally:
            self.weighted = w

    def fitness(self, theta):
        """f = 1 / L (Liu 2021 eqs. 10 and 20)."""
        return 1.0 / np.asarray(self(theta))

    # --- least squares ------------------------------------------------------------------------------------
    def _weights(self):
        if self.w is None:
            raise ValueError("weighted objective: call set_weights(theta) first")
        return self.w

    def set_weights(self, theta):
        """Fix the weights 1 / sigma_r at ``theta`` (sigma_r from :meth:`residual_sigma`)."""
        self.w = 1.0 / self.residual_sigma(theta)
        return self.w

    def residuals(self, theta):
        """Residual vector (M,) at one parameter vector (whitened if weighted)."""
        return self.residuals_pop(np.atleast_2d(np.asarray(theta, dtype=float)))[0]

    def input_directions(self, theta):
        M, b = self.form.KE_b(theta)
        x = np.linalg.solve(M, (self.N - b).T).T  # (M, 3)
        u = np.linalg.solve(M.T, x.T).T  # M^-T x
        return M, x, u

    def jacobian(self, theta):
        """d r / d theta (M, p), analytic: dr = 2 u^T (dM x + db), u = M^-T x (whitened if weighted)."""
        _, x, u = self.input_directions(theta)
        dM, db = self.form.derivatives(theta)
        GM = 2.0 * np.einsum("mi,mj->mij", u, x).reshape(self.M, 9)
        J = GM @ dM + 2.0 * u @ db
        if self.weighted:
            J = J * self._weights()[:, None]
        return J

    def residual_sigma(self, theta):
        """Std of each unweighted residual r_m from the std of N_m: sigma_r^2 = sum_i (2 u_i sigma_i)^2."""
        if self.sigma is None:
            raise ValueError("residual sigmas need the sigma of the static means")
        _, _, u = self.input_directions(theta)
        return np.sqrt(np.sum((2.0 * u * self.sigma) ** 2, axis=1))


class LgmObjective:
    """L_gm of Liu 2021 eq. 26 on J rotation pairs, vectorised; fitness f = 1 / L_gm.

    d : (J, 3) N+_j - N-_j [output unit]; w : (J, 3) (2 omega_0^b)_j = (r+ - r-) x axis [input unit];
    sigma_d : (J, 3) std of d. Form 'ke9' (default) or 'paper12' (the biases then have zero gradient).
    ``relative`` (default True) divides term j by |d_j|^2 (dimensionless L_gm), see module docstring.
    """

    kind = "lgm"

    def __init__(self, d, w, *, sigma_d=None, form="ke9", relative=True, name="L_gm"):
        self.d = np.asarray(d, dtype=float)
        self.wv = np.asarray(w, dtype=float)
        if self.d.shape != self.wv.shape or self.d.ndim != 2 or self.d.shape[1] != 3:
            raise ValueError(f"d and w must both be (J, 3), got {self.d.shape} and {self.wv.shape}")
        self.J = self.d.shape[0]
        if self.J < 2:
            raise ValueError("eq. 26 needs at least 2 rotation pairs")
        self.form = form if isinstance(form, Form) else Form(form)
        self.names = self.form.names
        self.dim = self.form.dim
        self.relative = bool(relative)
        self.d2 = np.einsum("ji,ji->j", self.d, self.d)
        self.scale = self.d2 if self.relative else np.ones(self.J)
        self.sigma = None if sigma_d is None else np.broadcast_to(np.asarray(sigma_d, float), self.d.shape).copy()
        self.weighted = False
        self.name = name
        self.l_unit = 1.0
        self.M = self.J
        self._code = FORM_CODE[self.form.name]
        self._fm = np.zeros(9)
        self._fb = np.zeros(3)
        self.wv = np.ascontiguousarray(self.wv)

    def residuals_pop(self, th):
        """r_j = (|d_j|^2 - |K E w_j|^2) / scale_j (P, J) (Liu 2021 eq. 26 terms)."""
        th = np.ascontiguousarray(np.atleast_2d(th), dtype=np.float64)
        out = np.empty((th.shape[0], self.J))
        _k_lgm_residuals(th, self._code, self._fm, self._fb, self.wv, self.d2, self.scale, out)
        return out

    def residuals_pop_numpy(self, th):
        """Reference (pure numpy) implementation of :meth:`residuals_pop`."""
        m, _ = self.form.entries(np.atleast_2d(np.asarray(th, dtype=float)))
        w = self.wv
        y0 = m[0][:, None] * w[None, :, 0] + m[1][:, None] * w[None, :, 1] + m[2][:, None] * w[None, :, 2]
        y1 = m[3][:, None] * w[None, :, 0] + m[4][:, None] * w[None, :, 1] + m[5][:, None] * w[None, :, 2]
        y2 = m[6][:, None] * w[None, :, 0] + m[7][:, None] * w[None, :, 1] + m[8][:, None] * w[None, :, 2]
        return (self.d2[None, :] - (y0 * y0 + y1 * y1 + y2 * y2)) / self.scale[None, :]

    def __call__(self, theta):
        """L_gm (Liu 2021 eq. 26): sqrt(sum_j r_j^2 / (J - 1))."""
        th = np.asarray(theta, dtype=float)
        single = th.ndim == 1
        r = self.residuals_pop(th)
        L = np.empty(r.shape[0])
        _k_rms(r, float(self.J - 1), L)
        return float(L[0]) if single else L

    eq7 = __call__

    def fitness(self, theta):
        return 1.0 / np.asarray(self(theta))

    def residuals(self, theta):
        return self.residuals_pop(np.atleast_2d(np.asarray(theta, dtype=float)))[0]

    def jacobian(self, theta):
        """d r_j / d theta (J, p): d|M w|^2 / dM_ik = 2 (M w)_i w_k."""
        M, _ = self.form.KE_b(theta)
        y = self.wv @ M.T
        dM, db = self.form.derivatives(theta)
        G = -2.0 * np.einsum("ji,jk->jik", y, self.wv).reshape(self.J, 9) / self.scale[:, None]
        return G @ dM

    def residual_sigma(self, theta):
        """Std of r_j from the std of d_j: dr/dd = 2 d / scale."""
        if self.sigma is None:
            raise ValueError("residual sigmas need sigma_d")
        return np.sqrt(np.sum((2.0 * self.d * self.sigma) ** 2, axis=1)) / self.scale
