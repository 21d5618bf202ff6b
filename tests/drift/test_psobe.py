"""Gyro-drift estimation (He 2019): PSO, J, Ac, the noise limit and the baselines, against known truth."""
import math

import numpy as np
import pytest

from calib.calibration.optimizers import particle_swarm
from calib.drift import psobe as drift
from calib.drift import pso
from calib.sim.static_session import simulate_static_session
from calib.core.earth import DEG_PER_H

LAT = math.radians(30.58)
TRUTH = np.array([-0.01, 0.01, 0.01])


def test_accuracy_eq19():
    """Ac = (1 - |(eta_e - eta_i)/eta_i|) x 100 % (He 2019 eq. 19): the paper's Table 1 means give its Ac."""
    ac = pso.accuracy([-0.01038, 0.01073, 0.01046], TRUTH)
    assert ac == pytest.approx([96.2, 92.7, 95.4], abs=0.001)


@pytest.mark.parametrize("variant", ["paper", "standard"])
def test_pso_finds_minimum_of_a_bowl(variant):
    """Both variants reach the known minimum of a quadratic bowl inside the search range; velocities obey the
    clamp (a particle never moves more than v_max per generation)."""
    x0 = np.array([0.012, -0.007, 0.021])
    s = pso.PSOSettings(variant=variant, c1=1.0 if variant == "paper" else 2.0, c2=1.0 if variant == "paper" else 2.0,
                        generations=200, v_max=0.002)
    r = pso.minimize(lambda X: np.sum((X - x0) ** 2, axis=1), np.random.default_rng(1), s)
    assert np.abs(r.best - x0).max() < 2e-4
    assert np.abs(np.diff(r.positions, axis=0)).max() <= s.v_max + 1e-15
    assert np.all(np.diff(r.history) <= 0)  # the global best never gets worse
    assert r.pinned == []


def test_pso_flags_a_bound():
    s = pso.PSOSettings(generations=60)
    r = pso.minimize(lambda X: np.sum((X - 0.05) ** 2, axis=1), np.random.default_rng(2), s)  # optimum outside
    assert r.pinned == [0, 1, 2] and np.allclose(r.best, 0.03)


def test_filter_covariance_north_axis_equals_arw_over_sqrt_T():
    """With the true initial attitude, the north gyro's drift is seen directly through phi_N -> vE: the Kalman
    filter's 1-sigma reaches the angle-random-walk limit ARW / sqrt(T) (within 1 %). After self-alignment the east
    drift is unobservable: the filter's sigma stays near its prior (>= 100 x larger)."""
    arw = 0.001 * math.pi / 180 / 60  # 0.001 deg/sqrt(h) in rad/sqrt(s)
    s_true, _ = drift.filter_covariance(3.0, 60.0, LAT, np.eye(3), arw, "true_attitude")
    assert s_true[1] / DEG_PER_H == pytest.approx(0.001 / math.sqrt(3.0), rel=0.01)
    s_sa, _ = drift.filter_covariance(3.0, 60.0, LAT, np.eye(3), arw, "self_aligned")
    assert s_sa[0] > 100 * s_true[0]


@pytest.fixture(scope="module")
def quiet_window(tmp_path_factory):
    """1 h of He 2019 stationary data with no noise: drift (-0.01, 0.01, 0.01) deg/h, accel bias 1e-3 m/s^2."""
    p = tmp_path_factory.mktemp("drift") / "w.nc"
    simulate_static_session({"mode": "physical", "duration_h": 1.0, "site": {"latitude_deg": 30.58},
                             "gyro_noise": {"model": "arw", "arw_deg_rth": 0.0}}, 1, p)
    win = drift.load_window(p, 1.0, 2.0)
    return drift.NavigationCost(win, 60.0, [1, 1, 1, 10], "arcmin")


def test_estimators_recover_the_drift_without_noise(quiet_window):
    """Without noise, the Kalman filter and the linear least squares with accelerometer biases recover the true
    drift (to 3 % of its size: the remaining difference is the nonlinearity of the 1 h navigation)."""
    arw = 1e-9
    e, se, ab = drift.kalman_baseline(quiet_window, arw, "true_attitude")
    assert np.abs(e - TRUTH).max() < 0.03 * 0.01
    assert ab[:2] == pytest.approx([1e-3, 1e-3], rel=0.03)
    e2, ab2, _ = drift.linear_lsq(quiet_window, with_accel_bias=True)
    assert np.abs(e2 - TRUTH).max() < 0.03 * 0.01


def test_drift_only_J_is_biased_by_the_accelerometer_bias(quiet_window):
    """He et al. (2019)'s J on a drift-only model: the unmodelled accelerometer bias moves its minimum away from the
    truth, so J at the truth is larger than J at the drift-only least-squares solution."""
    e, _, _ = drift.linear_lsq(quiet_window, with_accel_bias=False)
    J = quiet_window(np.array([TRUTH, e]))
    assert J[1] < J[0]
    assert np.abs(e - TRUTH).max() > 0.005  # more than half the drift itself


def test_two_hz_navigation_matches_100_hz_path(tmp_path):
    """The fitness uses 2 Hz navigation of pre-integrated increments; on the stationary data it matches the
    100 Hz single-speed path to 1e-3 of J."""
    p = tmp_path / "w.nc"
    simulate_static_session({"mode": "physical", "duration_h": 0.5, "site": {"latitude_deg": 30.58}}, 3, p)
    X = np.array([TRUTH, [0.0, 0.0, 0.0], [0.02, -0.02, 0.0]])
    J = [drift.NavigationCost(drift.load_window(p, 0.5, r), 60.0, [1, 1, 1, 10], "arcmin")(X) for r in (2.0, 100.0)]
    assert J[0] == pytest.approx(J[1], rel=1e-3)


def test_window_longer_than_recording_is_refused(tmp_path):
    p = tmp_path / "w.nc"
    simulate_static_session({"mode": "physical", "duration_h": 0.1, "site": {"latitude_deg": 30.58}}, 3, p)
    with pytest.raises(ValueError, match="window_h"):
        drift.load_window(p, 3.0, 2.0)


def test_pso_evaluates_a_visited_position_once_with_the_same_result():
    """The swarm's repeated positions are scored from the first evaluation (RowMemo): the run equals the plain
    particle swarm on every evaluation, bit for bit, while the cost sees each position once. In the paper variant
    (deterministic pulls, velocity clamp) particles come to rest on the best positions, so repeats occur."""
    x0 = np.array([0.012, -0.007, 0.021])
    seen = []

    def bowl(X):
        seen.extend(r.tobytes() for r in X)
        return np.sum((X - x0) ** 2, axis=1) + 1e-3 * np.sum(np.abs(X), axis=1)

    s = pso.PSOSettings(generations=80, v_max=0.002)
    r = pso.minimize(bowl, np.random.default_rng(5), s)
    plain = particle_swarm(lambda X: np.sum((X - x0) ** 2, axis=1) + 1e-3 * np.sum(np.abs(X), axis=1),
                           np.full(3, s.lower), np.full(3, s.upper), np.random.default_rng(5), s.particles,
                           s.generations, c1=s.c1, c2=s.c2, vlim=s.v_max, inertia=s.inertia,
                           fixed_coefficients=(s.r1, s.r2), init_velocity="zero", gbest_update="strict",
                           keep_trajectory=True)
    assert r.best.tobytes() == plain.gbest.tobytes() and r.best_cost == plain.gcost
    assert r.history.tobytes() == plain.history.tobytes()
    assert r.positions.tobytes() == plain.trajectory.tobytes()
    assert len(seen) == len(set(seen))   # no position evaluated twice
    visited = {p.tobytes() for p in r.positions.reshape(-1, 3)}
    assert len(seen) == len(visited) < s.particles * (s.generations + 1)


def test_row_memo_refuses_a_cost_of_the_wrong_length():
    memo = pso.RowMemo(lambda X: np.zeros(len(X) + 1))
    with pytest.raises(ValueError, match="2 values for 1 particles"):
        memo(np.zeros((3, 3)))
