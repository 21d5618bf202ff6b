"""Synthetic-data stage: path plan, exact kinematics, pulse-count output, effects, long static sessions.

Every expected value is a closed form of the truth (Liu 2021 eqs. 1-4 and 21, WGS-84 normal gravity and
Earth rate, the effect formulas of calib.sim.effects), never a number captured from the simulator.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import xarray as xr

from calib.core import earth
from calib.sim import effects
from calib.io import recording
from calib.sim.calibration_session import (build_calibration_simulator, calibration_session_channels,
                                           calibration_session_dataset, simulate_calibration_session)
from calib.sim.counts_engine import NOISE_BLOCK, _noise_and_count
from calib.sim.settings import NOISE_DEFAULTS, SimConfigError, STATIC_COUNTS_DEFAULTS, TEMPERATURE_DEFAULTS
from calib.sim.static_session import simulate_static_session, static_counts_dataset
from calib.sim import trajectory
from calib.core.earth import STANDARD_GRAVITY
from calib.core.triad import liu2021_model
from calib.core.rotations import dcm_to_rotvec, euler_to_dcm, rot_x, rot_y, rot_z, rotvec_to_dcm

LAT, H = 30.58, 0.0
SITE = {"latitude_deg": LAT, "height_m": H}
FS = 100.0
DT = 1.0 / FS
GAMMA = float(earth.normal_gravity(math.radians(LAT), H))
W_IE_N = earth.earth_rate_enu(math.radians(LAT))
EAST, NORTH, UP = np.eye(3)

#: short calibration session: 24 positions of 10 s, +-10/20/30 deg/s windows of one revolution
SHORT = {"site": SITE, "dwell_s": 10.0, "revolutions": 1, "sample_rate_hz": FS}
QUIET = {"accel_vrw_ug_rthz": 0.0, "accel_bias_instability_ug": 0.0, "gyro_arw_deg_rth": 0.0,
         "gyro_bias_instability_deg_h": 0.0}
#: tiny session for the effect checks (2 positions per phase, one rate)
TINY = {"site": SITE, "dwell_s": 2.0, "positions_per_phase": 2, "step_deg": 90.0, "rotation_rates_deg_s": [30.0],
        "revolutions": 1, "sample_rate_hz": FS, "noise": {**QUIET, "quantize": False}}

ACC, GYR = liu2021_model("accel"), liu2021_model("gyro")


def true_rates(cbn, acc=ACC, gyr=GYR, lat=LAT, gamma=GAMMA):
    """Closed-form static output K E x + b [count s-1] at attitude C_b^n (Liu 2021 eqs. 1, 3)."""
    f_g = cbn.T @ np.array([0.0, 0.0, gamma]) / STANDARD_GRAVITY
    w_dh = cbn.T @ earth.earth_rate_enu(math.radians(lat)) / earth.DEG_PER_H
    return acc.KE @ f_g + acc.b, gyr.KE @ w_dh + gyr.b


def seg_slices(ds):
    idx = ds["segment_index"].values
    out = []
    for j in range(ds.sizes["segment"]):
        k = np.flatnonzero(idx == j)
        assert k.size and np.all(np.diff(k) == 1), f"segment {j} is not one contiguous run"
        out.append(slice(k[0], k[-1] + 1))
    return out


@pytest.fixture(scope="module")
def noisy(tmp_path_factory):
    d = tmp_path_factory.mktemp("cal")
    path = simulate_calibration_session(SHORT, 7, d / "cal.nc", d / "cal.truth.json")
    return path, recording.load(path), d


@pytest.fixture(scope="module")
def quiet(tmp_path_factory):
    d = tmp_path_factory.mktemp("calq")
    path = simulate_calibration_session({**SHORT, "noise": QUIET}, 7, d / "cal.nc")
    return recording.load(path)


# ---- plan -----------------------------------------------------------------------------------------

def test_plan_is_the_liu2021_path():
    plan = trajectory.calibration_plan(time_grid_s=DT)
    segs = trajectory.recorded_segments(plan)
    labels = [s.label for s in segs]
    assert labels[:24] == [f"P{p}-POS{k}" for p in (1, 2, 3) for k in range(1, 9)]
    assert labels[24:] == [f"ROT-{a}{s}{r}" for a in "xyz" for r in (10, 20, 30) for s in "+-"]
    up_at_pos1 = {1: 2, 2: 0, 3: 1}  # phase -> body axis up at POS1 (z, x, y)
    for p in (1, 2, 3):
        ax = p - 1
        cs = [s.cbn_start for s in segs[8 * ax:8 * ax + 8]]
        for k, c in enumerate(cs):
            np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-13)
            assert np.linalg.det(c) == pytest.approx(1.0)
            np.testing.assert_allclose(c[:, ax], NORTH, atol=1e-13)  # phase axis points north
            np.testing.assert_array_equal(segs[8 * ax + k].axis, np.eye(3)[ax])
        np.testing.assert_allclose(cs[0][:, up_at_pos1[p]], UP, atol=1e-13)
        rot = (rot_x, rot_y, rot_z)[ax]
        for c0, c1 in zip(cs[:-1], cs[1:]):  # consecutive positions 45 deg apart about the phase axis
            np.testing.assert_allclose(c0.T @ c1, rot(math.radians(45.0)), atol=1e-13)
    for s in segs[24:]:
        ax = "xyz".index(s.label[4])
        np.testing.assert_allclose(s.cbn_start[:, ax], UP, atol=1e-13)  # rotation axis held vertical
        if s.label.startswith("ROT-z"):
            np.testing.assert_allclose(s.cbn_start, np.eye(3), atol=1e-13)  # Liu 2021 eq. 21 start
        rate = float(s.label[5:])
        assert s.rate_deg_s == rate
        assert s.duration_s == pytest.approx(2 * 360.0 / abs(rate))
    # the transitions really move the IMU: the attitude is continuous through the whole plan
    for a, b in zip(plan[:-1], plan[1:]):
        np.testing.assert_allclose(a.cbn_end, b.cbn_start, atol=1e-12)
        assert b.t_start_s == pytest.approx(a.t_end_s)
    # bounded angular acceleration (ramp of 2 s to at most 30 deg/s) and grid-aligned boundaries
    assert max(abs(s.accel_deg_s2) for s in plan) <= 30.0 / 2.0 + 1e-9
    for s in plan:
        assert abs(s.t_start_s * FS - round(s.t_start_s * FS)) < 1e-6


def test_plan_horizontal_option_and_nominal_attitudes():
    plan = trajectory.calibration_plan(positions_per_phase=2, rotation_rates_deg_s=(10,),
                                       rotation_axes="vertical+horizontal")
    segs = trajectory.recorded_segments(plan)
    horiz = [s for s in segs if s.label.startswith("ROTH-")]
    assert [s.label for s in horiz] == ["ROTH-x+10", "ROTH-x-10", "ROTH-y+10", "ROTH-y-10", "ROTH-z+10", "ROTH-z-10"]
    for s in horiz:
        ax = "xyz".index(s.label[5])
        np.testing.assert_allclose(s.cbn_start[:, ax], NORTH, atol=1e-13)
    att = trajectory.planned_nominal_attitudes(plan)
    np.testing.assert_array_equal(att, np.array([s.cbn_start for s in segs]))
    with pytest.raises(ValueError, match="rotation_axes"):
        trajectory.calibration_plan(rotation_axes="diagonal")


def test_kinematics_norms_and_eq21():
    plan = trajectory.calibration_plan(dwell_s=5.0, revolutions=1, time_grid_s=DT)
    traj = trajectory.Trajectory(plan)
    for s in plan:
        t = s.t_start_s + np.linspace(0.0, s.duration_s, 7)
        k = traj.kinematics(t, math.radians(LAT), H)
        # |f| = normal gravity everywhere on the table axis, |omega| = Earth rate at rest
        np.testing.assert_allclose(np.linalg.norm(k.f_b, axis=1), GAMMA, rtol=1e-13)
        if s.kind == "static":
            np.testing.assert_allclose(np.linalg.norm(k.w_ib_b, axis=1), earth.OMEGA_IE, rtol=1e-12)
            np.testing.assert_allclose(k.cbn, np.broadcast_to(s.cbn_start, k.cbn.shape), atol=1e-13)
        if s.kind == "rotation" and s.label.startswith("ROT-z"):
            w = math.radians(s.rate_deg_s)
            tau = t - s.t_start_s
            c, sn = np.cos(w * tau), np.sin(w * tau)
            om, L = earth.OMEGA_IE, math.radians(LAT)
            expect = np.stack([sn * om * math.cos(L),
                               c * om * math.cos(L), np.full_like(tau, w + om * math.sin(L))], axis=1)
            np.testing.assert_allclose(k.w_ib_b, expect, atol=1e-15)  # Liu 2021 eq. (21)
            np.testing.assert_allclose(k.table_angle_deg, s.rate_deg_s * tau, atol=1e-9)


# ---- output of the calibration session -----------------------------------------------------------

def test_recording_layout(noisy):
    path, ds, d = noisy
    assert ds["accel"].dtype == np.int32 and ds["gyro"].dtype == np.int32
    for v in ("accel", "gyro"):
        assert ds[v].attrs["sample_kind"] == "increment" and ds[v].attrs["units"] == "count"
    assert ds.attrs["latitude_deg"] == LAT and ds.attrs["source"] == "synthetic"
    assert ds.attrs["sensor"] == "liu2021 synthetic nav-grade unit"
    assert ds.attrs["accel_input_unit"] == "g" and ds.attrs["gyro_input_unit"] == "deg h-1"
    assert set(ds["segment_kind"].values) == {"static", "rotation"}
    assert (ds["segment_index"].values == -1).any()
    truth = json.loads((d / "cal.truth.json").read_text())
    np.testing.assert_allclose(truth["accel"]["vector"], ACC.to_vector())
    np.testing.assert_allclose(truth["gyro"]["vector"], GYR.to_vector())
    assert truth["seed"] == 7 and truth["effects"] == {}


def _static_check(ds, tol_fn):
    segs = seg_slices(ds)
    nom = ds["nominal_attitude"].values
    for j, sl in enumerate(segs):
        if str(ds["segment_kind"].values[j]) != "static":
            continue
        n = sl.stop - sl.start
        ra, rg = true_rates(nom[j])
        ma = ds["accel"].values[sl].astype(float).sum(0) / (n * DT)
        mg = ds["gyro"].values[sl].astype(float).sum(0) / (n * DT)
        ta, tg = tol_fn(n)
        assert np.all(np.abs(ma - ra) < ta), (str(ds["segment_label"].values[j]), ma - ra, ta)
        assert np.all(np.abs(mg - rg) < tg), (str(ds["segment_label"].values[j]), mg - rg, tg)


def test_static_means_noise_free_within_quantisation(quiet):
    # the pulse counter loses less than 1 count over a segment: |mean - K E x - b| < 1 / T
    _static_check(quiet, lambda n: (1.0 / (n * DT), 1.0 / (n * DT)))


def test_static_means_with_noise(noisy):
    nz = NOISE_DEFAULTS
    # 5 sigma of the segment mean: white noise K s_w / (sqrt(n) dt), bias instability K s_b; + quantisation 1/T
    s_wa = nz["accel_vrw_ug_rthz"] * 1e-6 * math.sqrt(DT) * ACC.K
    s_wg = nz["gyro_arw_deg_rth"] * 60.0 * math.sqrt(DT) * GYR.K
    s_ba = nz["accel_bias_instability_ug"] * 1e-6 * ACC.K
    s_bg = nz["gyro_bias_instability_deg_h"] * GYR.K

    def tol(n):
        q = 1.0 / (n * DT)
        return (q + 5 * np.hypot(s_wa / (math.sqrt(n) * DT), s_ba), q + 5 * np.hypot(s_wg / (math.sqrt(n) * DT), s_bg))

    _static_check(noisy[1], tol)


def _revolution_check(ds, tol_deg):
    segs = seg_slices(ds)
    for j, sl in enumerate(segs):
        if str(ds["segment_kind"].values[j]) != "rotation":
            continue
        n = sl.stop - sl.start
        T = n * DT
        counts = ds["gyro"].values[sl].astype(float).sum(0)
        angle = np.linalg.solve(GYR.KE, counts - GYR.b * T) / 3600.0  # (deg/h) s -> deg
        u = ds["rotation_axis"].values[j]
        rate = float(ds["rotation_rate"].values[j])
        assert T == pytest.approx(360.0 / abs(rate))  # one whole revolution in the window
        # the table angle plus the Earth rate along the axis (up: W sin L; north: W cos L)
        along = (ds["nominal_attitude"].values[j] @ u) @ W_IE_N
        expect = math.copysign(360.0, rate) + math.degrees(along) * T
        assert abs(angle @ u - expect) < tol_deg(T), (str(ds["segment_label"].values[j]), angle @ u - expect)
        # the horizontal Earth rate integrates to zero over whole revolutions
        assert np.all(np.abs(angle - (angle @ u) * u) < tol_deg(T))


def test_table_angle_restarts_at_zero_and_sweeps_whole_revolutions(quiet):
    """Every rotation segment's table_angle starts at 0 deg and its last sample is one step short of
    k x 360 deg (sample k covers [k dt, (k+1) dt)), so windows can be cut on whole revolutions."""
    for j, sl in enumerate(seg_slices(quiet)):
        if str(quiet["segment_kind"].values[j]) != "rotation":
            continue
        a = quiet["table_angle"].values[sl]
        rate = float(quiet["rotation_rate"].values[j])
        assert a[0] == pytest.approx(0.0, abs=1e-9)
        assert a[-1] + rate * DT == pytest.approx(math.copysign(360.0, rate) * round(abs(a[-1]) / 360.0), abs=1e-6)


def test_rotation_windows_integrate_to_whole_revolutions(noisy, quiet):
    _revolution_check(quiet, lambda T: 1e-6)
    nz = NOISE_DEFAULTS
    # 5 sigma: angle random walk ARW sqrt(T), bias instability s_b T, plus < 1 count of quantisation
    _revolution_check(noisy[1], lambda T: 5 * (nz["gyro_arw_deg_rth"] * math.sqrt(T / 3600.0)
                                            + nz["gyro_bias_instability_deg_h"] * T / 3600.0) + 1e-6)


def test_horizontal_rotation_windows(tmp_path):
    cfg = {**SHORT, "positions_per_phase": 1, "rotation_rates_deg_s": [30.0], "rotation_axes": "vertical+horizontal",
           "noise": QUIET}
    ds = recording.load(simulate_calibration_session(cfg, 1, tmp_path / "h.nc"))
    labels = [str(x) for x in ds["segment_label"].values]
    assert labels[3:9] == ["ROT-x+30", "ROT-x-30", "ROT-y+30", "ROT-y-30", "ROT-z+30", "ROT-z-30"]
    assert labels[9:] == ["ROTH-x+30", "ROTH-x-30", "ROTH-y+30", "ROTH-y-30", "ROTH-z+30", "ROTH-z-30"]
    _revolution_check(ds, lambda T: 1e-6)


def test_quantisation_tracks_integral(noisy):
    path, ds, _ = noisy
    sim = build_calibration_simulator(SHORT, 7)
    eng = sim.engine()
    incs, counts = [], []
    for i0 in range(0, sim.n_samples, 50_000):
        ch = eng.next(min(50_000, sim.n_samples - i0))
        incs.append(np.hstack([ch.accel_increment, ch.gyro_increment]))
        counts.append(np.hstack([ch.accel, ch.gyro]))
    inc, cnt = np.vstack(incs), np.vstack(counts)
    file_counts = np.hstack([ds["accel"].values, ds["gyro"].values])
    np.testing.assert_array_equal(cnt, file_counts)
    # sum I - sum c = carried fraction in [0, 1) at every sample (sums in extended precision; counts exact)
    lag = np.cumsum(inc.astype(np.longdouble), axis=0) - np.cumsum(cnt.astype(np.int64), axis=0)
    assert lag.min() > -1e-5 and lag.max() < 1.0 + 1e-5
    assert np.abs(cnt[:, 3:]).max() > 1e6  # the rotation windows put millions of counts in one sample


def test_same_seed_identical_different_seed_differs(noisy, tmp_path):
    path, _, _ = noisy
    p2 = simulate_calibration_session(SHORT, 7, tmp_path / "again.nc")
    p3 = simulate_calibration_session(SHORT, 8, tmp_path / "other.nc")
    with xr.open_dataset(path) as a, xr.open_dataset(p2) as b, xr.open_dataset(p3) as c:
        assert a.load().identical(b.load())
        c = c.load()
        assert not np.array_equal(a["gyro"].values, c["gyro"].values)
        assert not np.array_equal(a["accel"].values, c["accel"].values)
        np.testing.assert_array_equal(a["segment_index"].values, c["segment_index"].values)


def test_bad_config_is_refused():
    with pytest.raises(SimConfigError, match="site.latitude_deg"):
        build_calibration_simulator({"dwell_s": 5}, 1)
    with pytest.raises(SimConfigError, match="dwel_s"):
        build_calibration_simulator({"site": SITE, "dwel_s": 5}, 1)
    with pytest.raises(SimConfigError, match="effects.no_such_effect"):
        build_calibration_simulator({"site": SITE, "effects": {"no_such_effect": {}}}, 1)
    with pytest.raises(SimConfigError, match="k2_ug_per_g2"):
        build_calibration_simulator(
            {"site": SITE, "effects": {"accel_quadratic_nonlinearity": {"k2_ug_per_g2": [1.0, 2.0]}}}, 1)
    with pytest.raises(SimConfigError, match="noise.gyro_arw_deg_rth"):
        build_calibration_simulator({"site": SITE, "noise": {"gyro_arw_deg_rth": -1.0}}, 1)


def test_sensor_override():
    sim = build_calibration_simulator(
        {**TINY, "sensor": {"accel": {"K": [1e4, 1e4, 1e4], "b": [0, 0, 0]}, "gyro": {"E": [0.0] * 6}}}, 1)
    np.testing.assert_array_equal(sim.accel.K, [1e4, 1e4, 1e4])
    np.testing.assert_array_equal(sim.accel.E, ACC.E)  # untouched parts keep the Liu 2021 truth
    np.testing.assert_array_equal(sim.gyro.E, np.eye(3))


# ---- effects --------------------------------------------------------------------------------------

def _run(cfg, seed=3):
    sim = build_calibration_simulator(cfg, seed)
    ch = sim.engine().next(sim.n_samples)
    return sim, ch


@pytest.fixture(scope="module")
def base():
    return _run(TINY)


def _with(effect, **params):
    return _run({**TINY, "effects": {effect: {"enabled": True, **params}}})


def _static_segments(sim):
    idx = trajectory.sample_segment_index(sim.plan, sim.n_samples, FS)
    for j, s in enumerate(trajectory.recorded_segments(sim.plan)):
        yield s, np.flatnonzero(idx == j)


def _inputs(cbn, gamma=GAMMA, lat=LAT):
    f_g = cbn.T @ np.array([0.0, 0.0, gamma]) / STANDARD_GRAVITY
    w = cbn.T @ earth.earth_rate_enu(math.radians(lat)) / earth.DEG_PER_H
    return f_g, w, ACC.E @ f_g, GYR.E @ w


def _check_static_term(base, effect, term_fn, sensor="accel"):
    """diff of the rate output over static samples == K * term(inputs) (closed form)."""
    sim0, ch0 = base
    sim1, ch1 = _with(effect)
    p = effects.REGISTRY[effect].defaults
    K = (ACC if sensor == "accel" else GYR).K
    checked = 0
    for s, k in _static_segments(sim1):
        if s.kind != "static":
            continue
        f_g, w, ya, yg = _inputs(s.cbn_start)
        got = (getattr(ch1, f"{sensor}_increment")[k] - getattr(ch0, f"{sensor}_increment")[k]) / DT
        np.testing.assert_allclose(got, np.broadcast_to(K * term_fn(p, f_g, w, ya, yg), got.shape),
                                   rtol=1e-7, atol=1e-7)
        checked += 1
    assert checked == 6
    other = "gyro" if sensor == "accel" else "accel"
    np.testing.assert_array_equal(getattr(ch1, f"{other}_increment"), getattr(ch0, f"{other}_increment"))


def test_effect_registry_ids():
    assert set(effects.REGISTRY) == {
        "accel_quadratic_nonlinearity", "accel_cubic_nonlinearity", "accel_scale_asymmetry", "accel_cross_coupling",
        "accel_lever_arm", "gyro_g_sensitivity", "gyro_scale_asymmetry", "gyro_scale_nonlinearity", "bias_drift",
        "temperature_sensitivity", "latitude_error", "gravity_error", "time_offset"}
    for eid, e in effects.REGISTRY.items():
        apply, defaults = e[:2]
        assert callable(apply) and isinstance(defaults, dict) and set(e.units) == set(defaults), eid
    assert effects.resolve({"bias_drift": False}) == {}


def test_effect_accel_quadratic(base):
    _check_static_term(base, "accel_quadratic_nonlinearity", lambda p, f, w, ya, yg: np.array(p["k2_ug_per_g2"]) * 1e-6 * ya**2)


def test_effect_accel_cubic(base):
    _check_static_term(base, "accel_cubic_nonlinearity", lambda p, f, w, ya, yg: np.array(p["k3_ug_per_g3"]) * 1e-6 * ya**3)


def test_effect_accel_asymmetry(base):
    _check_static_term(base, "accel_scale_asymmetry", lambda p, f, w, ya, yg: np.array(p["asym_ppm"]) * 1e-6 * np.abs(ya))


def test_effect_accel_cross_coupling(base):
    def term(p, f, w, ya, yg):
        c = np.array(p["k_cross_ug_per_g2"]) * 1e-6
        return np.array([f[i] * sum(c[i, j] * f[j] for j in range(3) if j != i) for i in range(3)])
    _check_static_term(base, "accel_cross_coupling", term)


def test_effect_gyro_g_sensitivity(base):
    _check_static_term(base, "gyro_g_sensitivity", lambda p, f, w, ya, yg: np.array(p["G_deg_h_per_g"]) @ f, "gyro")


def test_effect_gyro_asymmetry(base):
    _check_static_term(base, "gyro_scale_asymmetry", lambda p, f, w, ya, yg: np.array(p["asym_ppm"]) * 1e-6 * np.abs(yg), "gyro")


def _rotation_windows(sim):
    for s, k in _static_segments(sim):
        if s.kind == "rotation":
            yield s, k


def test_effect_accel_lever_arm(base):
    sim0, ch0 = base
    sim1, ch1 = _with("accel_lever_arm")
    r = np.array(effects.REGISTRY["accel_lever_arm"].defaults["lever_arms_m"])
    for s, k in _static_segments(sim1):
        diff = (ch1.accel_increment[k] - ch0.accel_increment[k]) / DT
        if s.kind == "static":
            np.testing.assert_array_equal(diff, 0.0)  # no motion, no lever-arm term
            continue
        w = s.axis * math.radians(s.rate_deg_s)  # constant rate: centripetal only
        expect = [ACC.K[i] * (ACC.E[i] @ np.cross(w, np.cross(w, r[i]))) / STANDARD_GRAVITY for i in range(3)]
        np.testing.assert_allclose(diff, np.broadcast_to(expect, diff.shape), rtol=1e-9, atol=1e-9)


def test_effect_gyro_scale_nonlinearity(base):
    sim0, ch0 = base
    sim1, ch1 = _with("gyro_scale_nonlinearity")
    kp = np.array(effects.REGISTRY["gyro_scale_nonlinearity"].defaults["k_ppm_per_deg_s"])
    n_win = 0
    for s, k in _rotation_windows(sim1):
        ax = int(np.argmax(s.axis))
        # axis sensor: y = E[a] omega; its mean over whole turns is rate + W sin L (horizontal terms average out)
        y = s.rate_deg_s * 3600.0 + math.degrees(earth.OMEGA_IE * math.sin(math.radians(LAT))) * 3600.0
        got = (ch1.gyro_increment[k, ax] - ch0.gyro_increment[k, ax]).sum() / (len(k) * DT)
        assert got == pytest.approx(GYR.K[ax] * kp[ax] * 1e-6 * y * abs(y) / 3600.0, rel=1e-6)
        n_win += 1
    assert n_win == 6


def test_effect_bias_drift(base):
    sim0, ch0 = base
    sim1, ch1 = _with("bias_drift")
    p = effects.REGISTRY["bias_drift"].defaults
    t0 = np.arange(sim1.n_samples) * DT
    t1 = t0 + DT

    def integral(A, tau, s):  # int_{t0}^{t1} (A exp(-t/tau) + s t / 3600) dt, per axis
        A, s = np.asarray(A), np.asarray(s)
        return (A * tau * (np.exp(-t0 / tau) - np.exp(-t1 / tau))[:, None]
                + s * ((t1**2 - t0**2) / 7200.0)[:, None])

    ea = ACC.K * integral(p["accel_warmup_ug"], p["accel_tau_s"], p["accel_trend_ug_per_h"]) * 1e-6
    eg = GYR.K * integral(p["gyro_warmup_deg_h"], p["gyro_tau_s"], p["gyro_trend_deg_h_per_h"])
    np.testing.assert_allclose(ch1.accel_increment - ch0.accel_increment, ea, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(ch1.gyro_increment - ch0.gyro_increment, eg, rtol=1e-6, atol=1e-9)


def test_effect_temperature(base, tmp_path):
    sim0, ch0 = base
    sim1, ch1 = _with("temperature_sensitivity")
    p = effects.REGISTRY["temperature_sensitivity"].defaults
    prof = TEMPERATURE_DEFAULTS
    for s, k in _static_segments(sim1):
        if s.kind != "static":
            continue
        tm = (k + 0.5) * DT
        T = prof["end_degC"] + (prof["start_degC"] - prof["end_degC"]) * np.exp(-tm / prof["tau_s"])
        np.testing.assert_allclose(ch1.temperature[k], T, rtol=1e-12)
        dT = (T - p["T_ref_degC"])[:, None]
        f_g, w, ya, yg = _inputs(s.cbn_start)
        ea = ACC.K * (np.array(p["accel_bias_ug_per_degC"]) * 1e-6 * dT + np.array(p["accel_scale_ppm_per_degC"]) * 1e-6 * dT * ya)
        eg = GYR.K * (np.array(p["gyro_bias_deg_h_per_degC"]) * dT + np.array(p["gyro_scale_ppm_per_degC"]) * 1e-6 * dT * yg)
        # midpoint vs 3-point Gauss over 10 ms of a 30-min exponential: equal to ~1e-11 relative
        np.testing.assert_allclose((ch1.accel_increment[k] - ch0.accel_increment[k]) / DT, ea, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose((ch1.gyro_increment[k] - ch0.gyro_increment[k]) / DT, eg, rtol=1e-7, atol=1e-9)


def test_effect_latitude_and_gravity_error(base):
    dlat, dg = 0.5, 4e-4
    sim1, ch1 = _run({**TINY, "effects": {"latitude_error": {"delta_lat_deg": dlat},
                                          "gravity_error": {"delta_g_m_s2": dg}}})
    assert sim1.latitude_deg == LAT  # the file keeps the assumed latitude
    g_true = float(earth.normal_gravity(math.radians(LAT + dlat), H)) + dg
    for s, k in _static_segments(sim1):
        if s.kind != "static":
            continue
        ra, rg = true_rates(s.cbn_start, lat=LAT + dlat, gamma=g_true)
        np.testing.assert_allclose(ch1.accel_increment[k] / DT, np.broadcast_to(ra, (len(k), 3)), rtol=1e-12)
        np.testing.assert_allclose(ch1.gyro_increment[k] / DT, np.broadcast_to(rg, (len(k), 3)), rtol=1e-10)
        # the calibrated specific-force norm is the true local gravity, not normal gravity at the file's latitude
        f = np.linalg.solve(ACC.KE, ch1.accel_increment[k[0]] / DT - ACC.b) * STANDARD_GRAVITY
        assert np.linalg.norm(f) == pytest.approx(g_true, rel=1e-12)


def test_effect_time_offset(base):
    sim0, ch0 = base
    sim1, ch1 = _with("time_offset", offset_s=0.05)
    m = 5  # 0.05 s at 100 Hz: the IMU sees at stamp t what the table did at t + 0.05 s
    np.testing.assert_allclose(ch1.gyro_increment[:-m], ch0.gyro_increment[m:], rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(ch1.accel_increment[:-m], ch0.accel_increment[m:], rtol=1e-9, atol=1e-6)
    assert not np.allclose(ch1.gyro_increment, ch0.gyro_increment, rtol=1e-6)


def test_conceal_hides_effects(tmp_path):
    eff = {"accel_quadratic_nonlinearity": {}, "time_offset": {"offset_s": 0.02}}
    shown = simulate_calibration_session({**TINY, "effects": eff}, 1, tmp_path / "shown.nc")
    hidden = simulate_calibration_session({**TINY, "effects": eff, "conceal": True}, 1, tmp_path / "hidden.nc",
                                          tmp_path / "hidden.truth.json")
    plain = simulate_calibration_session({**TINY, "conceal": True}, 1, tmp_path / "plain.nc")
    with xr.open_dataset(shown) as s:
        assert "accel_quadratic_nonlinearity" in s.attrs["effects_enabled"]  # the check below can fail
    with xr.open_dataset(hidden) as h, xr.open_dataset(plain) as p:
        texts = [f"{k}={v}" for k, v in h.attrs.items()]
        for var in h.variables.values():
            texts += [f"{k}={v}" for k, v in var.attrs.items()]
        blob = " ".join(texts).lower()
        for eid in effects.REGISTRY:
            assert eid not in blob
        assert "effect" not in blob
        assert set(h.variables) == set(p.variables) and set(h.attrs) == set(p.attrs)
    truth = json.loads((tmp_path / "hidden.truth.json").read_text())
    assert set(truth["effects"]) == set(eff)


# ---- long stationary sessions ---------------------------------------------------------------------

PHYS = {"site": SITE, "mode": "physical", "duration_h": 0.5, "sample_rate_hz": FS,
        "attitude_deg": {"pitch": 2.0, "roll": -3.0, "yaw": 40.0}}


def _read_all(path):
    h = recording.read_header(path)
    acc, gyr = [], []
    for _, a, g in recording.iter_raw_chunks(path, h):
        acc.append(a)
        gyr.append(g)
    return h, np.vstack(acc), np.vstack(gyr)


def test_static_physical_mean_and_noise(tmp_path):
    calls = []
    p = simulate_static_session(PHYS, 11, tmp_path / "nav.nc", tmp_path / "nav.truth.json",
                                progress=lambda d, n: calls.append((d, n)), chunk_samples=100_000)
    h, dv, dth = _read_all(p)
    n = h.n_samples
    assert n == 180_000 and calls[-1] == (n, n) and h.gyro_units == "rad" and h.accel_units == "m s-1"
    cbn = euler_to_dcm(*np.radians([2.0, -3.0, 40.0]))
    drift = np.array([-0.01, 0.01, 0.01]) * earth.DEG_PER_H
    expect_g = (cbn.T @ W_IE_N + drift) * DT
    expect_a = (cbn.T @ np.array([0.0, 0.0, GAMMA]) + 0.001) * DT
    sig = 0.001 * earth.DEG / 60.0 * math.sqrt(DT)  # ARW 0.001 deg/sqrt(h) per sample [rad]
    np.testing.assert_allclose(dth.mean(0), expect_g, rtol=0, atol=5 * sig / math.sqrt(n))
    # the drift alone is several sigma of this mean: leaving it out must fail the same check
    assert np.any(np.abs(dth.mean(0) - (expect_g - drift * DT)) > 5 * sig / math.sqrt(n))
    np.testing.assert_allclose(dth.std(0), sig, rtol=0.02)
    np.testing.assert_array_equal(dv, np.broadcast_to(expect_a, dv.shape))  # no accel noise by default
    truth = json.loads((tmp_path / "nav.truth.json").read_text())
    np.testing.assert_allclose(truth["mean_increment"]["gyro_rad"], expect_g, rtol=1e-12)


def test_static_physical_white_reading_and_vrw(tmp_path):
    cfg = {**PHYS, "duration_h": 0.1, "gyro_noise": {"model": "white", "white_deg_h": 0.001},
           "accel_vrw_ug_rthz": 20.0}
    h, dv, dth = _read_all(simulate_static_session(cfg, 5, tmp_path / "w.nc"))
    np.testing.assert_allclose(dth.std(0), 0.001 * earth.DEG_PER_H * DT, rtol=0.03)
    np.testing.assert_allclose(dv.std(0), 20e-6 * STANDARD_GRAVITY * math.sqrt(DT), rtol=0.03)


@pytest.mark.parametrize("mode,effect", [("physical", None), ("counts", None), ("counts", "bias_drift"),
                                         ("counts", "temperature_sensitivity")])
def test_static_chunk_size_independent(tmp_path, mode, effect):
    cfg = {**PHYS, "duration_h": 0.25, "mode": mode}  # 90,000 samples: crosses a noise block
    if mode == "counts":
        cfg = {k: v for k, v in cfg.items() if k in STATIC_COUNTS_DEFAULTS}
        cfg["effects"] = {effect: {}} if effect else {}
    a = _read_all(simulate_static_session(cfg, 3, tmp_path / "a.nc", chunk_samples=7_777))
    b = _read_all(simulate_static_session(cfg, 3, tmp_path / "b.nc", chunk_samples=1 << 20))
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_array_equal(a[2], b[2])


def test_static_counts_matches_unit(tmp_path):
    cfg = {"site": SITE, "mode": "counts", "duration_h": 0.1, "sample_rate_hz": FS,
           "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}, "noise": QUIET}
    p = simulate_static_session(cfg, 2, tmp_path / "s.nc", tmp_path / "s.truth.json")
    ds = recording.load(p)
    assert ds["accel"].dtype == np.int32 and "temperature" in ds
    n = ds.sizes["time"]
    ra, rg = true_rates(np.eye(3))  # body axes along E, N, U
    T = n * DT
    np.testing.assert_array_less(np.abs(ds["accel"].values.astype(float).sum(0) / T - ra), 1.0 / T)
    np.testing.assert_array_less(np.abs(ds["gyro"].values.astype(float).sum(0) / T - rg), 1.0 / T)
    assert ds.attrs["effects_enabled"] == "none"


def test_gyro_sees_the_transitions(quiet):
    """Strapdown attitude propagation of the quantised gyro output (converted with the true model) carries
    the nominal attitude at the end of each segment to the nominal attitude at the start of the next:
    C_{k+1} = exp(-[w_ie^n dt x]) C_k exp([dtheta_k x])."""
    ds = quiet
    segs = seg_slices(ds)
    nom = ds["nominal_attitude"].values
    rate = np.linalg.solve(GYR.KE, (ds["gyro"].values / DT - GYR.b).T).T * earth.DEG_PER_H  # rad/s
    dth = rate * DT
    earth_step = rotvec_to_dcm(-W_IE_N * DT)
    worst = 0.0
    for j in range(len(segs) - 1):
        c = nom[j]  # statics end where they start; rotation windows after whole revolutions
        for k in range(segs[j].stop, segs[j + 1].start):
            c = earth_step @ c @ rotvec_to_dcm(dth[k])
        err = np.linalg.norm(dcm_to_rotvec(c.T @ nom[j + 1]))
        worst = max(worst, err)
    # 1 count of quantisation is 1.2e-10 rad; allow float round-off over ~1,000-sample transitions
    assert worst < 1e-8


# ---- in-memory sessions (the z-score study) ----------------------------------------------------------

@pytest.mark.parametrize("effect,chunk", [(None, NOISE_BLOCK), (None, 7_777),
                                          ("temperature_sensitivity", NOISE_BLOCK),
                                          ("bias_drift", 50_000)])
def test_static_counts_dataset_is_the_loaded_file(tmp_path, effect, chunk):
    """``static_counts_dataset`` is what ``recording.load`` returns for the file of ``simulate_static_session``
    (counts mode): the same samples, dtypes, variables and attributes, for any generation chunk."""
    cfg = {"site": SITE, "mode": "counts", "duration_h": 0.25, "sample_rate_hz": FS,  # crosses a noise block
           "attitude_deg": {"pitch": 2.0, "roll": -3.0, "yaw": 40.0}, "effects": {effect: {}} if effect else {}}
    p = simulate_static_session(cfg, 11, tmp_path / "s.nc")
    a, b = static_counts_dataset(cfg, 11, chunk_samples=chunk, path=p), recording.load(p)
    assert sorted(a.variables) == sorted(b.variables)
    for v in a.variables:
        assert a[v].dtype == b[v].dtype and a[v].dims == b[v].dims and a[v].attrs == b[v].attrs, v
        np.testing.assert_array_equal(a[v].values, b[v].values, err_msg=v)
    assert set(a.attrs) == set(b.attrs)
    for k in a.attrs:
        assert type(a.attrs[k]) is type(b.attrs[k]) and np.array_equal(a.attrs[k], b.attrs[k]), k
    with pytest.raises(SimConfigError, match="static_session.mode: 'physical'"):
        static_counts_dataset({**cfg, "mode": "physical"}, 11)


def test_static_counts_dataset_without_a_mode_is_the_counts_session():
    """The in-memory static record is counts only, so a config that names no mode is a counts session (not
    refused as the physical mode the caller never asked for): the same record as with ``mode: counts``."""
    cfg = {"site": SITE, "duration_h": 0.002, "sample_rate_hz": FS}
    a, b = static_counts_dataset(cfg, 4), static_counts_dataset({**cfg, "mode": "counts"}, 4)
    assert a.identical(b) and a["accel"].dtype == np.int32 and a.sizes["time"] == round(0.002 * 3600 * FS)


def test_calibration_session_dataset_for_another_seed(noisy):
    """The clean increments and the seed-independent channels of one simulator serve every noise seed: the
    dataset for seed 7 from a simulator of seed 3 has the samples of the file written for seed 7."""
    _, ds, _ = noisy
    sim = build_calibration_simulator(SHORT, 3)
    mem = calibration_session_dataset(sim, 7, sim.clean_increments(),
                                      calibration_session_channels(sim))
    for v in ("accel", "gyro", "temperature", "segment_index", "table_angle", "time", "rotation_rate",
              "nominal_attitude"):
        assert mem[v].dtype == ds[v].dtype, v
        np.testing.assert_array_equal(mem[v].values, ds[v].values, err_msg=v)
    own = calibration_session_dataset(sim)  # the simulator's own seed, everything computed here
    assert not np.array_equal(own["accel"].values, ds["accel"].values)
    np.testing.assert_array_equal(own["table_angle"].values, ds["table_angle"].values)


@pytest.mark.parametrize("quantize", [True, False])
def test_noise_and_count_is_the_stated_recursion(quantize):
    """The compiled noise and pulse counter (blocks of rows through two kernels) against the recursion of its
    docstring written out in plain Python: beta_i = a beta_(i-1) + c z_i, inc_i = clean_i + K (sig_w z_i + beta_i dt),
    counts_i = floor(r + inc_i) with the fraction r carried -- to the bit, over more than one block of rows and on
    broadcast (constant) clean increments."""
    rng = np.random.default_rng(20261126)
    n, dt = 9000, 0.01
    z = rng.standard_normal((n, 12))
    sig_w, c, K = rng.random(6), rng.random(6) * 1e-3, 1e4 * (0.5 + rng.random(6))
    a = np.array([1.0, 0.999, 0.99, 1.0, 0.999, 0.9])
    for clean in (rng.normal(size=(n, 6)) * 1e3, np.broadcast_to(rng.normal(size=6) * 1e3, (n, 6))):
        beta, carry = np.full(6, 0.1), np.full(6, 0.3)
        inc = np.empty((n, 6))
        counts = np.empty((n, 6), dtype=np.int64) if quantize else inc
        _noise_and_count(clean, z, sig_w, a, c, K, dt, beta, carry, quantize, inc, counts)
        b, r = [0.1] * 6, [0.3] * 6
        want_inc, want_counts = np.empty((n, 6)), np.empty((n, 6), dtype=np.int64)
        for i in range(n):
            for j in range(6):
                b[j] = float(a[j]) * b[j] + float(c[j]) * float(z[i, 6 + j])
                x = float(clean[i, j]) + float(K[j]) * (float(sig_w[j]) * float(z[i, j]) + b[j] * dt)
                want_inc[i, j] = x
                q = math.floor(r[j] + x)
                want_counts[i, j], r[j] = q, r[j] + x - q
        assert np.array_equal(inc, want_inc)
        assert np.array_equal(beta, b)
        if quantize:
            assert np.array_equal(counts, want_counts) and np.array_equal(carry, r)
