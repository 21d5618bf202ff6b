"""The triad error model N = K E x + b (Liu 2021 eqs. 1-4): its parameter vector and its matrix forms."""
import numpy as np
import pytest

from calib.core.triad import TriadModel, liu2021_model


def test_vector_round_trip_and_forward_inverse():
    m = liu2021_model("accel")
    m2 = TriadModel.from_vector(m.to_vector(), m.input_unit, m.output_unit)
    assert np.array_equal(m2.KE, m.KE) and np.array_equal(m2.b, m.b)
    x = np.random.default_rng(1).normal(size=(10, 3))
    np.testing.assert_allclose(m.inverse(m.forward(x)), x, rtol=1e-12, atol=1e-12)


def test_from_KE_splits_scale_and_unit_diagonal_misalignment():
    KE = np.array([[1.01, 0.002, -0.003], [0.001, 0.98, 0.004], [-0.002, 0.003, 1.02]])
    m = TriadModel.from_KE(KE, [0.1, -0.2, 0.3], "m s-2", "m s-2")
    assert np.allclose(np.diag(m.E), 1.0) and np.allclose(m.K, np.diag(KE))
    np.testing.assert_allclose(m.KE, KE, rtol=1e-15)
    with pytest.raises(ValueError, match="zero on its diagonal"):
        TriadModel.from_KE(np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, 1]]), np.zeros(3))
