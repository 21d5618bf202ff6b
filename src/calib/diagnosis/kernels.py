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
