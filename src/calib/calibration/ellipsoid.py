"""Algebraic ellipsoid fit of static accelerometer means: the closed-form start of every norm calibration.

A static mean N of a triad with ``N = M f + b`` and ``|f| = g`` lies on the ellipsoid
``(N - b)^T (M M^T)^-1 (N - b) = g^2``. Fitting the quadric ``z^T Q z + l^T z = 1`` to the centred, scaled
means ``z = (N - c0) / s0`` by linear least squares gives the centre (the bias) and the shape ``Q`` up to the
norm; the triangular factors of the normalised ``Q`` are then the scale-and-misalignment matrix in whichever
triangular convention the caller uses (field calibration: upper ``T K``; diagnosis: lower ``M``).

Needs >= 9 means spread over orientations; returns None when the fitted quadric is not an ellipsoid.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class EllipsoidFit:
    """``Qn``: normalised quadric of the scaled means (``z^T Qn z`` = 1 on the surface, z about ``centre_z``);
    ``c0``, ``s0``: centring and scaling of the means; ``centre_z``: the centre in scaled coordinates."""
    Qn: np.ndarray
    c0: np.ndarray
    s0: float
    centre_z: np.ndarray

    @property
    def bias(self) -> np.ndarray:
        """Centre of the ellipsoid in the means' unit (the triad's bias)."""
        return self.c0 + self.s0 * self.centre_z


def fit_ellipsoid(means) -> EllipsoidFit | None:
    """Algebraic ellipsoid fit of ``means`` (M, 3); None if the fit is singular or not an ellipsoid."""
    m = np.asarray(means, dtype=float)
    c0 = m.mean(axis=0)
    s0 = float(np.max(np.abs(m - c0))) or 1.0
    z = (m - c0) / s0
    x, y, w = z[:, 0], z[:, 1], z[:, 2]
    A = np.column_stack([x * x, y * y, w * w, 2 * x * y, 2 * x * w, 2 * y * w, x, y, w])
    try:
        coef, *_ = np.linalg.lstsq(A, np.ones(len(z)), rcond=None)
        Q = np.array([[coef[0], coef[3], coef[4]], [coef[3], coef[1], coef[5]], [coef[4], coef[5], coef[2]]])
        c = -0.5 * np.linalg.solve(Q, coef[6:9])
    except np.linalg.LinAlgError:
        return None
    Qn = Q / (1.0 + c @ Q @ c)
    if not np.all(np.isfinite(Qn)) or np.any(np.linalg.eigvalsh(Qn) <= 0):
        return None
    return EllipsoidFit(Qn=Qn, c0=c0, s0=s0, centre_z=c)
