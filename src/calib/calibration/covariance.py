"""Standard errors of the triad fits (:mod:`calib.calibration.fit`): covariances from the residual Jacobian.

* :func:`sandwich` — unweighted eq. 7 with independent residuals: ``C = J^+ diag(sigma_r^2) J^+T``;
  :func:`sandwich_full` with correlated residuals of covariance ``C_r`` (:func:`norm_residual_cov`, from the
  covariance of the segment means). Both use the pseudo-inverse in bound-scaled coordinates, so a
  rank-deficient form (Liu 2021's 12-parameter norm form, rank 9) gets the minimum-norm gauge.
* :func:`weighted_cov` — weighted or linear fits: ``(J^T W J)^-1``.
* :func:`paper_cov` — delta method from [vec(K E), b] to the paper's [K, E, b] (Liu 2021 eq. 8).
* :func:`propagate_linear` — covariance of an estimator linear in independent observations.
"""
from __future__ import annotations

import numpy as np

from calib.calibration import objectives as ob


def sandwich(J, sigma_r, scale, rcond=1e-8):
    """C = J^+ diag(sigma_r^2) J^+T computed in scaled coordinates (min-norm gauge if rank-deficient)."""
    Js = J * scale[None, :]
    Jp = np.linalg.pinv(Js, rcond=rcond)
    Cs = (Jp * sigma_r[None, :] ** 2) @ Jp.T
    return Cs * scale[:, None] * scale[None, :]


def sandwich_full(J, C_r, scale, rcond=1e-8):
    """C = J^+ C_r J^+T for correlated residuals of covariance ``C_r`` (M, M), in scaled coordinates."""
    Js = J * scale[None, :]
    Jp = np.linalg.pinv(Js, rcond=rcond)
    Cs = Jp @ C_r @ Jp.T
    return Cs * scale[:, None] * scale[None, :]


def norm_residual_cov(obj, theta, cov_means):
    """Covariance (M, M) of the eq. 7 residuals r_m = ref^2 - |x_m|^2 from the covariance of the means.

    dr_m / dN_m = -2 u_m^T with u_m = (K E)^-T x_m, axes independent, so
    C_r[m, n] = sum_i 4 u_mi u_ni C_i[m, n], C_i = ``cov_means[i]`` (M, M) [output unit^2] of axis i."""
    _, _, u = obj.input_directions(theta)
    return 4.0 * np.einsum("mi,ni,imn->mn", u, u, np.asarray(cov_means, dtype=float))


def weighted_cov(Jw, scale, rcond=1e-8):
    """C = (Jw^T Jw)^+ of whitened residuals ``Jw`` (weighted least squares), in scaled coordinates."""
    Js = Jw * scale[None, :]
    Cs = np.linalg.pinv(Js.T @ Js, rcond=rcond**2, hermitian=True)
    return Cs * scale[:, None] * scale[None, :]


def paper_cov(M, cov_lin):
    """Covariance of [K, E offdiag, b] from that of [vec(M) row-major, b] (delta method)."""
    G = np.zeros((12, 12))
    G[:9, :9] = ob.paper_jacobian(M)
    G[9:, 9:] = np.eye(3)
    return G @ cov_lin @ G.T


def propagate_linear(est, y0, sigma):
    """Covariance of est(y) for independent y with std sigma; est linear in y (central differences, h = sigma)."""
    y0 = np.asarray(y0, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    cols = []
    for k in range(y0.size):
        h = sigma[k]
        e = np.zeros_like(y0)
        e[k] = h
        cols.append((est(y0 + e) - est(y0 - e)) / (2.0 * h) * sigma[k])
    A = np.array(cols).T  # d est / d (y / sigma)
    return A @ A.T
