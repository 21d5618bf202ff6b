"""The Cramér–Rao bound of a triad's calibration (:mod:`calib.calibration.bound`): closed forms of simple pose sets,
the rotation of the norm model left undetermined, and the spread of efficient estimators over noise draws."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calib.calibration import bound as cb
from calib.calibration import linear as lin
from calib.calibration import objectives as ob
from calib.calibration import optimizers as opt
from calib.core.triad import PARAM_NAMES

G = 1.0  # input magnitude [g]
SIGMA = 2.0  # std of every window mean [output unit]


def _six_axis_poses():
    return np.concatenate([np.eye(3), -np.eye(3)]) * G


def _white(n, sigma=SIGMA):
    return np.stack([np.eye(n) * sigma ** 2] * 3)


def _generic_poses(n=24, seed=3):
    u = np.random.default_rng(seed).standard_normal((n, 3))
    return G * u / np.linalg.norm(u, axis=1, keepdims=True)


def _obs(x, sigma=SIGMA):
    return cb.Observations(x, _white(len(x), sigma), np.ones(len(x), bool))


M_TRUE = np.array([[1000.0, 0.0, 0.0], [0.4, 1010.0, 0.0], [-0.3, 0.5, 990.0]])  # tri9 gauge (lower triangular)
M_ROT = M_TRUE @ np.array([[1.0, -2e-3, 1e-3], [2e-3, 1.0, -1.5e-3], [-1e-3, 1.5e-3, 1.0]])  # with Exy, Exz, Eyz
B_TRUE = np.array([5.0, -3.0, 2.0])


def test_vector_model_six_axis_poses_closed_form():
    """Known inputs +-g along each axis, independent means of std sigma: per output axis the design [x, 1] is
    orthogonal, so b_i = mean of the six (sigma / sqrt(6)) and M_ij = (y(+e_j) - y(-e_j)) / (2 g)
    (sigma / (g sqrt(2))); K_i = M_ii."""
    B = cb.bound("accel", M_ROT, B_TRUE, [_obs(_six_axis_poses())], "vector", "paper12")
    assert B.determined.all()
    s = B.as_dict()
    for ax in "xyz":
        assert s[f"b{ax}"] == pytest.approx(SIGMA / math.sqrt(6), rel=1e-9)
        assert s[f"K{ax}"] == pytest.approx(SIGMA / (G * math.sqrt(2)), rel=1e-9)


def test_norm_model_six_axis_poses_closed_form():
    """Only |x| known: at M = diag(k) the pose +e_j says nothing about the tangential components of its mean (the
    unknown direction takes them), only the radial one y_j = +-k_j g + b_j: K_j = sigma / (g sqrt(2)),
    b_j = sigma / sqrt(2) (half the vector model's information on b), and six poses along the axes cannot tell
    the off-diagonal of (K E)(K E)^T: the tri9 installation errors are not determined."""
    M = np.diag([1000.0, 1010.0, 990.0])
    B = cb.bound("accel", M, B_TRUE, [_obs(_six_axis_poses())], "norm", "tri9")
    s = B.as_dict()
    for ax in "xyz":
        assert s[f"K{ax}"] == pytest.approx(SIGMA / (G * math.sqrt(2)), rel=1e-9)
        assert s[f"b{ax}"] == pytest.approx(SIGMA / math.sqrt(2), rel=1e-9)
    assert s["Eyx"] is None and s["Ezx"] is None and s["Ezy"] is None
    assert "rotation of the whole triad" in B.describe("Eyx")


def test_norm_model_leaves_the_triad_rotation_undetermined():
    """The norm cannot see M -> M R: the information of the paper's 12 parameters has a 3-dimensional null space,
    K and E (moved by the rotation) get no bound, b does; the lower-triangular gauge is fully determined."""
    x = _generic_poses()
    P = cb.bound("accel", M_ROT, B_TRUE, [_obs(x)], "norm", "paper12")
    assert P.null.shape[1] == 3
    s = P.as_dict()
    assert all(s[n] is None for n in PARAM_NAMES[:9])
    assert all(s[n] is not None and np.isfinite(s[n]) for n in ("bx", "by", "bz"))
    assert np.all(np.isinf(P.sigma[:9]))
    T = cb.bound("accel", M_ROT, B_TRUE, [_obs(x)], "norm", "tri9")
    assert T.determined.all() and np.all(np.isfinite(T.sigma))
    # with known directions the same poses determine all 12, and better
    V = cb.bound("accel", M_ROT, B_TRUE, [_obs(x)], "vector", "paper12")
    assert V.determined.all() and np.all(V.sigma[9:] < P.sigma[9:])


def test_tri9_gauge_jacobian_against_differences():
    """d tri9 / d [vec(M), b] of the Cholesky gauge against central differences of the gauge map itself."""
    val, G_an = cb.gauge_jacobian(M_ROT, B_TRUE, "tri9")

    def tri9(theta):
        L, _ = ob.lower_triangular_gauge(theta[:9].reshape(3, 3))
        return ob.Form("tri9").from_KE_b(L, theta[9:])

    th = np.concatenate([M_ROT.ravel(), B_TRUE])
    assert np.allclose(val, tri9(th))
    h = 1e-2  # 1e-5 of the scale factors: truncation ~1e-10, round-off ~1e-12 relative
    G_fd = np.column_stack([(tri9(th + h * e) - tri9(th - h * e)) / (2 * h) for e in np.eye(12)])
    assert np.abs(G_an - G_fd).max() <= 1e-7 * np.abs(G_an).max()


def test_vector_least_squares_spread_matches_the_bound():
    """Weighted linear least squares is efficient for known inputs and Gaussian noise: its spread over 2000 noise
    draws is the bound (within the 3 % sampling error of a std over 2000 draws, 4 sigma)."""
    x = _generic_poses(12)
    B = cb.bound("accel", M_ROT, B_TRUE, [_obs(x)], "vector", "paper12")
    rng = np.random.default_rng(11)
    clean = x @ M_ROT.T + B_TRUE
    est = []
    for _ in range(2000):
        M, b, _, _ = lin.vector_solve(clean + SIGMA * rng.standard_normal(clean.shape), x)
        est.append(ob.paper_vector(M, b))
    ratio = np.std(est, axis=0, ddof=1) / B.sigma
    assert np.all(np.abs(ratio - 1.0) < 0.065), ratio


def test_norm_least_squares_spread_matches_the_bound():
    """Eq. 7 least squares in the tri9 gauge with equal noise on every axis and near-equal scale factors weights
    every residual alike, so it is (asymptotically) efficient: its spread over 400 draws matches the norm model's
    bound (Schur complement of the unknown pose directions) within 15 % (the std of a std over 400 draws: 3.5 %)."""
    x = _generic_poses(24)
    B = cb.bound("accel", M_TRUE, B_TRUE, [_obs(x)], "norm", "tri9")
    truth = ob.Form("tri9").from_KE_b(M_TRUE, B_TRUE)
    lo = truth - np.r_[np.full(3, 50.0), np.full(3, 0.01), np.full(3, 50.0)]
    hi = truth + np.r_[np.full(3, 50.0), np.full(3, 0.01), np.full(3, 50.0)]
    rng = np.random.default_rng(12)
    clean = x @ M_TRUE.T + B_TRUE
    est = []
    for _ in range(400):
        obj = ob.NormObjective(clean + SIGMA * rng.standard_normal(clean.shape), G, form="tri9")
        est.append(opt.lsq(obj, (lo, hi), x0=truth).x)
    ratio = np.std(est, axis=0, ddof=1) / B.sigma
    assert np.all(np.abs(ratio - 1.0) < 0.15), ratio


def test_correlated_windows_bound_exceeds_the_white_one():
    """A bias common to all windows (a slow bias, fully correlated) is indistinguishable from b: the bound of b
    grows by exactly its std in quadrature, while M (seen through differences of the windows) is unchanged."""
    x = _six_axis_poses()
    slow = 3.0
    cov = _white(6) + slow ** 2
    corr = cb.bound("accel", M_ROT, B_TRUE, [cb.Observations(x, cov, np.ones(6, bool))], "vector", "paper12")
    white = cb.bound("accel", M_ROT, B_TRUE, [_obs(x)], "vector", "paper12")
    assert np.allclose(corr.sigma[9:], np.hypot(white.sigma[9:], slow), rtol=1e-9)
    assert np.allclose(corr.sigma[:3], white.sigma[:3], rtol=1e-9)
