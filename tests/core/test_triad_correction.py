"""The one correction of a triad (calib.core.triad.TriadCorrection) inverts the forward model N = K E x + b of
calib.core.triad (Liu 2021 eqs. 1-4), for rate and increment samples, and every user of it (the turntable
calibration's result, the field calibration's fit and result, the navigation's calibration, the exported
calibration of ``calib apply``, the import's declared scale and sign) gives the forward model's inverse."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calib.calibration.fit import CalibrationResult
from calib.core.earth import STANDARD_GRAVITY
from calib.core.triad import PARAM_NAMES, TriadCorrection, TriadModel, liu2021_model
from calib.fieldcal.results import FieldCalResult, TriadFit
from calib.ingest.common import apply_triad
from calib.io.export_formats import Calibration, TriadCal
from calib.nav.navigation import TriadCalibration

DEG_H = math.pi / 180.0 / 3600.0   # rad s-1 per deg h-1
DT = 0.01                          # sample interval [s]

# K = diag(2, 4, 5), E unit lower triangular with E_yx = 0.5: K E and its inverse in closed form
K = np.array([2.0, 4.0, 5.0])
E = np.array([[1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]])
KE_INV = np.array([[0.5, 0.0, 0.0], [-0.25, 0.25, 0.0], [0.0, 0.0, 0.2]])
B = np.array([1.0, -2.0, 3.0])
X = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.25, 0.5, -2.0], [3.0, -4.0, 8.0]])
# the forward model written out: N = K E x + b
N_CLOSED = np.array([[2.0 * x + 1.0, 2.0 * x + 4.0 * y - 2.0, 5.0 * z + 3.0] for x, y, z in X])
G = np.array([[0.1, 0.3, 0.6], [-1.3, 0.0, 0.8], [-0.7, -0.8, 0.2]])   # N per m s-2


def closed_model(input_unit="g", output_unit="count s-1"):
    return TriadModel(K.copy(), E.copy(), B.copy(), input_unit, output_unit)


def test_forward_model_is_the_closed_form():
    np.testing.assert_array_equal(closed_model().forward(X), N_CLOSED)


@pytest.mark.parametrize("kind", ["rate", "increment"])
def test_correction_inverts_the_forward_model_in_closed_form(kind):
    c = TriadCorrection.from_model(closed_model(), "accel")
    np.testing.assert_allclose(c.matrix, KE_INV, rtol=1e-15, atol=1e-16)
    np.testing.assert_array_equal(c.bias, B)
    raw = N_CLOSED * DT if kind == "increment" else N_CLOSED
    np.testing.assert_allclose(c.apply(raw, sample_kind=kind, dt=DT), X, rtol=1e-14, atol=1e-14)
    assert (c.reading_unit, c.output_unit) == ("count s-1", "g")


@pytest.mark.parametrize("kind", ["rate", "increment"])
def test_unit_factors_scale_the_output_and_the_reading(kind):
    """x in m s-2 (s = g0) from readings in 1/8 count s-1 (N = 8 r): A = s (K E)^-1 8, beta = b / 8."""
    c = TriadCorrection.from_model(closed_model(), "accel", output_unit="m s-2", output_factor=STANDARD_GRAVITY,
                                   reading_factor=8.0, reading_unit="eighth count s-1")
    np.testing.assert_allclose(c.matrix, STANDARD_GRAVITY * 8.0 * KE_INV, rtol=1e-15, atol=1e-15)
    np.testing.assert_array_equal(c.bias, B / 8.0)
    r = N_CLOSED / 8.0
    raw = r * DT if kind == "increment" else r
    np.testing.assert_allclose(c.apply(raw, sample_kind=kind, dt=DT), STANDARD_GRAVITY * X, rtol=1e-14,
                               atol=1e-13)
    # the same through the raw-sample factor instead of the folded one
    c2 = TriadCorrection("accel", STANDARD_GRAVITY * KE_INV, B, "count s-1", "m s-2", factor=8.0)
    np.testing.assert_allclose(c2.apply(raw, sample_kind=kind, dt=DT), STANDARD_GRAVITY * X, rtol=1e-14,
                               atol=1e-13)


@pytest.mark.parametrize("sensor", ["accel", "gyro"])
@pytest.mark.parametrize("kind", ["rate", "increment"])
def test_liu2021_parameters_round_trip(sensor, kind):
    m = liu2021_model(sensor)
    x = np.random.default_rng(3).normal(size=(50, 3)) * (1.0 if sensor == "accel" else 15.0)
    n = m.forward(x)
    c = TriadCorrection.from_vector(m.to_vector(), sensor, m.input_unit)
    raw = n * DT if kind == "increment" else n
    np.testing.assert_allclose(c.apply(raw, sample_kind=kind, dt=DT), x, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(c.apply(raw, sample_kind=kind, dt=DT), m.inverse(n), rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(c.model().to_vector(), m.to_vector(), rtol=1e-12)


def test_g_sensitive_gyro_needs_the_specific_force():
    """N_g = K E w + b + G a: the correction removes G a of the calibrated specific force a."""
    a = np.random.default_rng(4).normal(size=(len(X), 3)) * 9.8
    n = N_CLOSED + a @ G.T
    c = TriadCorrection.from_model(closed_model("rad s-1", "count s-1"), "gyro", g_sensitivity=G)
    np.testing.assert_allclose(c.apply(n, accel=a), X, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="g-sensitive"):
        c.apply(n)


def test_a_correction_without_matrix_keeps_each_axis_on_its_own():
    f = np.array([-2.0, 1.0, 0.5])
    raw = np.array([[1.0, 2.0, 4.0], [np.nan, -3.0, 8.0]])
    out = TriadCorrection("accel", None, None, "m s-2", "m s-2", factor=f).apply(raw)
    np.testing.assert_array_equal(out, [[-2.0, 2.0, 2.0], [np.nan, -3.0, 4.0]])


def test_bad_sample_kind_and_missing_dt_are_refused():
    c = TriadCorrection.from_model(closed_model(), "accel")
    with pytest.raises(ValueError, match="need dt"):
        c.apply(N_CLOSED, sample_kind="increment")
    with pytest.raises(ValueError, match="sample_kind"):
        c.apply(N_CLOSED, sample_kind="counts")


# ----------------------------------------------------------------------------- every user: the same inverse


@pytest.mark.parametrize("kind", ["rate", "increment"])
def test_turntable_result_applies_the_inverse(kind):
    m = closed_model()
    res = CalibrationResult(sensor="accel", method="separate", form="paper12", names=PARAM_NAMES,
                            x=m.to_vector(), cov=np.zeros((12, 12)), KE=m.KE, b=m.b, input_unit="g",
                            output_unit="count s-1", frame="body")
    raw = N_CLOSED * DT if kind == "increment" else N_CLOSED
    np.testing.assert_allclose(res.apply(raw, sample_kind=kind, dt=DT), X, rtol=1e-14, atol=1e-14)


def _fit(sensor, kind, factor, G=None):
    """A field calibration fit of the closed-form model: x [SI] = s (K E)^-1 (factor raw [/ dt] - b - G a)."""
    s = STANDARD_GRAVITY if sensor == "accel" else DEG_H
    return TriadFit(sensor=sensor, method="test", names=(), values=np.zeros(0), covariance=np.zeros((0, 0)),
                    param_units=(), matrix=s * KE_INV, bias=B.copy(), input_units="count", input_factor=factor,
                    input_kind=kind, dt=DT, output_units="m s-2" if sensor == "accel" else "rad s-1",
                    scale_factors=np.ones(3), scale_factor_std=np.zeros(3), scale_factor_units="",
                    residual_rms=0.0, residual_units="", n_residuals=0, identifiability=None, g_sensitivity=G)


@pytest.mark.parametrize("kind", ["rate", "increment"])
def test_field_calibration_applies_the_inverse(kind):
    factor = 4.0   # raw samples in quarter counts
    a_si = STANDARD_GRAVITY * X
    n_g = N_CLOSED + a_si @ G.T        # gyro counts: input X in deg h-1, plus G a
    to_raw = (lambda n: n * DT / factor) if kind == "increment" else (lambda n: n / factor)
    fa, fg = _fit("accel", kind, factor), _fit("gyro", kind, factor, G)
    np.testing.assert_allclose(fa.apply(to_raw(N_CLOSED)), a_si, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(fg.apply(to_raw(n_g), a_si), X * DEG_H, rtol=1e-12, atol=1e-18)
    res = FieldCalResult(method="test", accel=fa, gyro=fg, frame="body", gravity_m_s2=STANDARD_GRAVITY,
                         intervals=np.zeros((0, 2)), detection_rule="", source="", sensor="", metrics={},
                         notes=[], settings={})
    a, w = res.apply(to_raw(N_CLOSED), to_raw(n_g))
    np.testing.assert_allclose(a, a_si, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(w, X * DEG_H, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(fa.model().KE, closed_model().KE / STANDARD_GRAVITY, rtol=1e-14)


def test_navigation_calibration_applies_the_inverse_in_si():
    cal = TriadCalibration(closed_model("g"), closed_model("deg h-1"))
    np.testing.assert_allclose(cal.apply_accel(N_CLOSED), STANDARD_GRAVITY * X, rtol=1e-14, atol=1e-13)
    np.testing.assert_allclose(cal.apply_gyro(N_CLOSED), DEG_H * X, rtol=1e-14, atol=1e-20)


def test_exported_calibration_applies_the_inverse():
    """``calib apply``'s form: rate readings r with N = f r (f = 2), gyro N_g = K E w + b + G a."""
    f = 2.0
    a_si = STANDARD_GRAVITY * X
    cal = Calibration(TriadCal("accel", closed_model("g"), f, "half count s-1", (("count", "rate"),)),
                      TriadCal("gyro", closed_model("deg h-1"), f, "half count s-1", (("count", "rate"),), G),
                      "test", "test")
    a, w = cal.apply(N_CLOSED / f, (N_CLOSED + a_si @ G.T) / f)
    np.testing.assert_allclose(a, a_si, rtol=1e-14, atol=1e-13)
    np.testing.assert_allclose(w, DEG_H * X, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(cal.gyro.G_rate, G / f, rtol=1e-15)


def test_import_applies_the_declared_sign_and_scale():
    tri = {"units": "m s-2", "kind": "rate", "factor": np.array([-1.0, 2.0, 1.0]) * 0.5}
    raw = np.array([[2.0, 3.0, -4.0]])
    np.testing.assert_array_equal(apply_triad(raw, tri), [[-1.0, 3.0, -2.0]])
