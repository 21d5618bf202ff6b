"""The numerical core of the diagnosis against closed forms: the block-by-block elimination of the base equals the
least squares of the whole design, the noise profile likelihood equals the dense Gaussian likelihood at every grid
point, and a rounding-level change of the data changes a report only at rounding level."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calib.diagnosis import diagnose_dataset
from calib.diagnosis.noise import profile_noise
from calib.diagnosis.problem import BaseQR, lstsq
from calib.diagnosis.vector import reml_design
from calib.studies.diagnosis_proof import FastSession

SHORT = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}


def _blocks(rng, sizes=(11, 9, 13), c=3):
    """A block-diagonal base (each block its own c columns), per-block Cholesky factors of random SPD covariances."""
    n, k = sum(sizes), c * len(sizes)
    X = np.zeros((n, k))
    starts = np.cumsum((0,) + sizes[:-1])
    Ls = []
    for b, (r0, m) in enumerate(zip(starts, sizes)):
        X[r0:r0 + m, c * b:c * b + c] = rng.normal(size=(m, c)) * rng.uniform(0.1, 1e4, size=c)
        A = rng.normal(size=(m, m))
        Ls.append(np.linalg.cholesky(A @ A.T + m * np.eye(m)))
    mmax = max(sizes)
    Lpad = np.zeros((len(sizes), mmax, mmax))
    for b, L in enumerate(Ls):
        Lpad[b, :L.shape[0], :L.shape[0]] = L
    layout = (np.array(starts, np.int64), np.array(sizes, np.int64),
              np.array([np.arange(c * b, c * b + c) for b in range(len(sizes))], np.int64))
    W = np.zeros((n, n))
    for r0, m, L in zip(starts, sizes, Ls):
        W[r0:r0 + m, r0:r0 + m] = np.linalg.inv(L)
    return X, Lpad, layout, W


def test_base_elimination_is_the_least_squares_of_the_whole_design():
    """Estimates, covariance, rank and chi-square of base + extra columns, eliminated block by block, equal the
    pivoted least squares of the whole whitened design (the partitioned normal equations are the same equations)."""
    rng = np.random.default_rng(11)
    for trial in range(5):
        X, Lpad, layout, W = _blocks(rng)
        n, k = X.shape
        S = rng.normal(size=(n, 1 + trial % 3)) * 50.0
        y = X @ rng.normal(size=k) + S @ rng.normal(size=S.shape[1]) + rng.normal(size=n)
        base = BaseQR(X, Lpad, layout, k)
        assert base.full_rank
        th, cov, rank, rw = base.solve(W @ y, W @ S)
        th0, cov0, rank0 = lstsq(W @ np.hstack([X, S]), W @ y)
        assert rank == rank0 == k + S.shape[1]
        np.testing.assert_allclose(th, th0, rtol=1e-9, atol=1e-12 * np.abs(th0).max())
        np.testing.assert_allclose(cov, cov0, rtol=1e-8, atol=1e-12 * np.abs(cov0).max())
        r0 = W @ y - W @ np.hstack([X, S]) @ th0
        assert math.isclose(float(rw @ rw), float(r0 @ r0), rel_tol=1e-9)
        assert math.isclose(base.chi2(W @ y, W @ S), float(r0 @ r0), rel_tol=1e-9)
        # the base alone
        thb, _, rankb, rwb = base.solve(W @ y)
        thb0, _, _ = lstsq(W @ X, W @ y)
        np.testing.assert_allclose(thb, thb0, rtol=1e-9, atol=1e-12 * np.abs(thb0).max())


def test_dependent_extra_column_is_cut_like_the_whole_design():
    """An extra column that the base (with another extra column) already spans is not determined: the same rank
    and chi-square as the pivoted least squares of the whole design (the compiled chi-square defers to it)."""
    rng = np.random.default_rng(5)
    X, Lpad, layout, W = _blocks(rng)
    n, k = X.shape
    s1 = rng.normal(size=n)
    S = np.column_stack([s1, 2.0 * s1 - 3.0 * X[:, 0]])
    y = X @ rng.normal(size=k) + rng.normal(size=n)
    base = BaseQR(X, Lpad, layout, k)
    _, _, rank, rw = base.solve(W @ y, W @ S)
    _, _, rank0 = lstsq(W @ np.hstack([X, S]), W @ y)
    assert rank == rank0 == k + 1
    assert math.isclose(base.chi2(W @ y, W @ S), float(rw @ rw), rel_tol=1e-9)


@pytest.fixture(scope="module")
def problem():
    fs = FastSession({**SHORT, "effects": {"accel_lever_arm": {}}, "conceal": True}, None, physical=True)
    ds = fs.dataset(8)
    rep, prob = diagnose_dataset(ds, None, {"figures": False}, path="p")
    return ds, rep, prob


def test_noise_profile_is_the_dense_likelihood(problem):
    """Every grid point of the profile likelihood (REML and ML) equals the Gaussian likelihood computed densely,
    C = lam (C_fast + rho A_slow(Tc)) per axis block with lam at its closed-form optimum, up to a constant shared by
    the grid."""
    _, _, prob = problem
    X = reml_design(prob)
    si, s = 0, "accel"
    for method in ("reml", "ml"):
        grid = {}
        profile_noise(prob.geom, prob.noise, prob.y, X, prob.parts, prob.cache, blocks=[(si, a) for a in range(3)],
                      method=method, update=False, grid_out=grid)
        pts = grid[s]
        picks = [pts[i] for i in (0, 7, 40, 71, 72 + 30, 3 * 72 + 55)]
        dense = []
        for _, tc, rho, _ in picks:
            rr, ld, nfree = 0.0, 0.0, 0
            for a in range(3):
                idx = prob.geom.obs["blocks"][(si, a)]
                Xb = X[idx][:, np.any(X[idx] != 0, axis=0)]
                U, sv, _ = np.linalg.svd(Xb, full_matrices=False)     # the column space (the REML design has
                Xb = U[:, sv > 1e-9 * sv[0]]                           # dependent columns)
                AN, AQ, _ = prob.parts[s]
                C = prob.noise.N_shape[s][a] ** 2 * AN + prob.noise.Q_shape[s][a] ** 2 * AQ
                if rho > 0:
                    from calib.diagnosis.noise import slow_structure
                    C = C + rho * slow_structure(prob.parts, prob.geom, s, tc, prob.cache)
                # the generalised least-squares residual of the block (y less its ordinary fit first: the
                # quadratic form is invariant to it, and y itself is ~1e6 times its residual)
                y = prob.y[idx] - Xb @ np.linalg.lstsq(Xb, prob.y[idx], rcond=None)[0]
                Lc = np.linalg.cholesky(C)
                Xw, yw = np.linalg.solve(Lc, Xb), np.linalg.solve(Lc, y)
                r = yw - Xw @ np.linalg.lstsq(Xw, yw, rcond=None)[0]
                rr += float(r @ r)
                ld += np.linalg.slogdet(C)[1] + (np.linalg.slogdet(Xw.T @ Xw)[1] if method == "reml" else 0.0)
                nfree += len(idx) - (Xb.shape[1] if method == "reml" else 0)
            dense.append(nfree * math.log(rr / nfree) + ld)
        got = np.array([p[0] for p in picks])
        dense = np.array(dense)
        np.testing.assert_allclose(got - got[0], dense - dense[0], atol=1e-6 * max(1.0, np.abs(dense - dense[0]).max()))


def test_rounding_level_change_of_the_data_changes_the_report_at_rounding_level(problem):
    """A 1e-15 relative change of the recording's observations moves the selection's statistics, the noise level
    and the estimates by less than 1e-6 relative (before the profile likelihood lost its cancellation, the same
    change moved a candidate's delta-chi2 by 3 % and its p-value by 4 %)."""
    from calib.diagnosis import vector

    ds, rep0, _ = problem
    orig = vector.reduce_data

    def nudged(geom, d):
        y, r = orig(geom, d)
        return y * (1.0 + 1e-15), r

    vector.reduce_data = nudged
    try:
        rep1, _ = diagnose_dataset(ds, None, {"figures": False}, path="p")
    finally:
        vector.reduce_data = orig
    assert rep0["verdict"] == rep1["verdict"]
    t0 = rep0["selection"]["last_step_candidates"]
    t1 = rep1["selection"]["last_step_candidates"]
    assert [r["term"] for r in t0] == [r["term"] for r in t1]
    for a, b in zip(t0, t1):
        assert math.isclose(a["delta_chi2"], b["delta_chi2"], rel_tol=1e-6, abs_tol=1e-6)
        assert math.isclose(a["p_lrt"], b["p_lrt"], rel_tol=1e-6, abs_tol=1e-12)
    for a, b in zip(rep0["noise"]["per_sensor_axis"], rep1["noise"]["per_sensor_axis"]):
        assert math.isclose(a["level_scale_from_residuals"], b["level_scale_from_residuals"], rel_tol=1e-6)
    for fa, fb in zip(rep0["found"], rep1["found"]):
        for pa, pb in zip(fa["parameters"], fb["parameters"]):
            assert math.isclose(pa["value"], pb["value"], rel_tol=1e-6, abs_tol=1e-6 * pa["se"])
            assert math.isclose(pa["se"], pb["se"], rel_tol=1e-6)


def test_clock_offset_profile_is_the_least_squares_of_the_patched_design(problem):
    """At every offset the clock profile tries, its chi-square (the patched base factorised block by block in one
    compiled call) equals the pivoted least squares of the whole whitened design patched at that offset."""
    from calib.diagnosis import fitting

    _, _, prob = problem
    terms = ["accel_lever_arm/accel", "time_offset"]
    f = fitting._offset_profile(prob, terms, {})
    S = fitting.columns(prob, "accel_lever_arm/accel", {})
    yw = prob.whiten(prob.y)
    for d in (-0.2, -0.013, 0.0, 0.004, 0.17):
        X = prob.cand("time_offset").offset.patch_design(prob.X0, d)
        Aw = prob.whiten(np.hstack([X, S]))
        th, _, _ = lstsq(Aw, yw, want_cov=False)
        r = yw - Aw @ th
        assert math.isclose(f(d), float(r @ r), rel_tol=1e-8)


@pytest.mark.parametrize("path", ["normal equations", "stacked QR"])
def test_standard_errors_over_the_slow_noise_grid_are_the_dense_gls(problem, path, monkeypatch):
    """At every grid point of the slow noise that the marginal standard errors weigh (Tc, rho, level of one
    sensor; the other sensor at the problem's noise), the estimates and variances of the fast grid solver (normal
    equations of the eigen-whitened sensor rows where well conditioned, QR of the stacked design elsewhere: both
    paths, the second forced) equal the generalised least squares computed densely: every axis block whitened by
    the Cholesky factor of its own covariance lam (C_fast + rho A_slow(Tc)) built from the parts, the whole design
    solved by pivoted least squares."""
    from calib.diagnosis import analysis

    if path == "stacked QR":
        monkeypatch.setattr(analysis, "NE_COND_MAX", 0.0)
    from calib.diagnosis.fitting import fit
    from calib.diagnosis.geometry import SENSORS
    from calib.diagnosis.noise import covariance_blocks, slow_structure

    _, _, prob = problem
    for terms, key in ((["accel_lever_arm/accel"], "accel_lever_arm/accel"),
                       (["accel_lever_arm/accel", "temperature_sensitivity/gyro"], "temperature_sensitivity/gyro")):
        f = fit(prob, terms)
        s = prob.cand(key).sensor
        si = SENSORS.index(s)
        grid = {}
        profile_noise(prob.geom, prob.noise, prob.y, f.X, prob.parts, prob.cache, blocks=[(si, a) for a in range(3)],
                      method="reml", update=False, grid_out=grid)
        pts = [(tc, rho, lam) for _, tc, rho, lam in grid[s]]
        picks = [pts[i] for i in np.linspace(0, len(pts) - 1, 9).astype(int)]
        th, var = analysis._gls_over_slow_grid(prob, f.X, s, picks, f.slices[key])
        _, Lp = covariance_blocks(prob.geom, prob.noise, prob.parts, prob.cache)
        AN, AQ, _ = prob.parts[s]
        for (tc, rho, lam), t_fast, v_fast in zip(picks, th, var):
            Xw, yw = [], []
            for (sj, a), idx in prob.geom.obs["blocks"].items():
                if sj == si:
                    C = lam * (prob.noise.N_shape[s][a] ** 2 * AN + prob.noise.Q_shape[s][a] ** 2 * AQ
                               + rho * slow_structure(prob.parts, prob.geom, s, tc, prob.cache))
                    L = np.linalg.cholesky(C)
                else:
                    L = Lp[(sj, a)]
                Xw.append(np.linalg.solve(L, f.X[idx]))
                yw.append(np.linalg.solve(L, prob.y[idx]))
            theta, cov, _ = lstsq(np.vstack(Xw), np.concatenate(yw))
            sl = f.slices[key]
            np.testing.assert_allclose(t_fast, theta[sl], rtol=1e-7, atol=1e-9 * np.sqrt(np.diag(cov)[sl]).max())
            np.testing.assert_allclose(v_fast, np.diag(cov)[sl], rtol=1e-7)
