"""The diagnosis on the shared real recordings (../shared/data): the injection test, and the static intervals
of the field calibration."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib import diagnosis as dg
from calib.ingest import importers
from calib.io import recording
from calib.signal import detect
from calib.studies.diagnosis_real import import_real, inject_accel_term

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT.parent / "shared" / "data"
FAST = {"figures": False}
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"shared real-data directory {REAL} is missing")


@needs_real
def test_injected_quadratic_found_on_top_of_the_real_xsens_data():
    """A known quadratic nonlinearity added to the real IMU-TK Xsens session (in the sensor model its own norm
    calibration identifies) is named, and the difference between the estimates with and without it brackets
    the injected value in its 95 % interval."""
    ds = import_real(ROOT / "config" / "import" / "imu_tk_xsens.yaml")
    rep0, prob = dg.diagnose_dataset(ds, None, FAST, path="xsens")
    assert rep0["model"] == "norm"
    inj = {"k2_ug_per_g2": [4000.0, -3000.0, 2500.0]}
    rep1, _ = dg.diagnose_dataset(inject_accel_term(ds, prob, "accel_quadratic_nonlinearity", inj), None, FAST,
                                  path="xsens + quadratic")
    f = [x for x in rep1["found"] if x["effect"] == "accel_quadratic_nonlinearity"]
    assert f, rep1["verdict_reason"]
    base = {p["name"]: p["value"] for e in rep0["found"] + rep0["absent"] if e["effect"] == f[0]["effect"]
            for p in (e.get("parameters") or e.get("upper_bound_95", []))}
    for p, truth in zip(f[0]["parameters"], inj["k2_ug_per_g2"]):
        d = p["value"] - base.get(p["name"], 0.0)
        half = 0.5 * (p["ci95"][1] - p["ci95"][0])
        assert abs(d - truth) <= half, (p["name"], d, truth, half)


@needs_real
def test_given_static_intervals_are_the_ones_diagnosed(tmp_path):
    """diagnose_recording on an imported recording without a segment table uses the intervals it is given
    (those of the field calibration), and too few of them give 'inconclusive' saying how many are needed."""
    ds = importers.import_dataset(importers.load_settings(ROOT / "config" / "import" / "mikoff_imu0.yaml"))
    path = recording.write(ds, tmp_path / "imu0.nc")
    iv = np.asarray(detect.detect_in_recording(ds).intervals)
    assert len(iv) >= 14
    rep = dg.diagnose_recording(path, tmp_path / "a", FAST, intervals=iv[:14], intervals_source="test")
    assert rep["observations"]["static_segments"] == 14
    rep = dg.diagnose_recording(path, tmp_path / "b", FAST, intervals=iv[:5])
    assert rep["verdict"] == "inconclusive" and "only 5 static segments" in rep["verdict_reason"]
    assert "at least 10" in rep["verdict_reason"]
