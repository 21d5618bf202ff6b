"""One answer per file: ``fieldcal`` and ``diagnose`` use the same static intervals and the same minimum, and
each says the other's conclusion. Nine poses calibrate the nine-parameter accelerometer model exactly (no
redundancy): fieldcal says so and that diagnose will be inconclusive; diagnose, on the same intervals, is."""
from __future__ import annotations

import numpy as np

from calib.core.triad import MIN_POSES_TO_TEST, NORM_PARAMETERS
from calib.diagnosis import diagnose
from calib.fieldcal import fieldcal_recording
from calib.io import recording

from conftest import session


def _dataset(s):
    return recording.make_dataset(s["accel"], s["gyro"], sample_rate_hz=s["fs"], latitude_deg=45.0,
                                  accel_units="m s-2", gyro_units="rad s-1", gravity_m_s2=s["gravity"],
                                  source="recorded")


def test_nine_poses_fieldcal_and_diagnose_agree(tmp_path):
    assert MIN_POSES_TO_TEST == NORM_PARAMETERS + 1 == 10
    s = session(9, n_poses=9)
    path = recording.write(_dataset(s), tmp_path / "nine.nc")
    r = fieldcal_recording(path, {"gravity_m_s2": s["gravity"]})
    assert len(r.intervals) == 9
    notes = " | ".join(r.summary()["notes"])
    assert "no redundancy" in notes and "calib diagnose needs at least 10" in notes
    rep = diagnose(path, out_dir=None, intervals=np.asarray(r.intervals), intervals_source="the fieldcal")
    assert rep["verdict"] == "inconclusive"
    assert "only 9 static segments" in rep["verdict_reason"]
    assert "field calibration of the same file has no redundancy" in rep["verdict_reason"]


def test_enough_poses_both_go_ahead(tmp_path):
    s = session(3, n_poses=14)
    path = recording.write(_dataset(s), tmp_path / "fourteen.nc")
    r = fieldcal_recording(path, {"gravity_m_s2": s["gravity"]})
    assert len(r.intervals) == 14
    assert not any("no redundancy" in n for n in r.summary()["notes"])
    rep = diagnose(path, out_dir=None, intervals=np.asarray(r.intervals), intervals_source="the fieldcal")
    assert "static segments" not in rep.get("verdict_reason", "")
    assert rep["observations"]["static_segments"] == 14
