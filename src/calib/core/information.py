"""Inverting a Fisher information matrix that may not determine every parameter.

The Cramér–Rao bounds of the calibration (:mod:`calib.calibration.bound`) and of the diagnosis's terms
(:mod:`calib.sim.fisher`) both scale the information to unit diagonal, split it by its eigenvalues into the
combinations the data see and those they do not (an eigenvalue below ``tol`` of the largest), and invert it on the
seen ones. A parameter a null combination moves is not determined: its bound is not a number.
"""
from __future__ import annotations

import numpy as np


def seen_inverse(F, tol: float, var_floor: float = 0.0, rel_floor: float = 0.0):
    """``(null, inv, s)`` of a symmetric information matrix ``F`` (p, p).

    ``s`` (p,): the scale, the square root of the diagonal clipped below at ``var_floor`` and raised to at least
    ``rel_floor`` times its largest element (a parameter the data do not touch keeps a finite scale); ``null``
    (p, k): an orthonormal basis, in unit-diagonal coordinates ``theta * s``, of the combinations whose
    eigenvalue of ``F / (s s^T)`` is below ``tol`` times the largest; ``inv`` (p, p): the inverse of ``F / (s s^T)``
    on the other combinations, in those coordinates (``inv / (s s^T)`` is the pseudo-inverse of ``F``).
    """
    s = np.sqrt(np.clip(np.diag(F), var_floor, None))
    if rel_floor:
        s = np.maximum(s, rel_floor * s.max())
    lam, V = np.linalg.eigh(F / np.outer(s, s))
    good = lam >= tol * lam.max()
    return V[:, ~good], (V[:, good] / lam[good]) @ V[:, good].T, s
