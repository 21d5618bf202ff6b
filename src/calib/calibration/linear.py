"""Linear (vector) estimators of a triad's K E and b (Liu 2021): closed-form weighted least squares.

* :func:`eq25_solve` — the component form of eq. 25: ``(N+ - N-) / (2 omega) = K E a`` for the rotation axis
  ``a``, i.e. one column of ``K E`` per axis: linear, full rank with rotations about three axes.
* :func:`vector_solve` — the classical (separate) calibration's vector observations
  ``N_m = K E x_m + b`` with known inputs ``x_m`` (linear least squares per output axis).

The nonlinear norm objectives (eqs. 7 and 26) are in :mod:`calib.calibration.objectives`.
"""
from __future__ import annotations

import numpy as np


def eq25_solve(d, w, sigma_d=None):
    """K E from rotation-pair differences, Liu 2021 eq. 25 in component form (linear least squares).

    For a pair about body axis k at table rates +omega / -omega, ``(N+ - N-) / (2 omega)`` *is* column k
    of K E (three components, not just its norm); with pairs about three non-coplanar axes the nine
    entries are determined (rank 9). Several rates per axis are combined by weighted least squares per
    output row: d_{j,i} = w_j . M_i.

    Returns ``(M (3, 3), cov (9, 9))`` with cov over row-major vec(M) from sigma_d (None -> unit weights and
    no meaningful covariance).
    """
    d = np.asarray(d, dtype=float)
    W = np.asarray(w, dtype=float)
    if np.linalg.matrix_rank(W, tol=1e-9 * np.abs(W).max()) < 3:
        raise ValueError(f"eq. 25 component form: the {W.shape[0]} rotation pairs span fewer than three axes - "
                         "add + and - rotations about each body axis")
    sig = np.ones_like(d) if sigma_d is None else np.broadcast_to(np.asarray(sigma_d, float), d.shape)
    M = np.zeros((3, 3))
    cov = np.zeros((9, 9))
    for i in range(3):
        A = W / sig[:, i:i + 1]
        y = d[:, i] / sig[:, i]
        C = np.linalg.inv(A.T @ A)
        M[i] = C @ (A.T @ y)
        cov[3 * i:3 * i + 3, 3 * i:3 * i + 3] = C
    return M, cov


def vector_solve(N, x, sigma=None):
    """Classical calibration: N_m = K E x_m + b with known inputs x_m (Liu 2021 eqs. 1/3 as vector
    observations), weighted linear least squares per output axis i: N_{m,i} = [x_m, 1] . [M_i, b_i].

    Returns ``(M (3, 3), b (3,), cov (12, 12), chi2 (3,))`` with cov over [vec(M) row-major, b] and the
    chi-square of each axis' fit (dof = n - 4).
    """
    N = np.asarray(N, dtype=float)
    x = np.asarray(x, dtype=float)
    A0 = np.hstack([x, np.ones((x.shape[0], 1))])
    if np.linalg.matrix_rank(A0) < 4:
        raise ValueError(f"vector calibration: the {x.shape[0]} input directions do not span 3-D space plus an "
                         "offset (need at least 4 positions with non-coplanar inputs)")
    sig = np.ones_like(N) if sigma is None else np.broadcast_to(np.asarray(sigma, float), N.shape)
    M = np.zeros((3, 3))
    b = np.zeros(3)
    cov = np.zeros((12, 12))
    chi2 = np.zeros(3)
    for i in range(3):
        A = A0 / sig[:, i:i + 1]
        y = N[:, i] / sig[:, i]
        C = np.linalg.inv(A.T @ A)
        beta = C @ (A.T @ y)
        M[i], b[i] = beta[:3], beta[3]
        rr = y - A @ beta
        chi2[i] = rr @ rr
        idx = [3 * i, 3 * i + 1, 3 * i + 2, 9 + i]
        cov[np.ix_(idx, idx)] = C
    return M, b, cov, chi2
