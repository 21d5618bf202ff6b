"""Linearised stationary INS error model (calib.nav.errormodel) against closed forms.

Closed forms used: the characteristic polynomial of the stationary error equations for a spherical Earth,
(s^2 + W^2) [(s^2 + ws^2)^2 + 4 s^2 wF^2] s = 0 (ws^2 = g/R, wF = W sin L), its steady state (secular
longitude rate eps_N cos L + eps_U sin L, heading error -eps_E/(W cos L)), short-time Taylor expansions and
the exact Euler-angle perturbation. Tolerances in each test name/docstring.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from calib.core import earth
from calib.nav import errormodel
from calib.core.rotations import dcm_to_euler, euler_to_dcm, rotvec_to_dcm

LAT = math.radians(30.58)
C = euler_to_dcm(0.02, -0.01, 0.7)
EPS = 0.01 * earth.DEG_PER_H


def test_f_matrix_eigenvalues_match_closed_form_spherical_earth_1e9():
    """Spherical Earth (R_M = R_N = R): eigenvalues of F are 0, +-i W and +-i (sqrt(ws^2 + wF^2) +- wF),
    within 1e-9 relative."""
    R = 6.371e6
    g = float(earth.normal_gravity(LAT))
    F = errormodel.f_matrix(LAT, radius=R, gravity=g)
    ws2, wf, W = g / R, earth.OMEGA_IE * math.sin(LAT), earth.OMEGA_IE
    expect = sorted([W, math.sqrt(ws2 + wf**2) - wf, math.sqrt(ws2 + wf**2) + wf])
    ev = np.linalg.eigvals(F)
    assert np.abs(ev.real).max() < 1e-9 * W
    got = np.sort(ev.imag[ev.imag > 0])
    assert np.allclose(got, expect, rtol=1e-9)
    assert np.sum(np.abs(ev) < 1e-12) == 1  # the longitude integrator
    # WGS-84: the mean of the Schuler pair is sqrt(ws^2 + wF^2) with ws = earth.schuler_frequency within 0.01 %
    w = errormodel.mode_frequencies(LAT)
    ws = earth.schuler_frequency(LAT)
    assert abs((w[1] + w[2]) / 2 - math.sqrt(ws**2 + wf**2)) < 1e-4 * ws


def test_transition_uniform_grid_equals_direct_expm_1e9():
    """Blocked propagation on a uniform grid == expm(A t) z0 evaluated directly, over 240 h at 1-min steps,
    within 1e-9 of each channel's max (14400 products: rounding grows like k u |Phi|, ~1e-10 at the end)."""
    A = errormodel.system_matrix(LAT, C)
    z0 = np.zeros(13)
    z0[7:10] = [EPS, -EPS, 2 * EPS]
    z0[10:13] = [1e-4, 2e-4, -1e-4]
    t = np.arange(0, 240 * 3600 + 1, 60.0)
    X = errormodel.transition(t, A, z0, block=97)
    scale = np.abs(X).max(0)
    for k in (0, 1, 96, 97, 98, 5000, len(t) - 1):
        ref = scipy.linalg.expm(A * t[k]) @ z0
        assert np.all(np.abs(X[k] - ref) <= 1e-9 * scale), k
    # non-uniform times take the direct path
    tn = np.array([0.0, 10.0, 1000.0, 86400.0])
    ref = np.array([scipy.linalg.expm(A * tk) @ z0 for tk in tn])
    assert np.allclose(errormodel.transition(tn, A, z0), ref, rtol=1e-12, atol=0)


def test_sensitivity_is_the_linear_map_of_error_response_1e12():
    """error_response(drift, bias) == sensitivity @ [drift, bias] to 1e-12 relative; columns add up."""
    t = np.arange(0, 3 * 3600 + 1, 10.0)
    S = errormodel.sensitivity(t, LAT, C)
    u = np.array([EPS, -0.5 * EPS, 2 * EPS, 1e-4, -3e-4, 2e-4])
    ds = errormodel.error_response(t, LAT, u[:3], u[3:], C)
    X = np.column_stack([ds[n].values for n in errormodel.STATE_NAMES])
    Y = S @ u
    assert np.allclose(X, Y, rtol=1e-12, atol=1e-12 * np.abs(Y).max(0))
    assert ds["time"].attrs["units"] == "h" and ds["vE_err"].attrs["units"] == "m s-1"


def test_short_time_taylor_expansion_1e3():
    """For t << 1/W: a drift makes phi^n grow like -C eps t and the velocity error like f x phi ~ g t^2/2; an
    accelerometer bias makes dv grow like C nabla t. Checked at t = 2 s (W t ~ 1e-4) within 1e-3 relative."""
    t = np.array([0.0, 2.0])
    e_n = C @ np.array([EPS, 2 * EPS, -EPS])
    ds = errormodel.error_response(t, LAT, np.array([EPS, 2 * EPS, -EPS]), C_bn=C)
    phi = np.array([ds[f"phi_{c}"].values[1] for c in "ENU"])
    assert np.allclose(phi, -e_n * 2.0, rtol=1e-3)
    g = float(earth.normal_gravity(LAT))
    # dvE' = -g phi_N, dvN' = g phi_E with phi = -e t  ->  dvE = g e_N t^2/2, dvN = -g e_E t^2/2
    assert ds["vE_err"].values[1] == pytest.approx(g * e_n[1] * 2.0, rel=1e-3)
    assert ds["vN_err"].values[1] == pytest.approx(-g * e_n[0] * 2.0, rel=1e-3)
    nab = np.array([1e-4, -2e-4, 3e-4])
    ds = errormodel.error_response(t, LAT, accel_bias_body=nab, C_bn=C)
    a_n = C @ nab
    assert ds["vE_err"].values[1] == pytest.approx(a_n[0] * 2.0, rel=1e-3)
    assert ds["vN_err"].values[1] == pytest.approx(a_n[1] * 2.0, rel=1e-3)


def test_steady_state_longitude_rate_and_heading_error_closed_forms_1e9():
    """Steady state of F x + G u = 0 with the longitude as free integrator: d(lambda)/dt = eps_N cos L +
    eps_U sin L (errormodel.longitude_rate) and phi_U = (W sin L phi_N - eps_E)/(W cos L) with
    phi_N = nabla_E / g, within 1e-9 relative (F from WGS-84 radii)."""
    u = np.array([EPS, -2 * EPS, 1.5 * EPS, 2e-4, 0.0, 0.0])
    A = errormodel.system_matrix(LAT, np.eye(3))
    F, G = A[:7, :7], A[:7, 7:]
    # unknowns: the six bounded states and the longitude rate; F[:, :6] x + G u = -e_lambda * rate
    M = np.column_stack([F[:, :6], np.eye(7)[:, 6] * -1.0])
    sol = np.linalg.solve(M, -G @ u)
    rate = sol[6]
    assert rate == pytest.approx(-2 * EPS * math.cos(LAT) + 1.5 * EPS * math.sin(LAT), rel=1e-9)
    assert rate == pytest.approx(errormodel.longitude_rate(LAT, u[:3]), rel=1e-12)
    g = float(earth.normal_gravity(LAT))
    W = earth.OMEGA_IE
    assert sol[1] == pytest.approx(2e-4 / g, rel=1e-9)
    assert sol[2] == pytest.approx((W * math.sin(LAT) * 2e-4 / g - EPS) / (W * math.cos(LAT)), rel=1e-9)


def test_longitude_error_of_model_grows_at_longitude_rate_over_240h_1e4():
    """The integrated model's dlambda(t)/t tends to longitude_rate: slope of a fit (constant, slope, the
    three mode frequencies) over 240 h within 1e-4 relative."""
    t = np.arange(0, 240 * 3600 + 1, 60.0)
    drift = C.T @ np.array([0.0, EPS, EPS])
    dl = errormodel.error_response(t, LAT, drift, C_bn=C)["lon_err"].values
    cols = [np.ones_like(t), t] + [f(w * t) for w in errormodel.mode_frequencies(LAT) for f in (np.cos, np.sin)]
    coef, *_ = np.linalg.lstsq(np.column_stack(cols), dl, rcond=None)
    assert coef[1] == pytest.approx(errormodel.longitude_rate(LAT, drift, C), rel=1e-4)


@pytest.mark.parametrize("att", [(0.0, 0.0, 0.0), (0.02, -0.01, 0.7), (-0.3, 0.4, -2.0)])
def test_phi_to_euler_error_matches_exact_small_rotation_1e5(att):
    """d(pitch, roll, yaw) of C_computed = exp(-[phi x]) C_true vs the linear map, phi ~ 1e-6 rad, within
    1e-5 relative (second order)."""
    Ct = euler_to_dcm(*att)
    phi = np.array([1.0, -2.0, 1.5]) * 1e-6
    Cc = rotvec_to_dcm(-phi) @ Ct
    exact = np.array(dcm_to_euler(Cc)) - np.array(dcm_to_euler(Ct))
    lin = errormodel.phi_to_euler_error(phi, *att)
    assert np.allclose(lin, exact, rtol=1e-5, atol=1e-5 * np.abs(exact).max())


def test_drift_coupling_term_is_bilinear_and_off_by_default():
    """drift_coupling adds -[C eps x] to the phi block only; without it the response is linear (doubling the
    drift doubles every channel to 1e-12) and with it it is not."""
    A0 = errormodel.system_matrix(LAT, C)
    d = np.array([EPS, 0.0, 0.0])
    A1 = errormodel.system_matrix(LAT, C, drift_coupling=d)
    diff = A1 - A0
    assert np.allclose(diff[0:3, 0:3], -np.array([[0, -(C @ d)[2], (C @ d)[1]], [(C @ d)[2], 0, -(C @ d)[0]],
                                                  [-(C @ d)[1], (C @ d)[0], 0]]))
    assert np.count_nonzero(diff[3:, :]) == 0 and np.count_nonzero(diff[:, 3:]) == 0
    t = np.arange(0, 48 * 3600 + 1, 600.0)
    r1 = errormodel.error_response(t, LAT, d, C_bn=C)["phi_U"].values
    r2 = errormodel.error_response(t, LAT, 2 * d, C_bn=C)["phi_U"].values
    assert np.allclose(r2, 2 * r1, rtol=1e-12, atol=1e-20)
    c1 = errormodel.error_response(t, LAT, d, C_bn=C, drift_coupling=True)["phi_U"].values
    c2 = errormodel.error_response(t, LAT, 2 * d, C_bn=C, drift_coupling=True)["phi_U"].values
    assert np.abs(c2 - 2 * c1).max() > 1e-6 * np.abs(c1).max()
