"""Compiled kernels of the diagnosis's small least-squares problems (numba).

Every fit of the diagnosis is the base model (a block-diagonal design: per observation block -- sensor, axis -- its
own few columns) plus a few candidate columns, on a few hundred observations. At these sizes a LAPACK call costs
more in its set-up than in its arithmetic, so the steps that are repeated hundreds of times per diagnosis -- the
base whitened and factorised block by block at every clock offset the profile tries, what the base leaves of the
observations and of the candidate columns, the chi-square of the rest -- are written out here, one compiled call
each. Factorisations are modified Gram-Schmidt with one re-orthogonalisation ("twice is enough": orthogonal to
working precision for the column-normalised, well-conditioned designs these are); where a column is (nearly)
dependent -- a diagonal of R at or below ``tol`` -- the kernels say so and the caller solves the whole design with
pivoting instead (:func:`calib.diagnosis.problem.lstsq`).
"""
from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _mgs2(A, Q, R):  # pragma: no cover - compiled
    """Thin QR of ``A`` (m, c) into ``Q`` (m, c) and ``R`` (c, c) by modified Gram-Schmidt, each column
    re-orthogonalised once. Returns the smallest |R_jj|."""
    m, c = A.shape
    dmin = np.inf
    for j in range(c):
        for i in range(m):
            Q[i, j] = A[i, j]
        for k in range(j + 1):
            R[k, j] = 0.0
        for _ in range(2):
            for k in range(j):
                s = 0.0
                for i in range(m):
                    s += Q[i, k] * Q[i, j]
                R[k, j] += s
                for i in range(m):
                    Q[i, j] -= s * Q[i, k]
        s = 0.0
        for i in range(m):
            s += Q[i, j] * Q[i, j]
        d = math.sqrt(s)
        R[j, j] = d
        if d < dmin:
            dmin = d
        if d > 0.0:
            for i in range(m):
                Q[i, j] /= d
    return dmin


@numba.njit(cache=True, nogil=True)
def whiten_factor_blocks(X, Lpad, starts, sizes, bcols, Qpad, Rpad, nrm):  # pragma: no cover - compiled
    """Per block b: ``B = L_b^-1 X[rows_b, bcols_b]`` (forward substitution with the block's Cholesky factor
    ``Lpad[b, :m, :m]``), its columns scaled to unit norm (``nrm[b]``) and factorised, ``B / nrm = Q R`` into
    ``Qpad[b, :m]``, ``Rpad[b]``. Returns the smallest |R_jj| over the blocks."""
    nb, c = bcols.shape
    dmin = np.inf
    for b in range(nb):
        r0 = starts[b]
        m = sizes[b]
        B = np.empty((m, c))
        for j in range(c):
            col = bcols[b, j]
            for i in range(m):
                acc = X[r0 + i, col]
                for t in range(i):
                    acc -= Lpad[b, i, t] * B[t, j]
                B[i, j] = acc / Lpad[b, i, i]
            s = 0.0
            for i in range(m):
                s += B[i, j] * B[i, j]
            s = math.sqrt(s)
            if s == 0.0:
                s = 1.0
            nrm[b, j] = s
            for i in range(m):
                B[i, j] /= s
        d = _mgs2(B, Qpad[b, :m, :], Rpad[b])
        if d < dmin:
            dmin = d
    return dmin


@numba.njit(cache=True, nogil=True)
def project_blocks(Qpad, starts, sizes, A, out):  # pragma: no cover - compiled
    """``out = A - blockdiag(Q_b Q_b') A``: what the base leaves of the columns of ``A`` (n, p) (twice, for the
    same working-precision orthogonality as the factors)."""
    nb = starts.shape[0]
    c = Qpad.shape[2]
    n, p = A.shape
    for i in range(n):
        for j in range(p):
            out[i, j] = A[i, j]
    for b in range(nb):
        r0 = starts[b]
        m = sizes[b]
        for j in range(p):
            for _ in range(2):
                for k in range(c):
                    s = 0.0
                    for i in range(m):
                        s += Qpad[b, i, k] * out[r0 + i, j]
                    for i in range(m):
                        out[r0 + i, j] -= s * Qpad[b, i, k]


@numba.njit(cache=True, nogil=True)
def residual_ss(Sp, nS, yp, tol):  # pragma: no cover - compiled
    """The residual sum of squares of ``yp`` on the columns of ``Sp`` (both already off the base), the columns
    scaled by ``nS`` (their norms before the base was taken off, as :func:`calib.diagnosis.problem.lstsq` scales
    the whole design); ``(ss, dmin)``, dmin the smallest |R_jj| of the scaled columns (a column at or below ``tol``
    is not determined: the caller then solves with pivoting)."""
    n, p = Sp.shape
    A = np.empty((n, p))
    for j in range(p):
        for i in range(n):
            A[i, j] = Sp[i, j] / nS[j]
    Q = np.empty((n, p))
    R = np.empty((p, p))
    dmin = _mgs2(A, Q, R) if p > 0 else np.inf
    r = yp.copy()
    if dmin > tol:
        for _ in range(2):
            for k in range(p):
                s = 0.0
                for i in range(n):
                    s += Q[i, k] * r[i]
                for i in range(n):
                    r[i] -= s * Q[i, k]
    ss = 0.0
    for i in range(n):
        ss += r[i] * r[i]
    return ss, dmin


@numba.njit(cache=True, nogil=True)
def base_backsolve(Q, R, nrm, starts, sizes, bcols, rest, Sw, want_cov, theta, cov, G):  # pragma: no cover
    """The base parameters of a fit given the extra columns' estimates, block by block: ``theta[cols_b] =
    diag(1/n_b) R_b^-1 Q_b' rest_b`` (``rest`` = the whitened observations less the extra columns' part); with
    ``want_cov`` also the base blocks of the covariance without the extra columns, ``cov[cols_b, cols_b] =
    diag(1/n_b) R_b^-1 R_b^-T diag(1/n_b)``, and ``G[cols_b] = diag(1/n_b) R_b^-1 Q_b' Sw_b`` (how the base estimates
    move with the extra columns' ones)."""
    nb, c = bcols.shape
    p = Sw.shape[1]
    z = np.empty(c)
    x = np.empty(c)
    Ri = np.zeros((c, c))
    QtS = np.empty((c, p))
    for b in range(nb):
        r0 = starts[b]
        m = sizes[b]
        for j in range(c):
            s = 0.0
            for i in range(m):
                s += Q[b, i, j] * rest[r0 + i]
            z[j] = s
        for j in range(c - 1, -1, -1):
            acc = z[j]
            for k in range(j + 1, c):
                acc -= R[b, j, k] * x[k]
            x[j] = acc / R[b, j, j]
        for j in range(c):
            theta[bcols[b, j]] = x[j] / nrm[b, j]
        if not want_cov:
            continue
        for j in range(c):                       # R^-1, upper triangular, column by column
            for i in range(c):
                Ri[i, j] = 0.0
            Ri[j, j] = 1.0 / R[b, j, j]
            for i in range(j - 1, -1, -1):
                acc = 0.0
                for k in range(i + 1, j + 1):
                    acc += R[b, i, k] * Ri[k, j]
                Ri[i, j] = -acc / R[b, i, i]
        for i in range(c):
            for j in range(c):
                Ri[i, j] /= nrm[b, i]
        for i in range(c):
            for j in range(c):
                s = 0.0
                for k in range(c):
                    s += Ri[i, k] * Ri[j, k]
                cov[bcols[b, i], bcols[b, j]] = s
        if p:
            for j in range(c):
                for t in range(p):
                    s = 0.0
                    for i in range(m):
                        s += Q[b, i, j] * Sw[r0 + i, t]
                    QtS[j, t] = s
            for i in range(c):
                for t in range(p):
                    s = 0.0
                    for k in range(c):
                        s += Ri[i, k] * QtS[k, t]
                    G[bcols[b, i], t] = s


@numba.njit(cache=True, nogil=True)
def whiten_blocks(Lpad, starts, sizes, A, out):  # pragma: no cover - compiled
    """``out = blockdiag(L_b)^-1 A`` (forward substitution per block of rows, ``Lpad[b, :m, :m]`` lower
    triangular): the whitening of every column of ``A`` (n, p) in one call."""
    n, p = A.shape
    for b in range(starts.shape[0]):
        r0 = starts[b]
        m = sizes[b]
        for i in range(m):                  # row by row: the inner loops run along contiguous rows
            for j in range(p):
                out[r0 + i, j] = A[r0 + i, j]
            for k in range(i):
                lik = Lpad[b, i, k]
                if lik != 0.0:
                    for j in range(p):
                        out[r0 + i, j] -= lik * out[r0 + k, j]
            d = Lpad[b, i, i]
            for j in range(p):
                out[r0 + i, j] /= d


@numba.njit(cache=True, nogil=True)
def patched_chi2(X, Lpad, starts, sizes, bcols, yw, Sw, nS, tol):  # pragma: no cover - compiled
    """The chi-square of ``yw`` on ``[base X, Sw]`` for a base design ``X`` whose blocks change (the clock-offset
    profile patches the inputs of the rotation windows at every offset it tries): the base whitened and factorised
    block by block (:func:`whiten_factor_blocks`), ``yw`` and ``Sw`` taken off it (:func:`project_blocks`), the
    residual sum of squares on what is left of ``Sw`` (:func:`residual_ss`). Returns ``(chi2, ok)``; ok False when a
    base block or an extra column is nearly dependent (at ``tol``): the caller then solves with pivoting."""
    nb, c = bcols.shape
    mmax = Lpad.shape[1]
    Q = np.zeros((nb, mmax, c))
    R = np.zeros((nb, c, c))
    nrm = np.ones((nb, c))
    dmin = whiten_factor_blocks(X, Lpad, starts, sizes, bcols, Q, R, nrm)
    if not dmin > tol:
        return 0.0, False
    n = yw.shape[0]
    yp = np.empty((n, 1))
    y2 = np.empty((n, 1))
    for i in range(n):
        y2[i, 0] = yw[i]
    project_blocks(Q, starts, sizes, y2, yp)
    p = Sw.shape[1]
    if p == 0:
        ss = 0.0
        for i in range(n):
            ss += yp[i, 0] * yp[i, 0]
        return ss, True
    Sp = np.empty((n, p))
    project_blocks(Q, starts, sizes, Sw, Sp)
    ss, d2 = residual_ss(Sp, nS, yp[:, 0].copy(), tol)
    return ss, d2 > tol
