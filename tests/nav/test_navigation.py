"""Strapdown engine, streaming navigation of recordings and alignment (calib.nav.strapdown/navigation/alignment).

Truth comes from exact sensor increments (closed-form integrals of the body rate and specific force of a
stationary or turntable-mounted IMU, Earth rate and WGS-84 normal gravity included), from the linearised
error model integrated with a matrix exponential (calib.nav.errormodel), and from closed forms (Schuler,
Foucault, secular longitude rate, alignment equilibrium). Tolerances are stated in each test name/docstring.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.optimize

from calib.nav import alignment
from calib.core import earth
from calib.nav import errormodel
from calib.nav import navigation
from calib.io import recording
from calib.core import triad as sensors
from calib.nav import strapdown, strapdown_reference
from calib.io.netcdf import write_netcdf
from calib.io.recording import RecordingError
from calib.nav.strapdown import NavInit
from calib.core.rotations import axis_angle, dcm_to_rotvec, euler_to_dcm, rotvec_to_dcm

LAT = math.radians(30.58)  # He 2019 IV.A
H = 0.0
ATT = (0.02, -0.01, 0.7)  # pitch, roll, yaw [rad]: a non-trivial attitude so C_b^n enters everywhere
C0 = euler_to_dcm(*ATT)
G = float(earth.normal_gravity(LAT, H))
DEG_H = earth.DEG_PER_H


# ------------------------------------------------------------------------------------------------------
# exact increments
# ------------------------------------------------------------------------------------------------------
def stationary_rates(C=C0, lat=LAT, h=H):
    """True body rate omega_ib^b [rad/s] and specific force f^b [m/s^2] of an IMU at rest."""
    return C.T @ earth.earth_rate_enu(lat), C.T @ np.array([0.0, 0.0, float(earth.normal_gravity(lat, h))])


def turntable_increments(n, dt, axis, rate, C=C0, lat=LAT, i0=0):
    """Exact increments of an IMU turning at ``rate`` [rad/s] about the body ``axis`` (no lever arm).

    C_b^n(t) = C R_axis(rate t); omega_ib^b = rate axis + R(-rate t) C^T omega_ie^n, f^b = R(-rate t) C^T g_up.
    The integral of R(-w t) u is closed-form: u_par dt + (sin w t1 - sin w t0)/w u_perp + (cos w t1 - cos w t0)/w a x u.
    """
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t0 = (i0 + np.arange(n)) * dt
    t1 = t0 + dt

    def integ(u):
        up = a * (a @ u)
        return (up[None, :] * dt + ((np.sin(rate * t1) - np.sin(rate * t0)) / rate)[:, None] * (u - up)[None, :]
                + ((np.cos(rate * t1) - np.cos(rate * t0)) / rate)[:, None] * np.cross(a, u)[None, :])

    w_n = earth.earth_rate_enu(lat)
    g_up = np.array([0.0, 0.0, float(earth.normal_gravity(lat, 0.0))])
    return rate * a[None, :] * dt + integ(C.T @ w_n), integ(C.T @ g_up)


def turntable_attitude(t, axis, rate, C=C0):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return C @ axis_angle(a, rate * t)


def run_chunked(nav, dth_chunk, dv_chunk, n_total):
    """Feed the same chunk repeatedly (constant inputs) until n_total samples; returns (S, n_out, 9)."""
    outs, done = [], 0
    while done < n_total:
        k = min(len(dth_chunk), n_total - done)
        outs.append(nav.feed(dth_chunk[:k], dv_chunk[:k]))
        done += k
    return np.concatenate(outs, axis=1)


def engine_states(out, C=C0, lat=LAT, lon=0.0):
    """(n, 7) error states [phi_E, phi_N, phi_U, dvE, dvN, dL, dlambda] of output records (n, 9)."""
    phi = navigation.misalignment(out[:, 0], out[:, 1], out[:, 2], C)
    return np.column_stack([phi, out[:, 3], out[:, 4], out[:, 6] - lat, out[:, 7] - lon])


def model_states(t, drift=(0, 0, 0), bias=(0, 0, 0), C=C0):
    A = errormodel.system_matrix(LAT, C, H)
    z0 = np.zeros(13)
    z0[7:10], z0[10:13] = drift, bias
    return errormodel.transition(t, A, z0)[:, :7]


# ------------------------------------------------------------------------------------------------------
# engine: exactness, model agreement, closed forms
# ------------------------------------------------------------------------------------------------------
def test_perfect_sensors_stationary_24h_errors_at_rounding_level_1e9():
    """Perfect increments at rest, 100 Hz, 24 h, two-speed (10 Hz) and single-speed (100 Hz) paths.

    The algorithm is exact for a body fixed to the Earth (constant rates, no coning/sculling), so only
    rounding remains; bound: N u = 8.64e6 * 1.1e-16 ~ 1e-9 rad for attitude and latitude/longitude, and the
    velocity a 1e-9 rad tilt drives, g * 1e-9 / omega_s < 1e-5 m/s (asserted at 1e-6 m/s).
    """
    dt, chunk = 0.01, 1_000_000
    w_b, f_b = stationary_rates()
    dth, dv = np.tile(w_b * dt, (chunk, 1)), np.tile(f_b * dt, (chunk, 1))
    init = NavInit(lat=LAT, h=H, C_bn=C0)
    for n_sub in (10, 1):
        nav = navigation.StrapdownNavigator(init, dt, n_sub, out_every=6000 // n_sub)
        x = engine_states(run_chunked(nav, dth, dv, 24 * 360_000)[0])
        assert x.shape[0] == 1440
        assert np.abs(x[:, 0:3]).max() < 1e-9, n_sub
        assert np.abs(x[:, 3:5]).max() < 1e-6, n_sub
        assert np.abs(x[:, 5:7]).max() < 1e-9, n_sub


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_gyro_drift_follows_error_model_3h_within_1pct(axis):
    """0.01 deg/h on one body axis, latitude 30.58 deg, 100 Hz increments, 10 Hz two-speed navigation.

    Every error channel (phi_E, phi_N, phi_U, dvE, dvN, dL, dlambda and the Euler-angle errors) follows the
    linear error model (exact matrix exponential): max |difference| over [0, 3 h] <= 1 % of the channel's
    max |value|.
    """
    dt = 0.01
    eps = np.zeros(3)
    eps[axis] = 0.01 * DEG_H
    w_b, f_b = stationary_rates()
    n = 3 * 360_000
    dth, dv = np.tile((w_b + eps) * dt, (n, 1)), np.tile(f_b * dt, (n, 1))
    out, _, _ = strapdown.navigate_highrate(dth, dv, dt, 10, NavInit(lat=LAT, h=H, C_bn=C0), out_every=100)
    t = np.arange(1, len(out) + 1) * 10.0
    x = engine_states(out)
    m = model_states(t, drift=eps)
    for i, name in enumerate(errormodel.STATE_NAMES):
        assert np.abs(x[:, i] - m[:, i]).max() <= 0.01 * np.abs(m[:, i]).max(), name
    model = errormodel.error_response(t, LAT, eps, C_bn=C0, h=H)
    for i, name in enumerate(("pitch_err", "roll_err", "yaw_err")):
        eng = out[:, i] - ATT[i]
        ref = model[name].values
        assert np.abs(eng - ref).max() <= 0.01 * np.abs(ref).max(), name


def test_gyro_drift_240h_linear_part_within_2pct_and_remainder_second_order():
    """240 h at 10 Hz (nav-rate increments, 8.64 M steps), drift 0.01 deg/h on each body axis in turn.

    Streams with drift +eps and -eps navigate together. The odd part (x(eps) - x(-eps))/2 is the linear
    response: it follows the linear error model within 2 % of each channel's max over [0, 240 h]. The even
    part (x(eps) + x(-eps))/2 is the second-order response the linear model cannot have (mainly
    phi x C eps, which drives the 24-h mode at its own frequency and grows like t; 1-3 % of the channels at
    240 h): on the body z axis (the largest, ~3 %) two more streams at +-2 eps check that it scales as
    eps^2: even(2 eps) = 4 even(eps) within 5 % of its own max.
    """
    T, n_steps, chunk, oe = 0.1, 2_400 * 3600, 1_000_000, 600
    w_b, f_b = stationary_rates()
    base = (np.tile(w_b * T, (chunk, 1)), np.tile(f_b * T, (chunk, 1)))
    eps = 0.01 * DEG_H
    gb = []
    for axis, k in [(0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1), (2, 2), (2, -2)]:
        b = np.zeros(3)
        b[axis] = -k * eps  # the stream subtracts b: drift +k eps
        gb.append(b)
    state, outs, done = NavInit(lat=LAT, h=H, C_bn=C0), [], 0
    while done < n_steps:
        k = min(chunk, n_steps - done)
        o, state = strapdown.navigate_multi(base[0][:k], base[1][:k], T, state, np.array(gb), out_every=oe)
        outs.append(o)
        done += k
    out = np.concatenate(outs, axis=1)
    t = np.arange(1, out.shape[1] + 1) * oe * T
    x = [engine_states(o) for o in out]
    for axis in range(3):
        xp, xm = x[2 * axis], x[2 * axis + 1]
        drift = np.zeros(3)
        drift[axis] = eps
        m = model_states(t, drift=drift)
        odd = (xp - xm) / 2
        for i, name in enumerate(errormodel.STATE_NAMES):
            assert np.abs(odd[:, i] - m[:, i]).max() <= 0.02 * np.abs(m[:, i]).max(), (axis, name)
    even, even2 = (x[4] + x[5]) / 2, (x[6] + x[7]) / 2
    for i, name in enumerate(errormodel.STATE_NAMES):
        assert np.abs(even2[:, i] - 4 * even[:, i]).max() <= 0.05 * np.abs(even2[:, i]).max(), name


def _design(t, w, fixed):
    cols = [np.ones_like(t)]
    for wk in list(w) + list(fixed):
        cols += [np.cos(wk * t), np.sin(wk * t)]
    return np.column_stack(cols)


def _fit_residual(t, y, w, fixed):
    D = _design(t, w, fixed)
    coef, *_ = np.linalg.lstsq(D, y, rcond=None)
    return ((D @ coef - y) / np.abs(y).max(0)).ravel()


def _fit_frequency_pair(t, y, w_pk, fixed=()):
    """Least squares of y(t) (columns) on sinusoids at two free frequencies plus the ``fixed`` ones and a
    constant, amplitudes solved linearly inside (variable projection). Start: the best point of a coarse
    grid of (centre, half-split) around the spectral peak w_pk (centre +-6 %, half-split 0.2-8 %) on the
    series decimated 20x; refinement on the series decimated 2x (still > 10 samples per Schuler period)."""
    td, yd = t[::20], y[::20]
    best = None
    for c in w_pk * np.linspace(0.94, 1.06, 17):
        for d in w_pk * np.linspace(0.002, 0.08, 17):
            r = float(np.sum(_fit_residual(td, yd, (c - d, c + d), fixed) ** 2))
            if best is None or r < best[0]:
                best = (r, c - d, c + d)
    tr, yr = t[::2], y[::2]
    w = scipy.optimize.least_squares(lambda w: _fit_residual(tr, yr, w, fixed), best[1:], x_scale=1e-5,
                                     xtol=1e-14, ftol=1e-14).x
    return tuple(sorted(w))


def test_velocity_fit_recovers_foucault_split_and_schuler_frequency_0p2pct():
    """An accelerometer bias excites the Schuler loop; its Coriolis coupling splits omega_s into the pair
    sqrt(omega_s^2 + omega_F^2) +- omega_F (omega_F = W sin L). A fit of the engine's velocity errors over 48 h
    (start: a coarse grid around the strongest spectral peak) must give the half-difference within 2 % of
    W sin L and the mean within 0.2 % of sqrt(g/R) (R = sqrt(R_M R_N), calib.core.earth.schuler_frequency).
    """
    T, n = 0.1, 48 * 36_000
    w_b, f_b = stationary_rates()
    bias = C0.T @ np.array([2e-4, -1e-4, 0.0])  # m/s^2, 20 and -10 micro-g level biases
    out, _ = strapdown.navigate(np.tile(w_b * T, (n, 1)), np.tile((f_b + bias) * T, (n, 1)), T,
                                NavInit(lat=LAT, h=H, C_bn=C0), out_every=100)
    t = np.arange(1, len(out) + 1) * 10.0
    y = out[:, 3:5]
    spec = np.abs(np.fft.rfft(y[:, 0] * np.hanning(len(t)), 8 * len(t)))
    w_pk = 2 * np.pi * np.fft.rfftfreq(8 * len(t), 10.0)[np.argmax(spec[1:]) + 1]
    w1, w2 = _fit_frequency_pair(t, y, w_pk, fixed=(earth.OMEGA_IE,))
    w_f = earth.OMEGA_IE * math.sin(LAT)
    assert abs((w2 - w1) / 2 - w_f) <= 0.02 * w_f
    ws = earth.schuler_frequency(LAT, H)
    assert abs((w1 + w2) / 2 - ws) <= 0.002 * ws


def _secular_slope(t, y, freqs):
    cols = [np.ones_like(t), t] + [f(w * t) for w in freqs for f in (np.cos, np.sin)]
    coef, *_ = np.linalg.lstsq(np.column_stack(cols), y, rcond=None)
    return coef[1]


@pytest.mark.parametrize("enu_axis", [1, 2])
def test_longitude_error_grows_at_model_rate_for_north_and_up_drift_1pct(enu_axis):
    """A drift along ENU north (up) makes the longitude error grow at eps cos L (eps sin L), the drift
    component along the Earth's axis (steady state of the error model, errormodel.longitude_rate). The
    secular slope of the engine's dlambda over 72 h (fit: constant + slope + the three mode frequencies of
    the model) agrees within 1 %.
    """
    T, n = 0.1, 72 * 36_000
    e_n = np.zeros(3)
    e_n[enu_axis] = 0.01 * DEG_H
    eps = C0.T @ e_n
    w_b, f_b = stationary_rates()
    out, _ = strapdown.navigate(np.tile((w_b + eps) * T, (n, 1)), np.tile(f_b * T, (n, 1)), T,
                                NavInit(lat=LAT, h=H, C_bn=C0), out_every=100)
    t = np.arange(1, len(out) + 1) * 10.0
    slope = _secular_slope(t, out[:, 7], errormodel.mode_frequencies(LAT, H))
    rate = errormodel.longitude_rate(LAT, eps, C0)
    closed = 0.01 * DEG_H * (math.cos(LAT) if enu_axis == 1 else math.sin(LAT))
    assert rate == pytest.approx(closed, rel=1e-12)
    assert abs(slope - rate) <= 0.01 * abs(rate)


def test_accel_bias_schuler_oscillation_amplitude_matches_model_1pct():
    """An east accelerometer bias nabla_E: the east velocity error oscillates at the Schuler frequency with
    amplitude nabla_E / omega_s (first half period, where the Foucault beat and the Earth-rate mode change the
    envelope by < 0.5 %); the engine's peak matches the closed form within 1 % and the full model's peak
    within 0.5 %, and the model time series within 1 % over 6 h.
    """
    T, n = 0.1, 6 * 36_000
    w_b, f_b = stationary_rates()
    nab = 1e-4  # m/s^2, ~10 micro-g
    bias = C0.T @ np.array([nab, 0.0, 0.0])
    out, _ = strapdown.navigate(np.tile(w_b * T, (n, 1)), np.tile((f_b + bias) * T, (n, 1)), T,
                                NavInit(lat=LAT, h=H, C_bn=C0), out_every=10)
    t = np.arange(1, len(out) + 1) * 1.0
    ws = earth.schuler_frequency(LAT, H)
    first = t <= math.pi / ws
    peak = np.abs(out[first, 3]).max()
    assert abs(peak - nab / ws) <= 0.01 * nab / ws
    m = model_states(t, bias=bias)
    assert abs(peak - np.abs(m[first, 3]).max()) <= 0.005 * peak
    x = engine_states(out)
    for i, name in enumerate(errormodel.STATE_NAMES):
        assert np.abs(x[:, i] - m[:, i]).max() <= 0.01 * np.abs(m[:, i]).max(), name


# ------------------------------------------------------------------------------------------------------
# two-speed vs single-speed, compiled vs reference, multi-stream, streaming
# ------------------------------------------------------------------------------------------------------
AXIS = (1.0, 0.5, 1.0)  # tilted table axis (body frame)
RATE = math.radians(6.0)  # rad/s


def test_two_speed_matches_single_speed_and_truth_on_turntable_1h():
    """Turntable at 6 deg/s about a tilted body axis with Earth rate (the body rate vector cones at the
    table rate), 100 Hz exact increments, 1 h: 10 Hz two-speed and 100 Hz single-speed both follow the
    analytic truth and each other. Tolerances, set by what a sensor error 100x below the drift the project
    estimates would do in 1 h (1e-4 deg/h -> 1.7e-6 rad; 0.1 micro-g -> 3.5e-3 m/s): attitude 1e-8 rad,
    velocity 1e-5 m/s, latitude/longitude 1e-9 rad.
    """
    dt, n = 0.01, 360_000
    dth, dv = turntable_increments(n, dt, AXIS, RATE)
    init = NavInit(lat=LAT, h=H, C_bn=C0)
    o10, _, _ = strapdown.navigate_highrate(dth, dv, dt, 10, init, out_every=100)
    o1, _, _ = strapdown.navigate_highrate(dth, dv, dt, 1, init, out_every=1000)
    t = np.arange(1, len(o10) + 1) * 10.0
    Ct = np.array([turntable_attitude(tk, AXIS, RATE) for tk in t])
    phi = []
    for o in (o10, o1):
        Cc = navigation.euler_to_dcm_batch(o[:, 0], o[:, 1], o[:, 2])
        phi.append(np.array([dcm_to_rotvec(a @ b.T) for a, b in zip(Ct, Cc)]))
        assert np.abs(phi[-1]).max() < 1e-8
        assert np.abs(o[:, 3:5]).max() < 1e-5
        assert np.abs(o[:, 6] - LAT).max() < 1e-9 and np.abs(o[:, 7]).max() < 1e-9
    assert np.abs(phi[0] - phi[1]).max() < 1e-8
    assert np.abs(o10[:, 3:5] - o1[:, 3:5]).max() < 1e-5


def test_two_speed_matches_single_speed_stationary_1e12():
    """At rest the two paths differ only by rounding (N u = 3.6e5 * 1.1e-16 = 4e-11 for the 100 Hz path) and the
    third-order nav-frame rotation residual (W T)^2 g / 12 < 5e-11 m/s^2: attitude and position within 1e-10
    rad, velocity within the Schuler response to that tilt, g 1e-10 / omega_s ~ 8e-7 m/s (asserted 1e-6)."""
    dt, n = 0.01, 360_000
    w_b, f_b = stationary_rates()
    dth, dv = np.tile(w_b * dt, (n, 1)), np.tile(f_b * dt, (n, 1))
    init = NavInit(lat=LAT, h=H, C_bn=C0)
    o10, _, _ = strapdown.navigate_highrate(dth, dv, dt, 10, init, out_every=100)
    o1, _, _ = strapdown.navigate_highrate(dth, dv, dt, 1, init, out_every=1000)
    d = np.abs(o10 - o1).max(0)
    assert d[[0, 1, 2, 6, 7]].max() < 1e-10
    assert d[[3, 4]].max() < 1e-6


@pytest.mark.parametrize("n_sub", [10, 1])
def test_compiled_kernel_equals_reference_sample_for_sample_1e9(n_sub):
    """Compiled pre-integration and navigation vs the plain numpy reference (DCM, transforms.py) on the
    turntable plus a drift and a bias, every navigation step: angles, position within 1e-9 rad absolute
    (1e-9 relative for lat), velocities within 1e-9 relative to their scale (+1e-12 m/s)."""
    dt = 0.01
    dth, dv = turntable_increments(300 * n_sub, dt, AXIS, RATE)
    dth = dth + 0.3 * DEG_H * dt
    dv = dv + 2e-3 * dt
    Dth, Dv = strapdown.preintegrate(dth, dv, n_sub)
    Rth, Rv = strapdown_reference.preintegrate_reference(dth, dv, n_sub)
    assert np.allclose(Dth, Rth, rtol=1e-12, atol=1e-18) and np.allclose(Dv, Rv, rtol=1e-12, atol=1e-16)
    init = NavInit(lat=LAT, lon=0.3, h=120.0, C_bn=C0, vE=3.0, vN=-2.0)
    out, _ = strapdown.navigate(Dth, Dv, n_sub * dt, init)
    ref = strapdown_reference.navigate_reference(Dth, Dv, n_sub * dt, init)
    assert out.shape == ref.shape == (300, 9)
    ang = np.abs(out[:, [0, 1, 2, 7]] - ref[:, [0, 1, 2, 7]])
    ang[:, 2] = np.abs(navigation.wrap_pi(out[:, 2] - ref[:, 2]))
    assert ang.max() < 1e-9
    assert np.abs(out[:, 6] - ref[:, 6]).max() < 1e-9 * LAT
    vs = np.abs(ref[:, 3:5]).max()
    assert np.abs(out[:, 3:5] - ref[:, 3:5]).max() < 1e-9 * vs + 1e-12
    assert np.all(out[:, 8] == 120.0) and np.all(out[:, 5] == 0.0)  # vertical channel held


def test_multistream_equals_single_stream_with_bias_removed():
    """Stream s with gyro compensation b_s and accel compensation a_s == a single-stream run on the 100 Hz data
    with b_s dt, a_s dt removed before pre-integration. At rest: identical up to rounding (1e-12 rad, 1e-10
    m/s). On the turntable the shared coning/sculling terms miss (b dt) x (change of dtheta, dv within the
    interval): per step at most n^2/2 |b dt| w_table g dt^2 = 9e-12 m/s (n = 10, |b| = 0.035 deg/h, 6 deg/s),
    so over 6000 steps < 6e-8 m/s (asserted 1e-7 m/s) and attitude within 1e-10 rad. Also: parallel and
    serial give bit-identical results."""
    dt, n, n_sub = 0.01, 60_000, 10
    gb = np.array([[0.0, 0.0, 0.0], [0.02, -0.01, 0.03], [-0.03, 0.02, 0.0]]) * DEG_H
    ab = np.array([[0.0, 0.0, 0.0], [1e-3, -2e-3, 5e-4], [0.0, 0.0, -1e-3]])
    w_b, f_b = stationary_rates()
    cases = {"rest": (np.tile(w_b * dt, (n, 1)), np.tile(f_b * dt, (n, 1)), 1e-12, 1e-10),
             "turntable": (*turntable_increments(n, dt, AXIS, RATE), 1e-10, 1e-7)}
    init = NavInit(lat=LAT, h=H, C_bn=C0)
    for name, (dth, dv, tol_a, tol_v) in cases.items():
        Dth, Dv = strapdown.preintegrate(dth, dv, n_sub)
        multi, _ = strapdown.navigate_multi(Dth, Dv, n_sub * dt, init, gb, ab, out_every=60)
        serial, _ = strapdown.navigate_multi(Dth, Dv, n_sub * dt, init, gb, ab, out_every=60, parallel=False)
        assert np.array_equal(multi, serial)
        for s in range(len(gb)):
            D1, D2 = strapdown.preintegrate(dth - gb[s] * dt, dv - ab[s] * dt, n_sub)
            single, _ = strapdown.navigate(D1, D2, n_sub * dt, init, out_every=60)
            d = np.abs(multi[s] - single).max(0)
            assert d[[0, 1, 2, 6, 7]].max() < tol_a, (name, s)
            assert d[[3, 4]].max() < tol_v, (name, s)


def test_streaming_in_odd_chunks_is_bit_identical_to_one_pass():
    """State, pre-integration carry (an interval split across chunks) and output phase carried across chunks:
    chunk sizes not multiple of n_sub nor of the output interval give exactly the one-pass result, for the
    fused single stream and for the multi-stream path."""
    dt, n = 0.01, 20_000
    dth, dv = turntable_increments(n, dt, AXIS, RATE)
    init = NavInit(lat=LAT, h=H, C_bn=C0)
    whole, _, _ = strapdown.navigate_highrate(dth, dv, dt, 10, init, out_every=7)
    gb = np.array([[0.0, 0.0, 0.0], [1e-7, 0.0, -1e-7]])
    whole_m, _ = strapdown.navigate_multi(*strapdown.preintegrate(dth, dv, 10), 0.1, init, gb, out_every=7)
    for nav in (navigation.StrapdownNavigator(init, dt, 10, 7),
                navigation.StrapdownNavigator(init, dt, 10, 7, gyro_bias_rad_s=gb)):
        parts, i = [], 0
        for k in (1, 13, 999, 4567, 3, 10_000, n):
            parts.append(nav.feed(dth[i:i + k], dv[i:i + k]))
            i += k
            if i >= n:
                break
        got = np.concatenate(parts, axis=1)
        ref = whole[None] if nav.fused else whole_m
        assert np.array_equal(got, ref)


def test_vertical_channel_free_is_unstable_and_hold_keeps_height():
    """With a 1e-5 m/s^2 vertical accelerometer bias the free vertical channel diverges like
    exp(sqrt(2) omega_s t) (height error > 100 m after 2 h, closed form ~ nabla/(2 omega_s^2) (cosh - 1)
    ~ 2e2 m), the damped loop stays below 1 m and 'hold' keeps h and vU exactly."""
    T, n = 0.1, 2 * 36_000
    w_b, f_b = stationary_rates()
    bias = C0.T @ np.array([0.0, 0.0, 1e-5])
    Dth, Dv = np.tile(w_b * T, (n, 1)), np.tile((f_b + bias) * T, (n, 1))
    init = NavInit(lat=LAT, h=H, C_bn=C0)
    ws = earth.schuler_frequency(LAT, H)
    expect = 1e-5 / (2 * ws**2) * (math.cosh(math.sqrt(2) * ws * 7200) - 1)
    free, _ = strapdown.navigate(Dth, Dv, T, init, out_every=n, vertical="free")
    assert abs(free[-1, 8] - expect) < 0.05 * expect and expect > 100
    damped, _ = strapdown.navigate(Dth, Dv, T, init, out_every=100, vertical="damped")
    assert np.abs(damped[:, 8]).max() < 1.0
    held, _ = strapdown.navigate(Dth, Dv, T, init, out_every=100)
    assert np.all(held[:, 8] == H) and np.all(held[:, 5] == 0.0)


# ------------------------------------------------------------------------------------------------------
# alignment
# ------------------------------------------------------------------------------------------------------
def test_coarse_alignment_exact_on_perfect_data_and_equilibrium_with_biases():
    """Perfect data: the double-vector alignment returns C_b^n within 1e-12 rad. With level accelerometer
    biases and an east drift it returns the equilibrium phi_E = -nabla_N/g, phi_N = nabla_E/g,
    phi_U = (W sin L phi_N - eps_E)/(W cos L) within 1 % (first-order closed form)."""
    dt, n = 0.01, 30_000
    w_b, f_b = stationary_rates()
    C = alignment.coarse_align_increments(np.tile(w_b * dt, (n, 1)), np.tile(f_b * dt, (n, 1)), dt, LAT, H)
    assert np.abs(dcm_to_rotvec(C0 @ C.T)).max() < 1e-12
    eps = C0.T @ np.array([0.01 * DEG_H, 0.0, 0.0])
    nab = C0.T @ np.array([1e-3, -2e-3, 0.0])
    C = alignment.coarse_align_increments(np.tile((w_b + eps) * dt, (n, 1)), np.tile((f_b + nab) * dt, (n, 1)),
                                          dt, LAT, H)
    phi = dcm_to_rotvec(C0 @ C.T)
    g = G
    W = earth.OMEGA_IE
    expect = np.array([2e-3 / g, 1e-3 / g, (W * math.sin(LAT) * 1e-3 / g - 0.01 * DEG_H) / (W * math.cos(LAT))])
    assert np.allclose(phi, expect, rtol=0.01, atol=0)
    assert np.allclose(alignment.equilibrium_misalignment(LAT, C0, eps, nab, H), expect, rtol=1e-12)


def test_fine_alignment_converges_to_truth_from_a_wrong_start_1e9():
    """Perfect data, 10 min window, start 20 mrad off in heading and 1-2 mrad in tilt: the least-squares fine
    alignment returns the true attitude within 1e-9 rad and a north drift estimate below 1e-13 rad/s; with a
    north drift of 0.01 deg/h it estimates eps_N within 1 %."""
    dt, n = 0.01, 60_000
    w_b, f_b = stationary_rates()
    Dth, Dv = strapdown.preintegrate(np.tile(w_b * dt, (n, 1)), np.tile(f_b * dt, (n, 1)), 10)
    C_start = rotvec_to_dcm([1e-3, -2e-3, 2e-2]) @ C0
    C, info = alignment.fine_align(Dth, Dv, 0.1, LAT, H, C_start)
    assert np.abs(dcm_to_rotvec(C0 @ C.T)).max() < 1e-9
    assert abs(info["eps_N"]) < 1e-13
    e_n = 0.01 * DEG_H
    Dth2, Dv2 = strapdown.preintegrate(np.tile((w_b + C0.T @ [0.0, e_n, 0.0]) * dt, (n, 1)),
                                       np.tile(f_b * dt, (n, 1)), 10)
    C, info = alignment.fine_align(Dth2, Dv2, 0.1, LAT, H, C_start)
    assert abs(info["eps_N"] - e_n) < 0.01 * e_n
    assert np.abs(dcm_to_rotvec(C0 @ C.T)).max() < 1e-7


# ------------------------------------------------------------------------------------------------------
# recordings: navigate_recording, units, calibration, bad input
# ------------------------------------------------------------------------------------------------------
FS = 100.0


def _write(tmp_path, name, accel, gyro, accel_units, gyro_units, kind="increment", attrs=None, time=None,
           drop_latitude=False, unchecked=False):
    ds = recording.make_dataset(accel, gyro, sample_rate_hz=FS, latitude_deg=math.degrees(LAT), height_m=H,
                                accel_units=accel_units, gyro_units=gyro_units, accel_kind=kind, gyro_kind=kind,
                                time=time, extra_attrs=attrs)
    path = tmp_path / name
    if drop_latitude or unchecked:  # files the validating writer refuses
        if drop_latitude:
            del ds.attrs["latitude_deg"]
        write_netcdf(ds, path)
    else:
        recording.write(ds, path)
    return path


ATT_ATTRS = {"attitude_pitch_deg": math.degrees(ATT[0]), "attitude_roll_deg": math.degrees(ATT[1]),
             "attitude_yaw_deg": math.degrees(ATT[2])}


def test_navigate_recording_physical_units_perfect_data_errors_at_rounding_level(tmp_path):
    """30 min of perfect float64 increments (rad, m/s): initial attitude from the recording attributes, errors
    on a 1 s grid in seconds from t = 0, all at rounding level (1e-10 rad, 1e-7 m/s); units attributes set."""
    n = 180_000
    w_b, f_b = stationary_rates()
    path = _write(tmp_path, "phys.nc", np.tile(f_b / FS, (n, 1)), np.tile(w_b / FS, (n, 1)), "m s-1", "rad",
                  attrs=ATT_ATTRS)
    ds = navigation.navigate_recording(path, chunk=50_001)
    assert ds.sizes["time"] == 1801 and ds["time"].attrs["units"] == "s"
    assert ds["time"].values[-1] == pytest.approx(1800.0)
    for v in ("pitch_err", "roll_err", "yaw_err", "phi_E", "phi_N", "phi_U", "lat_err", "lon_err"):
        assert ds[v].attrs["units"] == "rad" and np.abs(ds[v].values).max() < 1e-10, v
    for v in ("vE_err", "vN_err"):
        assert ds[v].attrs["units"] == "m s-1" and np.abs(ds[v].values).max() < 1e-7, v
    assert ds["north_err_m"].attrs["units"] == "m"


def test_navigate_recording_counts_with_triad_calibration_and_gyro_compensation(tmp_path):
    """Counts (increment counts per sample, float) made with the Liu 2021 models N = K E x + b: a
    TriadCalibration of the same models recovers the physical increments (errors at rounding level); a 0.02
    deg/h drift added to the truth and compensated per stream gives stream 1 == perfect to 1e-9 rad."""
    n = 60_000
    dt = 1.0 / FS
    w_b, f_b = stationary_rates()
    drift = np.array([0.02, -0.01, 0.015]) * DEG_H
    am, gm = sensors.liu2021_model("accel"), sensors.liu2021_model("gyro")
    acc_counts = am.forward(f_b / earth.STANDARD_GRAVITY)[None, :].repeat(n, 0) * dt
    gyr_counts = gm.forward((w_b + drift) / DEG_H)[None, :].repeat(n, 0) * dt
    path = _write(tmp_path, "counts.nc", acc_counts, gyr_counts, "count", "count", attrs=ATT_ATTRS)
    cal = navigation.TriadCalibration(am, gm)
    ds = navigation.navigate_recording(path, calibration=cal, gyro_bias_rad_s=np.stack([np.zeros(3), drift]))
    assert ds.sizes["stream"] == 2
    assert np.abs(ds["yaw_err"].sel(stream=0).values).max() > 1e-6  # the drift is there ...
    for v in ("phi_E", "phi_N", "phi_U", "lat_err", "lon_err"):  # ... and compensated exactly
        assert np.abs(ds[v].sel(stream=1).values).max() < 1e-9, v
    with pytest.raises(RecordingError, match="no calibration"):
        navigation.navigate_recording(path)


def test_navigate_recording_bad_inputs_raise_clear_errors(tmp_path):
    """Missing latitude, physical units with a count calibration, a time gap, a navigation rate that does
    not divide the sample rate, an output interval off the navigation grid, no initial attitude: each raises
    an error naming the file/variable and the fix."""
    n = 2_000
    w_b, f_b = stationary_rates()
    acc, gyr = np.tile(f_b / FS, (n, 1)), np.tile(w_b / FS, (n, 1))
    p = _write(tmp_path, "nolat.nc", acc, gyr, "m s-1", "rad", drop_latitude=True)
    with pytest.raises(RecordingError, match="latitude_deg"):
        navigation.navigate_recording(p)
    p = _write(tmp_path, "ok.nc", acc, gyr, "m s-1", "rad", attrs=ATT_ATTRS)
    cal = navigation.TriadCalibration(sensors.liu2021_model("accel"), sensors.liu2021_model("gyro"))
    with pytest.raises(RecordingError, match="physical but a count calibration"):
        navigation.navigate_recording(p, calibration=cal)
    with pytest.raises(ValueError, match="does not divide"):
        navigation.navigate_recording(p, nav_rate_hz=30.0)
    with pytest.raises(ValueError, match="not a multiple of the navigation interval"):
        navigation.navigate_recording(p, output_interval_s=0.25)
    t = np.arange(n) / FS
    t[1000:] += 0.5  # half a second missing
    p = _write(tmp_path, "gap.nc", acc, gyr, "m s-1", "rad", attrs=ATT_ATTRS, time=t, unchecked=True)
    with pytest.raises(RecordingError, match="gap") as exc:
        navigation.navigate_recording(p)
    assert "samples 999 and 1000" in str(exc.value)
    p = _write(tmp_path, "noatt.nc", acc, gyr, "m s-1", "rad")
    with pytest.raises(RecordingError, match="init="):
        navigation.navigate_recording(p)


def test_navigate_recording_with_self_alignment_hides_east_drift_in_heading(tmp_path):
    """init='align' on a recording with an east drift of 0.01 deg/h and east and up accelerometer biases: the
    aligned start sits at the error-model equilibrium (heading error (W sin L phi_N - eps_E)/(W cos L), tilt
    phi_N = nabla_E/g, within 2 %), which is an exact rest point of the error equations for these errors, so
    over the first 30 min the velocity errors stay below 2e-4 m/s although the same errors from the true
    attitude give > 1e-2 m/s. (A north level bias has no rest point without a latitude offset: after
    alignment it still leaks through the Earth-rate coupling, W sin L nabla_N / g.)"""
    n = 180_000
    w_b, f_b = stationary_rates()
    eps = C0.T @ np.array([0.01 * DEG_H, 0.0, 0.0])
    nab = C0.T @ np.array([5e-4, 0.0, 3e-4])
    p = _write(tmp_path, "align.nc", np.tile((f_b + nab) / FS, (n, 1)), np.tile((w_b + eps) / FS, (n, 1)),
               "m s-1", "rad", attrs=ATT_ATTRS)
    aligned = navigation.navigate_recording(p, init="align", align_window_s=600.0)
    phi0 = np.array([aligned[f"phi_{c}"].values[0] for c in "ENU"])
    expect = alignment.equilibrium_misalignment(LAT, C0, eps, nab, H)
    assert np.abs(phi0 - expect).max() <= 0.02 * np.abs(expect).max()
    assert np.abs(aligned[["vE_err", "vN_err"]].to_array().values).max() < 2e-4
    true_start = navigation.navigate_recording(p)
    assert np.abs(true_start[["vE_err", "vN_err"]].to_array().values).max() > 1e-2
