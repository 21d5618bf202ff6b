"""The physical path of the library's effects (calib.sim.physical): two independent implementations of the same
physics must agree, and each must meet its closed form.

The registry formulas (calib.sim.effects, evaluated at Gauss-Legendre nodes inside each sample by the simulator's
kinematics) are what the diagnosis fits; the physical path works on the noise-free output through the unit's true
linear model, differentiates the proof masses' motion numerically and resamples the stream for a clock offset.
Agreement of the two (to what their different discretisations allow) is evidence that the proof's sessions carry
the effect the truth sidecar names, made by a path the detector does not use."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from calib.sim import effects, physical
from calib.sim.calibration_session import build_calibration_simulator
from calib.sim.counts_engine import temperature_profile
from calib.studies.diagnosis_proof import PROOF_SESSIONS

SHORT = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1, "conceal": True}


@pytest.fixture(scope="module")
def base():
    sim = build_calibration_simulator({**SHORT, "effects": {}}, 0)
    dt = 1.0 / sim.sample_rate_hz
    temp = temperature_profile((np.arange(sim.n_samples) + 0.5) * dt, sim.temperature)
    return sim, sim.clean_increments(), temp


#: largest disagreement between the two paths, relative to the effect's largest per-sample size. Where they differ
#: and why: the asymmetry |y| changes slope inside the samples where an input crosses zero (the node sum and the
#: sample-mean input then differ by up to ~1e-3 of the effect); the lever arm's angular acceleration jumps at the
#: ramp edges (central differences smear it over 0.1 ms); everything else agrees to rounding.
TOLERANCE = {"accel_scale_asymmetry": 2e-3, "gyro_scale_asymmetry": 2e-3, "confounded_asymmetry_vs_quadratic": 2e-3, "accel_lever_arm": 2e-3}


@pytest.mark.parametrize("name", [n for n, (k, e, _) in PROOF_SESSIONS.items()
                                  if k in ("single", "confounded") and set(e) & set(physical.EFFECTS)])
def test_physical_path_agrees_with_the_registry_formulas(base, name):
    sim, clean, temp = base
    eff = PROOF_SESSIONS[name][1]
    reg = build_calibration_simulator({**SHORT, "effects": eff}, 0).clean_increments()
    phy = physical.inject(sim, clean, effects.resolve(eff), temp)
    d_reg, d_phy = reg - clean, phy - clean
    size = np.abs(d_reg).max()
    assert size > 0
    err = np.abs(d_phy - d_reg).max() / size
    assert err <= TOLERANCE.get(name, 1e-5), (name, err)


def test_lever_arm_is_the_centripetal_acceleration_of_a_steady_turn(base):
    """During a steady table rotation at rate w the proof mass at r feels -w^2 r_perp (pointing at the axis):
    the numerically differentiated motion must give that closed form along each sensor axis."""
    sim, clean, temp = base
    r = np.array([[0.05, 0.0, 0.0], [0.0, 0.04, 0.0], [0.0, 0.0, 0.03]])
    phy = physical.inject(sim, clean, effects.resolve({"accel_lever_arm": {"lever_arms_m": r.tolist()}}), temp)
    dt = 1.0 / sim.sample_rate_hz
    extra_g = (phy[:, :3] - clean[:, :3]) / dt / sim.accel.K        # g, along the sensor axes
    t = (np.arange(sim.n_samples) + 0.5) * dt
    kin = sim.trajectory.kinematics(t, math.radians(sim.site.latitude_deg))
    lat = math.radians(sim.site.latitude_deg)
    edges = [sim.trajectory.kinematics(t + s * dt, lat) for s in (-0.5, 0.5)]
    steady = (np.linalg.norm(kin.w_nb_b, axis=1) > 0.1) & np.all(  # no ramp inside the sample
        [np.linalg.norm(k.dw_nb_b, axis=1) < 1e-12 for k in [kin] + edges], axis=0)
    steady[1:-1] &= steady[:-2] & steady[2:]   # and none in its neighbours: the difference step straddles edges
    assert steady.sum() > 1000
    w = kin.w_nb_b[steady]
    for i in range(3):
        ri = np.broadcast_to(r[i], w.shape)
        a = w * (w @ r[i])[:, None] - (w * w).sum(1)[:, None] * ri     # w x (w x r), written out
        expect = a @ sim.accel.E[i] / effects.STANDARD_GRAVITY
        # the body turns by w dt = 5 mrad within a sample: the mid-sample rotation leaves (w dt)^2 / 24 ~ 1e-6
        assert np.max(np.abs(extra_g[steady, i] - expect)) <= 3e-6 * np.max(np.abs(expect))


def test_time_offset_resamples_a_linear_ramp_exactly(base):
    """A stream whose cumulative output is a cubic polynomial in time is shifted exactly by the spline resampling."""
    sim = base[0]
    n, dt = 1000, 1.0 / sim.sample_rate_hz
    tb = np.arange(n + 1) * dt
    S = np.stack([2.0 * tb, 3.0 * tb ** 2, 0.5 * tb ** 3], axis=1)
    inc = np.diff(S, axis=0)
    out = physical._shift_stream(inc, dt, 0.0123)
    Sb = np.stack([2.0 * (tb + 0.0123), 3.0 * (tb + 0.0123) ** 2, 0.5 * (tb + 0.0123) ** 3], axis=1)
    assert np.allclose(out, np.diff(Sb, axis=0), rtol=0, atol=1e-9)   # not-a-knot ends: exact for a cubic


def test_unknown_effect_is_refused(base):
    sim, clean, temp = base
    with pytest.raises(ValueError, match="no physical model"):
        physical.inject(sim, clean, {"gravity_error": {"delta_g_m_s2": 1e-3}}, temp)


def test_injections_into_one_signal_share_its_inputs_and_only_that_signal(base):
    """The inputs recovered from a noise-free signal are kept for the next injection into the same signal (the
    Fisher bound's many): every injection equals one computed with nothing kept, bit for bit, and a signal changed
    in place, or another unit's, is never served the kept inputs."""
    sim, clean, temp = base
    eff = effects.resolve({"accel_quadratic_nonlinearity": {}, "gyro_g_sensitivity": {}})
    physical._BASE_INPUTS.clear()
    first = physical.inject(sim, clean, eff, temp)
    again = physical.inject(sim, clean, eff, temp)                   # served the kept inputs
    assert np.array_equal(first, again)
    changed = clean.copy()
    physical.inject(sim, changed, eff, temp)
    changed[100:200, 0] += 50.0                                     # the same array, other content
    got = physical.inject(sim, changed, eff, temp)
    physical._BASE_INPUTS.clear()
    assert np.array_equal(got, physical.inject(sim, changed, eff, temp))
    assert not np.array_equal(got, first)
    other = copy.deepcopy(sim)                                      # another unit: its accel scale factors differ
    other.accel.K = other.accel.K * 1.001
    physical.inject(sim, clean, eff, temp)
    got = physical.inject(other, clean, eff, temp)
    physical._BASE_INPUTS.clear()
    assert np.array_equal(got, physical.inject(other, clean, eff, temp))
