"""The Cramér–Rao bound of the gyro drift (calib.drift.bound) against closed forms, against a Monte-Carlo of an
efficient estimator on data the bound's code does not make, and against the project's drift estimators."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
from scipy import stats

from calib.core import earth, seeds
from calib.core.earth import DEG_PER_H
from calib.core.rotations import euler_to_dcm, rot_x, rot_y, rot_z
from calib.drift import bound
from calib.drift import psobe
from calib.nav import errormodel
from calib.sim.static_session import simulate_static_session

LAT = math.radians(30.58)
ARW = 0.001 * math.pi / 180.0 / 60.0  # 0.001 deg/sqrt(h) in rad/sqrt(s)


def _crb(J, K):
    F, _ = bound.fisher_information(J, K)
    return bound.bound_from_fisher(F)[1]


# ---------------------------------------------------------------------------------------------- closed forms
def test_constant_in_white_noise_is_sigma_over_sqrt_n():
    """A constant observed directly N times in white noise of sigma: CRB = sigma / sqrt(N)."""
    n, sig = 250, 0.37
    assert _crb(np.ones((n, 1)), sig * np.eye(n))[0] == pytest.approx(sig / math.sqrt(n), rel=1e-12)


def test_angle_drift_in_white_angle_noise_is_the_regression_bound():
    """An angle drifting at rate theta observed at t_k in white angle noise: CRB = sigma / sqrt(sum t_k^2)."""
    t = np.arange(1, 181) * 60.0
    sig = 2e-6
    assert _crb(t[:, None], sig * np.eye(t.size))[0] == pytest.approx(sig / math.sqrt(np.sum(t**2)), rel=1e-12)


def test_angle_drift_in_angle_random_walk_is_arw_over_sqrt_T():
    """The same drift with the angle carrying a random walk of PSD q (a correlated Sigma, Sigma_kl = q min(t_k,
    t_l)): the increments are independent, so the bound is sqrt(q / T) whatever the sampling."""
    t = np.arange(1, 181) * 60.0
    K = np.tril(np.ones((t.size, t.size))) * ARW * math.sqrt(60.0)  # cumulative sums of independent increments
    assert _crb(t[:, None], K)[0] == pytest.approx(ARW / math.sqrt(t[-1]), rel=1e-10)


def test_north_drift_reaches_the_arw_limit_through_the_ins_model():
    """Through the whole INS error model with the true initial attitude, the north gyro's drift is seen through
    phi_N in the east velocity: its bound is the angle-random-walk limit ARW / sqrt(T) (Schuler and Earth-rate
    couplings cost less than 0.2 % over 3 h)."""
    b = bound.drift_bound(3.0, 60.0, LAT, np.eye(3), q_gyro=ARW**2)
    assert b.sigma[1] == pytest.approx(ARW / math.sqrt(3 * 3600.0), rel=2e-3)
    assert b.identifiable.all() and b.null.shape[1] == 0
    assert b.cond_sigma > 1e6  # the conditioning that rules out an explicit inverse is reported


def test_bound_scales_with_the_noise_amplitude():
    """The bound is proportional to the noise amplitude (Sigma scales with q, J does not)."""
    a = bound.drift_bound(1.0, 60.0, LAT, np.eye(3), q_gyro=ARW**2).sigma
    b = bound.drift_bound(1.0, 60.0, LAT, np.eye(3), q_gyro=(3 * ARW) ** 2).sigma
    assert b == pytest.approx(3 * a, rel=1e-4)  # Sigma's condition ~1e11 leaves ~1e-5 of rounding


def test_levelling_hides_the_drift_behind_the_accelerometer_bias():
    """After levelling, a horizontal accelerometer bias b with the drift (C_b^n eps) = (W sin L b_E, W sin L b_N,
    -W cos L b_N) / g leaves every navigation error at zero (the tilt cancels the bias and the drift holds the
    tilt): no drift component is determined. After gyrocompassing the east drift and east bias alone are hidden
    too. Known accelerometer biases make the drift determined again."""
    g = float(earth.normal_gravity(LAT, 0.0))
    wN, wU = earth.OMEGA_IE * math.cos(LAT), earth.OMEGA_IE * math.sin(LAT)
    expected = np.array([[wU / g, 0, 0, 1, 0], [0, wU / g, -wN / g, 0, 1]]).T
    lev = bound.drift_bound(1.0, 60.0, LAT, np.eye(3), q_gyro=ARW**2, condition="leveled")
    assert lev.null.shape[1] == 2 and not lev.identifiable.any() and np.all(np.isinf(lev.sigma))
    # the computed null space is the span of the analytic one
    P = lev.null @ np.linalg.pinv(lev.null)
    assert np.allclose(P @ expected, expected, rtol=1e-6, atol=1e-12 * np.abs(expected).max())
    sa = bound.drift_bound(1.0, 60.0, LAT, np.eye(3), q_gyro=ARW**2, condition="self_aligned")
    assert sa.null.shape[1] == 3 and np.all(np.isinf(sa.sigma))
    known = bound.drift_bound(1.0, 60.0, LAT, np.eye(3), q_gyro=ARW**2, condition="leveled", accel_bias_known=True)
    assert known.identifiable.all() and np.all(np.isfinite(known.sigma))


def test_noise_psd_of_the_simulator_session():
    q_g, q_a = bound.noise_psd({"gyro_noise": {"model": "arw", "arw_deg_rth": 0.001}, "accel_vrw_ug_rthz": 50.0},
                               100.0)
    assert q_g == pytest.approx(ARW**2, rel=1e-12)
    assert q_a == pytest.approx((50e-6 * earth.STANDARD_GRAVITY) ** 2, rel=1e-12)
    q_w, _ = bound.noise_psd({"gyro_noise": {"model": "white", "white_deg_h": 0.001}}, 100.0)
    assert q_w == pytest.approx((0.001 * DEG_PER_H) ** 2 * 0.01, rel=1e-12)


# ------------------------------------------------------------ Monte-Carlo of an efficient estimator (GLS)
def _simulate_linear_model(theta, C, q_g, q_a, n_draws, window_s, dt_out, rng, h=1.0):
    """Observed errors [vE, vN, L, lambda] at k dt_out of the linear error model driven by white noise, by
    stepping the augmented state in steps of h with the noise of each step added at its middle (not the bound's
    path: no Van Loan integral, no stacked covariance)."""
    nx = errormodel.NX
    A = np.zeros((nx + 5, nx + 5))
    A[:nx, :nx] = errormodel.f_matrix(LAT, 0.0)
    A[0:3, nx:nx + 3] = -C
    A[3, nx + 3] = A[4, nx + 4] = 1.0
    half = scipy.linalg.expm(A * h / 2)
    z = np.zeros((n_draws, nx + 5))
    z[:, nx:] = theta
    every = int(round(dt_out / h))
    out = []
    for j in range(1, int(round(window_s / h)) + 1):
        z = z @ half.T
        z[:, 0:3] -= rng.standard_normal((n_draws, 3)) @ C.T * math.sqrt(q_g * h)  # phi' = ... - C w_g
        if q_a:
            z[:, 3:5] += rng.standard_normal((n_draws, 2)) * math.sqrt(q_a * h)
        z = z @ half.T
        if j % every == 0:
            out.append(z[:, 3:7].copy())
    return np.stack(out, axis=1).reshape(n_draws, -1)  # time-major, as bound.sensitivity_matrix


def test_gls_monte_carlo_spread_equals_the_bound():
    """Generalised least squares is efficient on the linear-Gaussian model: over 300 simulated 3 h records (gyro
    ARW and accelerometer VRW, a tilted unit) its spread equals sigma_CRB within 15 % on every parameter, and its
    mean is the truth."""
    rng = np.random.default_rng(20260)
    C = rot_z(0.7) @ rot_x(0.2) @ rot_y(-0.3)
    theta = np.array([-0.01, 0.01, 0.01, 0.0, 0.0]) * DEG_PER_H
    theta[3:] = [1e-3, -2e-3]
    q_g, q_a = ARW**2, (20e-6 * earth.STANDARD_GRAVITY) ** 2
    window_h, dt_out, n = 3.0, 60.0, 300
    Y = _simulate_linear_model(theta, C, q_g, q_a, n, window_h * 3600.0, dt_out, rng)
    t = bound.observation_times(window_h, dt_out)
    J = bound.sensitivity_matrix(t, LAT, C)
    K = bound.noise_factor(t, LAT, 0.0, q_g, q_a)
    # GLS: whiten with the Cholesky factor of Sigma, then ordinary least squares
    s = np.linalg.norm(K, axis=1)
    R = np.linalg.qr((K / s[:, None]).T, mode="r")
    Jw = scipy.linalg.solve_triangular(R, J / s[:, None], trans="T")
    Yw = scipy.linalg.solve_triangular(R, (Y / s).T, trans="T")
    est = np.linalg.lstsq(Jw, Yw, rcond=None)[0].T  # (n, 5)
    b = bound.drift_bound(window_h, dt_out, LAT, C, q_gyro=q_g, q_accel=q_a)
    ratio = est.std(0, ddof=1) / b.sigma
    assert np.all(np.abs(ratio - 1) < 0.15), ratio
    assert np.all(np.abs(est.mean(0) - theta) < 4 * b.sigma / math.sqrt(n))


def test_kalman_filter_covariance_approaches_the_independent_bound():
    """The Kalman filter of calib.drift.psobe with diffuse priors and a small measurement-noise floor is a
    different computation of the same limit on the drift (true initial attitude): within 1 %."""
    b = bound.drift_bound(3.0, 60.0, LAT, np.eye(3), q_gyro=ARW**2)
    kf, _ = psobe.filter_covariance(3.0, 60.0, LAT, np.eye(3), ARW, "true_attitude")
    assert kf == pytest.approx(b.sigma[:3], rel=0.01)


# ---------------------------------------------------- the project's drift problem: no estimator beats the bound
@pytest.fixture(scope="module")
def drift_problem(tmp_path_factory):
    """30 noise seeds of the project's stationary session (simulator, strapdown navigation, estimators), 0.5 h."""
    work = tmp_path_factory.mktemp("bound")
    window_h, n_seeds = 0.5, 30
    cfg = {"mode": "physical", "duration_h": window_h, "site": {"latitude_deg": 30.58},
           "gyro_noise": {"model": "arw", "arw_deg_rth": 0.001}, "gyro_drift_deg_h": [-0.01, 0.01, 0.01],
           "accel_bias_m_s2": [0.001, 0.001, 0.001]}
    est = {k: np.empty((n_seeds, 3)) for k in ("kalman", "lls_with_accel_bias", "lls_drift_only")}
    for k in range(n_seeds):
        path = work / f"s{k}.nc"
        simulate_static_session(cfg, seeds.child_seed(4242, "session", k), path)
        cost = psobe.NavigationCost(psobe.load_window(path, window_h, 2.0), 60.0, [1, 1, 1, 10], "arcmin")
        path.unlink()
        est["kalman"][k] = psobe.kalman_baseline(cost, ARW, "true_attitude")[0]
        est["lls_with_accel_bias"][k] = psobe.linear_lsq(cost, True)[0]
        est["lls_drift_only"][k] = psobe.linear_lsq(cost, False)[0]
    q_g, _ = bound.noise_psd(cfg, 100.0)
    full = bound.drift_bound(window_h, 60.0, LAT, np.eye(3), q_gyro=q_g).sigma_deg_h()
    known = bound.drift_bound(window_h, 60.0, LAT, np.eye(3), q_gyro=q_g, accel_bias_known=True).sigma_deg_h()
    return est, full, known, n_seeds


def test_no_estimator_spreads_less_than_the_bound(drift_problem):
    """Every linear estimator's spread over the seeds is at least its bound, within the sampling error of a
    variance (chi-square, 0.1 % one-sided): those that carry the accelerometer bias against the bound with it as
    nuisance, the drift-only least squares against the bound with it known (the model it fits; a linear estimator's
    spread does not depend on the truth, so the bias the unmodelled accelerometer bias causes does not enter).
    PSOBE is not among them: the bound holds for unbiased estimators, and where the data are weak (eps_z in a
    short window) PSOBE's answer is set by its search range and velocity clamp, which the study's table shows
    as a spread below the bound."""
    est, full, known, n = drift_problem
    lo = stats.chi2.ppf(0.001, n - 1) / (n - 1)
    for name, ref in (("kalman", full), ("lls_with_accel_bias", full), ("lls_drift_only", known)):
        var_ratio = est[name].var(0, ddof=1) / ref**2
        assert np.all(var_ratio >= lo), (name, np.sqrt(var_ratio))


def test_kalman_filter_is_efficient_on_the_drift_problem(drift_problem):
    """The Kalman filter's spread is the bound: the variance ratio lies in the two-sided 0.1 % chi-square band."""
    est, full, _, n = drift_problem
    var_ratio = est["kalman"].var(0, ddof=1) / full**2
    lo, hi = (stats.chi2.ppf(q, n - 1) / (n - 1) for q in (0.0005, 0.9995))
    assert np.all((var_ratio >= lo) & (var_ratio <= hi)), np.sqrt(var_ratio)


@pytest.mark.parametrize("condition", ["true_attitude", "leveled"])
def test_bounds_over_the_same_data_equal_each_bound_alone(condition):
    """drift_bounds shares the observation noise's decomposition between the nuisance and the known-bias bound;
    each is the bound drift_bound computes alone, to the bit (accelerometer noise on, a tilted unit)."""
    C = euler_to_dcm(0.1, -0.2, 0.7)
    q_a = (20e-6 * 9.80665) ** 2
    pair = bound.drift_bounds(1.0, 60.0, LAT, C, 10.0, ARW**2, q_a, condition)
    for known, b in zip((False, True), pair):
        alone = bound.drift_bound(1.0, 60.0, LAT, C, 10.0, ARW**2, q_a, condition, accel_bias_known=known)
        for f in ("sigma", "covariance", "fisher", "identifiable", "null"):
            assert getattr(b, f).tobytes() == getattr(alone, f).tobytes(), f
        assert (b.names, b.cond_sigma, b.cond_fisher, b.n_observations) == \
            (alone.names, alone.cond_sigma, alone.cond_fisher, alone.n_observations)
    assert len(pair[0].names) == 5 and len(pair[1].names) == 3
