"""What a pose set does not determine (calib.fieldcal results' determination): marginal standard errors,
verdicts, parameters held at nominal, the no-redundancy line."""
import numpy as np
import pytest
from conftest import _rot, session

from calib.fieldcal import fieldcal_recording
from calib.fieldcal.results import marginal_standard_errors
from calib.io import recording

ACCEL_UNSEEN = ("mis_zy", "mis_zx", "gain_z", "bias_z")            # z never along gravity
GYRO_UNSEEN = ("mis_yz", "mis_xz", "mis_xy", "mis_yx", "gain_x", "gain_y")  # x and y never turned


def _run(s, **settings):
    ds = recording.make_dataset(s["accel"], s["gyro"], sample_rate_hz=s["fs"], latitude_deg=45.0,
                                accel_units="m s-2", gyro_units="rad s-1", gravity_m_s2=s["gravity"],
                                source="recorded")
    return fieldcal_recording(ds, {"gravity_m_s2": s["gravity"], **settings})


def test_marginal_standard_errors_closed_form():
    rng = np.random.default_rng(0)
    J = rng.standard_normal((50, 3)) * [1.0, 10.0, 0.1]
    se = marginal_standard_errors(J, 0.5)
    np.testing.assert_allclose(se, 0.5 * np.sqrt(np.diag(np.linalg.inv(J.T @ J))), rtol=1e-10)
    J[:, 2] = 2 * J[:, 0]  # a direction no observation sees
    se = marginal_standard_errors(J, 0.5)
    assert np.isinf(se[0]) and np.isinf(se[2]) and np.isfinite(se[1])


def test_full_pose_set_determines_everything():
    s = session(7)
    r = _run(s)
    for fit in (r.accel, r.gyro):
        assert not fit.determination.not_determined and not fit.determination.held
        assert fit.determination.condition > 1
    assert "accel_determination" in r.summary() and "gyro_determination" in r.summary()


def test_one_axis_never_turned():
    # body z horizontal, every turn about body z: gravity stays in the body x-y plane, gyro x and y never turn
    s = session(8, axes=[0, 0, 1], start=_rot([1, 0, 0], np.pi / 2))
    r = _run(s)
    da, dg = r.accel.determination, r.gyro.determination
    for name in ACCEL_UNSEEN:
        assert da.verdict(name) == "not determined", (name, da.as_dict())
    for name in ("mis_yz", "gain_x", "gain_y", "bias_x", "bias_y"):
        assert da.verdict(name) != "not determined", (name, da.as_dict())
    for name in GYRO_UNSEEN:
        assert dg.verdict(name) == "not determined", (name, dg.as_dict())
    assert dg.verdict("gain_z") == "determined"
    # held at nominal: misalignment 0, gain 1, bias 0 (physical units)
    assert set(da.held) == set(ACCEL_UNSEEN) and set(dg.held) == set(GYRO_UNSEEN)
    for name in ACCEL_UNSEEN:
        assert r.accel.param(name) == (1.0 if name.startswith("gain") else 0.0)
    for name in GYRO_UNSEEN:
        assert r.gyro.param(name) == (1.0 if name.startswith("gain") else 0.0)
    # what is determined is still right
    assert r.gyro.scale_factors[2] == pytest.approx(s["gyro_scale_factors"][2], abs=2e-4)
    np.testing.assert_allclose(r.accel.scale_factors[:2], s["accel_scale_factors"][:2], atol=2e-3)
    notes = " | ".join(r.summary()["notes"])
    assert "not determined" in notes and "held at nominal" in notes
    assert np.isnan(r.accel.std[r.accel.names.index("gain_z")])


def test_no_redundancy_is_said(caplog):
    s = session(9, n_poses=9)
    with caplog.at_level("WARNING", logger="calib.fieldcal"):
        r = _run(s)
    assert len(r.intervals) == 9
    assert any("no redundancy" in n for n in r.summary()["notes"])
    assert "no redundancy" in caplog.text
