"""Closed-form (synthetic) segment means of a triad model, for tests, Monte Carlo and plan checks.

They have the types of the means extracted from a recording (:mod:`calib.signal.segments`): static means at
nominal attitudes (Liu 2021 eqs. 1-4) and whole-revolution means of + / - rotation pairs (eqs. 23-24).
"""
from __future__ import annotations

import math

import numpy as np

from calib.core import earth
from calib.signal.segments import RotationPairs, StaticMeans, reference_magnitude, to_input_unit


def vertical_axis_attitude(axis_b):
    """A C_b^n that points the body-frame unit vector ``axis_b`` up (the turntable axis), minimal rotation."""
    a = np.asarray(axis_b, dtype=float)
    a = a / np.linalg.norm(a)
    up = np.array([0.0, 0.0, 1.0])
    v = np.cross(a, up)
    s, c = np.linalg.norm(v), float(a @ up)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = v / s
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * Kx + (1.0 - c) * (Kx @ Kx)


def synthetic_static(model, attitudes, sigma, rng, *, sensor: str, latitude_deg: float = 39.98,
                     duration_s: float = 60.0) -> StaticMeans:
    """Static means N_m = K E x_m + b + noise at nominal attitudes C_b^n (closed form, Liu 2021 eqs. 1-4).

    x_m = C_n^b (0, 0, g) (accel, g = WGS-84 normal gravity in the model's input unit) or C_n^b omega_ie^n
    (gyro). ``sigma`` (scalar, (3,) or (M, 3)) in the output unit; noise N(0, sigma^2) from ``rng``
    (``rng=None``: noise-free).
    """
    att = np.asarray(attitudes, dtype=float)
    ref = reference_magnitude(sensor, model.input_unit, latitude_deg)
    st = StaticMeans(sensor=sensor, means=np.zeros((len(att), 3)), sigma=np.zeros((len(att), 3)),
                     duration_s=np.full(len(att), duration_s), reference=ref, input_unit=model.input_unit,
                     output_unit=model.output_unit, latitude_deg=latitude_deg, attitude=att,
                     labels=[f"pos {k + 1}" for k in range(len(att))], source="synthetic")
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), st.means.shape).copy()
    N = model.forward(st.true_inputs())
    if rng is not None:
        N = N + rng.normal(size=N.shape) * sig
    st.means, st.sigma = N, sig
    return st


def synthetic_pairs(model, axes, rates_deg_s, sigma, rng, *, latitude_deg: float = 39.98,
                    duration_s: float = 36.0) -> RotationPairs:
    """Whole-revolution means of + and - rotations about body ``axes`` (J, 3) at ``rates_deg_s`` (J,) with the
    rotation axis vertical (turntable): mean input = table rate x axis + Earth rate along the axis
    (Omega sin(lat)), Liu 2021 eqs. 23-24. Noise N(0, sigma^2) from ``rng`` (None: noise-free)."""
    axes = np.asarray(axes, dtype=float)
    axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    rates = np.asarray(rates_deg_s, dtype=float)
    att = np.array([vertical_axis_attitude(a) for a in axes])
    J = len(axes)
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), (J, 3)).copy()
    pr = RotationPairs(plus=np.zeros((J, 3)), minus=np.zeros((J, 3)), sigma_plus=sig, sigma_minus=sig.copy(),
                       axis=axes, rate_plus=rates, rate_minus=-rates, input_unit=model.input_unit,
                       output_unit=model.output_unit, latitude_deg=latitude_deg, attitude=att,
                       attitude_minus=att.copy(), labels=[f"pair {j + 1}" for j in range(J)])
    w_ie_n = to_input_unit(earth.earth_rate_enu(math.radians(latitude_deg)), model.input_unit)
    along = np.einsum("mij,mj->mi", att, axes) @ w_ie_n
    tab = to_input_unit(rates[:, None] * math.radians(1.0) * axes, model.input_unit)
    pr.plus = model.forward(tab + along[:, None] * axes)
    pr.minus = model.forward(-tab + along[:, None] * axes)
    if rng is not None:
        pr.plus = pr.plus + rng.normal(size=(J, 3)) * sig
        pr.minus = pr.minus + rng.normal(size=(J, 3)) * sig
    return pr
