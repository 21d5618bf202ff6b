"""The turntable calibration's result holds its estimate as the one triad model of calib.core.triad."""
from __future__ import annotations

import numpy as np

from calib.calibration.fit import CalibrationResult
from calib.core.triad import PARAM_NAMES, liu2021_model


def test_result_model_is_the_triad_model_of_its_estimate():
    truth = liu2021_model("gyro")
    res = CalibrationResult(sensor="gyro", method="separate", form="paper12", names=PARAM_NAMES,
                            x=truth.to_vector(), cov=np.zeros((12, 12)), KE=truth.KE, b=truth.b,
                            input_unit=truth.input_unit, output_unit=truth.output_unit, frame="body")
    m = res.model()
    np.testing.assert_array_equal(m.to_vector(), res.paper_vector())
    np.testing.assert_allclose(m.to_vector(), truth.to_vector(), rtol=1e-15)
    assert np.all(np.diag(m.E) == 1.0) and (m.input_unit, m.output_unit) == ("deg h-1", "count s-1")
    x = np.random.default_rng(0).normal(size=(20, 3))
    np.testing.assert_allclose(res.apply(truth.forward(x)), x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(m.inverse(truth.forward(x)), x, rtol=1e-9, atol=1e-9)
