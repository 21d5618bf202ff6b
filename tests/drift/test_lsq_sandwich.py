"""The least-squares limit of He 2019's channel-weighted cost (calib.drift.bound.cost_lsq_limit), computed from the
linear error model without running an estimator, against the simulator, the strapdown navigation and
calib.drift.psobe.linear_lsq over 200 noise seeds of a 2 h stationary window."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from scipy.optimize import linprog

from calib.core import earth, seeds
from calib.drift import bound, psobe
from calib.sim.static_session import simulate_static_session

LAT = math.radians(30.58)
WINDOW_H, N_SEEDS = 2.0, 200
WEIGHTS, UNIT = (1.0, 1.0, 1.0, 10.0), "arcmin"
DRIFT_DEG_H, ACCEL_BIAS = (-0.01, 0.01, 0.01), (0.001, 0.001, 0.001)
SESSION = {"mode": "physical", "duration_h": WINDOW_H, "site": {"latitude_deg": 30.58},
           "gyro_noise": {"model": "arw", "arw_deg_rth": 0.001}, "gyro_drift_deg_h": list(DRIFT_DEG_H),
           "accel_bias_m_s2": list(ACCEL_BIAS)}
THETA = np.r_[np.asarray(DRIFT_DEG_H) * earth.DEG_PER_H, ACCEL_BIAS[:2]]  # body axes along E, N, U


def _model_weights():
    kl, kn = psobe.position_scale(UNIT, LAT)
    return np.asarray(WEIGHTS) * [1.0, 1.0, kl, kn]


def _window(tmp_path, k):
    path = tmp_path / f"s{k}.nc"
    simulate_static_session(SESSION, seeds.child_seed(5151, "session", k), path)
    win = psobe.load_window(path, WINDOW_H, 2.0)
    path.unlink()
    return psobe.NavigationCost(win, 60.0, WEIGHTS, UNIT, threads_parallel=False)


@pytest.fixture(scope="module")
def quiet_cost(tmp_path_factory):
    """The window navigated from noise-free samples (the same drift and accelerometer biases)."""
    path = tmp_path_factory.mktemp("quiet") / "quiet.nc"
    simulate_static_session({**SESSION, "gyro_noise": {"model": "arw", "arw_deg_rth": 0.0}}, 1, path)
    return psobe.NavigationCost(psobe.load_window(path, WINDOW_H, 2.0), 60.0, WEIGHTS, UNIT)


def _j_minimum(cost, step=0.01):
    """The drift [deg/h] that minimises J on the navigated window, J's errors taken as linear in the drift (four
    navigations: none and a step on each axis; the navigation is linear in the drift to ~1e-3 over hours, and
    test_minimum_of_J_is_offset_by_the_accelerometer_bias checks the exact minimum): least absolute deviations
    as a linear programme (minimise sum(u + v) with H c + u - v = -y0)."""
    kl, kn = psobe.position_scale(UNIT, LAT)
    err = cost.errors(np.vstack([np.zeros(3), step * np.eye(3)]))
    Y = np.concatenate([err["vE"], err["vN"], kl * err["lat"], kn * err["lon"]], axis=-1)
    Y *= np.repeat(WEIGHTS, Y.shape[1] // 4)
    H = (Y[1:] - Y[0]).T / step
    n = H.shape[0]
    res = linprog(np.r_[np.zeros(3), np.ones(2 * n)], A_eq=np.hstack([H, np.eye(n), -np.eye(n)]), b_eq=-Y[0],
                  bounds=[(None, None)] * 3 + [(0, None)] * (2 * n), method="highs")
    assert res.status == 0, res.message
    return res.x[:3]


@pytest.fixture(scope="module")
def seed_estimates(tmp_path_factory):
    """Over the seeds: linear_lsq's drift estimates [deg/h] (7 navigations of the window per seed) and the
    minimum of J over the drift alone (:func:`_j_minimum`)."""
    work = tmp_path_factory.mktemp("lsq")
    lsq, jmin = [], []
    for k in range(N_SEEDS):
        cost = _window(work, k)
        lsq.append(psobe.linear_lsq(cost, True)[0])
        jmin.append(_j_minimum(cost))
    return np.array(lsq), np.array(jmin)


@pytest.fixture(scope="module")
def lsq_spread(seed_estimates):
    return seed_estimates[0]


def test_vertical_bias_column_is_the_navigations(quiet_cost):
    """The column of a vertical accelerometer bias in the navigation (a finite step of the body-z bias through the
    full strapdown navigation of noise-free samples) is the model's tilt coupling of the truth: within 0.1 %; it is
    below 1e-3 of a horizontal bias' column. (With noise the navigation's column also carries the noise's tilt,
    about a tenth of it; :func:`calib.drift.bound.vertical_bias_sensitivity` leaves that out.)"""
    cost = quiet_cost
    kl, kn = psobe.position_scale(UNIT, LAT)
    step = 1e-3
    err = cost.errors(np.zeros((3, 3)), np.array([[0, 0, 0], [0, 0, step], [step, 0, 0]], float))
    Y = np.stack([err["vE"], err["vN"], kl * err["lat"], kn * err["lon"]], axis=-1)  # (runs, N, 4)
    col = ((Y[1] - Y[0]) / step).reshape(-1)
    col_east = ((Y[2] - Y[0]) / step).reshape(-1)
    t = bound.observation_times(WINDOW_H, 60.0)
    model = (bound.vertical_bias_sensitivity(t, LAT, np.eye(3), THETA).reshape(-1, 4) * [1, 1, kl, kn]).reshape(-1)
    a = float(col @ model / (model @ model))
    assert abs(abs(a) - 1.0) < 1e-3, a
    assert np.linalg.norm(col - a * model) < 1e-3 * np.linalg.norm(col)
    assert np.linalg.norm(col) < 1e-3 * np.linalg.norm(col_east)


def test_linear_lsq_spreads_as_the_sandwich_of_its_columns(lsq_spread):
    """linear_lsq's spread over 200 seeds is the sandwich of the columns it fits (drift, and the accelerometer bias
    on all three axes): the variance ratio inside the two-sided 0.1 % chi-square band of 199 degrees of freedom
    (std ratio 0.84 .. 1.17). The sandwich of the bound's parameters alone (without the vertical bias) is
    rejected on the x and z drift, where it predicts a spread 1.6 and 2.1 times larger: the vertical bias, which
    the navigation carries only through the tilt, is what lets the fit spread less than J's weighting predicts."""
    q_g, q_a = bound.noise_psd(SESSION, 100.0)
    full = bound.cost_lsq_limit(WINDOW_H, 60.0, LAT, np.eye(3), THETA, _model_weights(), q_gyro=q_g, q_accel=q_a)
    horiz = bound.cost_lsq_limit(WINDOW_H, 60.0, LAT, np.eye(3), THETA, _model_weights(), q_gyro=q_g, q_accel=q_a,
                                 fit_vertical_bias=False)
    crb = bound.drift_bound(WINDOW_H, 60.0, LAT, np.eye(3), q_gyro=q_g, q_accel=q_a)
    assert full.parameters[-1] == "nabla_U" and horiz.parameters == bound.PARAMETERS
    assert np.all(horiz.sigma >= crb.sigma[:3])  # least squares of the bound's columns never beats the bound
    n = len(lsq_spread)
    lo, hi = (stats.chi2.ppf(q, n - 1) / (n - 1) for q in (0.0005, 0.9995))
    var_ratio = lsq_spread.var(0, ddof=1) / full.sigma_deg_h() ** 2
    assert np.all((var_ratio >= lo) & (var_ratio <= hi)), np.sqrt(var_ratio)
    var_ratio_h = lsq_spread.var(0, ddof=1) / horiz.sigma_deg_h() ** 2
    assert np.all(var_ratio_h[[0, 2]] < lo), np.sqrt(var_ratio_h)
    # the estimates are unbiased: the mean within 3.3 standard errors of the truth
    se = lsq_spread.std(0, ddof=1) / math.sqrt(n)
    assert np.all(np.abs(lsq_spread.mean(0) - DRIFT_DEG_H) < 3.3 * se)
    assert np.allclose(full.bias, 0.0, atol=1e-6 * crb.sigma[:3].min())


def test_drift_only_fit_is_shifted_by_the_accelerometer_bias(quiet_cost):
    """Fitting the drift alone (linear_lsq without accelerometer biases) on a noise-free navigated window, the
    horizontal accelerometer bias in the data moves the estimate from the truth by the model's offset of the
    noise-free fit: within 2 % of it (it is tens of Cramér–Rao bounds); without the bias the offset is zero."""
    est = psobe.linear_lsq(quiet_cost, False)[0]
    w = _model_weights()
    model = bound.cost_lsq_limit(WINDOW_H, 60.0, LAT, np.eye(3), THETA, w, q_gyro=1e-20, fit_accel_bias=False)
    assert est - DRIFT_DEG_H == pytest.approx(model.bias_deg_h(), rel=0.02)
    none = bound.cost_lsq_limit(WINDOW_H, 60.0, LAT, np.eye(3), np.r_[THETA[:3], 0.0, 0.0], w, q_gyro=1e-20,
                                fit_accel_bias=False)
    assert np.all(np.abs(none.bias) < 1e-9 * np.abs(model.bias))


def test_minimum_of_J_is_offset_by_the_accelerometer_bias(quiet_cost):
    """J itself (absolute errors, eq. 18), minimised over the drift by Nelder-Mead on the noise-free navigated
    window, lies where the model's linear programme puts it: within 2 % of the offset from the truth, which is
    several Cramér–Rao bounds on every axis."""
    x, _ = psobe.NavigationCost.minimum(quiet_cost, np.asarray(DRIFT_DEG_H))
    model = bound.cost_offset(WINDOW_H, 60.0, LAT, np.eye(3), THETA, _model_weights()) / earth.DEG_PER_H
    q_g, _ = bound.noise_psd(SESSION, 100.0)
    crb = bound.drift_bound(WINDOW_H, 60.0, LAT, np.eye(3), q_gyro=q_g).sigma_deg_h()
    assert np.all(np.abs(model) > 2.0 * crb)
    assert x - DRIFT_DEG_H == pytest.approx(model, rel=0.02)


def test_minimum_of_J_spreads_as_its_monte_carlo(seed_estimates):
    """The spread of J's own minimum over the drift alone (PSOBE's criterion, absolute errors) from the linear
    model (400 draws, each an exact linear programme) against J minimised on the 200 navigated seeds: the
    variance ratio inside the two-sided 0.1 % band of the F distribution of 199 and 399 degrees of freedom (the
    seeds' and the draws' sampling errors); the mean offset within 3.3 standard errors of both."""
    jmin = seed_estimates[1]
    q_g, q_a = bound.noise_psd(SESSION, 100.0)
    sigma, offset = bound.cost_minimum_spread(WINDOW_H, 60.0, LAT, np.eye(3), THETA, _model_weights(),
                                              seeds.stream(5151, "draws"), 400, q_gyro=q_g, q_accel=q_a)
    n = len(jmin)
    lo, hi = (stats.f.ppf(q, n - 1, 399) for q in (0.0005, 0.9995))
    var_ratio = jmin.var(0, ddof=1) / (sigma / earth.DEG_PER_H) ** 2
    assert np.all((var_ratio >= lo) & (var_ratio <= hi)), np.sqrt(var_ratio)
    se = np.hypot(jmin.std(0, ddof=1) / math.sqrt(n), sigma / earth.DEG_PER_H / math.sqrt(400))
    assert np.all(np.abs(jmin.mean(0) - DRIFT_DEG_H - offset / earth.DEG_PER_H) < 3.3 * se)


def test_minimum_of_J_in_white_noise_is_the_median_regression():
    """With white noise of equal size on every weighted observation, J's minimum (least absolute deviations)
    spreads sqrt(pi / 2) times the least-squares estimate (the asymptotic efficiency 2 / pi of the median in
    Gaussian noise; 240 observations): within 6 % (2000 draws: 1.6 % sampling error)."""
    w = _model_weights()
    t = bound.observation_times(1.0, 60.0)
    sigma, offset = bound.cost_minimum_spread(1.0, 60.0, LAT, np.eye(3), np.zeros(5), w, seeds.stream(5151, "lad"),
                                              2000, meas_sigma=1.0 / w)
    M = bound.sensitivity_matrix(t, LAT, np.eye(3))[:, :3] * np.tile(w, t.size)[:, None]
    ols = np.sqrt(np.diag(np.linalg.inv(M.T @ M)))
    assert sigma / ols == pytest.approx(np.full(3, math.sqrt(math.pi / 2)), rel=0.06)
    assert np.all(np.abs(offset) < 3.3 * sigma / math.sqrt(2000))
