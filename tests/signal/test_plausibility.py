"""The limits of calib.signal.plausibility on known values, and the error hierarchy it raises."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calib.core import earth
from calib.core.errors import CalibError, InputError, ResultCheckError
from calib.io.recording import RecordingError
from calib.signal import plausibility as pl


def test_error_hierarchy_and_exit_codes():
    assert issubclass(RecordingError, InputError) and issubclass(RecordingError, ValueError)
    assert InputError("x").exit_code == 2 and ResultCheckError("x").exit_code == 3
    e = CalibError("what", file="f.nc", field="accel", fix="do this")
    assert str(e) == "f.nc: accel: what (fix: do this)"
    r = RecordingError("f.nc", "time", "a gap", "split it")
    assert (r.file, r.field, r.fix, r.exit_code) == ("f.nc", "variable 'time'", "split it", 2)
    assert str(r) == "f.nc: variable 'time': a gap -- fix: split it"


@pytest.mark.parametrize("scale, bias, counts, problem", [
    ([1.0, 1.01, 0.99], [0.3, -0.2, 0.1], False, None),               # a MEMS accelerometer
    ([0.4, 1.0, 1.0], [0.0, 0.0, 0.0], False, "scale factor x = 0.4 outside [0.5, 2]"),
    ([1.0, 1.0, 1.0], [0.0, 2.5, 0.0], False, "accel bias 2.5 m s-2 above 2 m s-2"),
    ([414.5, 412.0, 414.6], None, True, None),                          # IMU-TK's Xsens, counts per m s-2
    ([414.5, 412.0, 1300.0], None, True, "differ by more than a factor 2"),
    ([np.nan, 1.0, 1.0], None, False, "not finite"),
])
def test_accelerometer_result_limits(scale, bias, counts, problem):
    out = pl.check_triad_result("accel", scale, bias, counts=counts)
    assert (out == []) if problem is None else any(problem in p for p in out), out


def test_gyro_bias_limit_in_deg_s():
    mems = np.radians([1.3, -0.4, 0.9])          # the MPU-9150 recordings reach 1.3 deg/s: plausible
    assert pl.check_triad_result("gyro", [1.0, 1.0, 1.0], mems, counts=False) == []
    wrong = np.radians([1.3, -0.4, 0.9]) * 180.0 / math.pi   # the same numbers read as rad/s
    assert any("gyro bias 74.48 deg/s above 10 deg/s" in p for p in
               pl.check_triad_result("gyro", [1.0, 1.0, 1.0], wrong, counts=False))


def test_earth_rate_constant():
    assert pl.EARTH_RATE_DEG_H == pytest.approx(15.041, abs=1e-3)
    assert pl.ACCEL_BIAS_MAX_M_S2 == pytest.approx(0.2 * earth.STANDARD_GRAVITY, rel=0.02)
