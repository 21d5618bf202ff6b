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


MIKOFF = ("mikoff_imu0", "mikoff_imu1", "mikoff_imu2")


def _limits_ok(rep):
    """No reported finding beyond physical sense, no collapsed chi-square (the acceptance criteria of a real-recording proof base)."""
    from calib.diagnosis.selection import CHI2_COLLAPSE, PHYSICAL_LIMITS

    for f in rep["found"]:
        for p in f["parameters"]:
            lim = PHYSICAL_LIMITS.get(p["name"].split("[")[0])
            assert lim is None or abs(p["value"]) <= lim, (f["key"], p)
        if f["effect"] == "gravity_error":
            assert abs(f["parameters"][0]["value"]) <= 0.05
    g = rep["goodness_of_fit"]["after"]
    assert g["chi2"] >= CHI2_COLLAPSE * g["dof"]


@needs_real
@pytest.mark.parametrize("name", MIKOFF)
def test_large_quadratic_on_real_data_is_named_not_a_degenerate_gravity_error(name):
    """5000 ug/g^2 on the y accelerometer of a real MEMS recording: a free delta-g in the norm model trades with the
    scale factors and collapses the chi-square -- refused as degenerate, never the explanation; the quadratic is
    named, and its estimate minus the untouched recording's own k2 (the same fit with the term added: the report's
    absent[] entry) holds the injected value inside the 99 % interval. Same samples, same noise: the difference
    carries no noise of its own, so the estimate's standard error bounds it generously."""
    ds = import_real(ROOT / "config" / "import" / f"{name}.yaml")
    rep0, prob = dg.diagnose_dataset(ds, None, FAST, path=name)
    assert rep0["found"] == []                                   # the untouched recording names nothing
    own = {p["name"]: p["value"] for e in rep0["absent"] if e["effect"] == "accel_quadratic_nonlinearity"
           for p in e["upper_bound_95"]}
    rep, _ = dg.diagnose_dataset(inject_accel_term(ds, prob, "accel_quadratic_nonlinearity",
                                                   {"k2_ug_per_g2": [0.0, 5000.0, 0.0]}), None, FAST, path=name)
    assert "gravity_error" not in {f["effect"] for f in rep["found"]}
    assert any(d["key"] == "gravity_error" and "collapses" in d["why"] for d in rep["degenerate_candidates"])
    f = [x for x in rep["found"] if x["effect"] == "accel_quadratic_nonlinearity"]
    assert f, rep["verdict_reason"]
    y = [p for p in f[0]["parameters"] if p["axis"] == "y"][0]
    assert abs(y["value"] - own[y["name"]] - 5000.0) <= 2.576 * y["se"], (y, own)
    _limits_ok(rep)


@needs_real
@pytest.mark.parametrize("name", MIKOFF)
def test_bias_step_on_real_data_is_never_explained(name):
    """A 0.10 m/s^2 step of the x accelerometer bias mid-recording (outside the library; added to the samples
    directly, a path the diagnosis does not share) is never called explained: either misfit remains, or a
    library term that absorbs it does not beat a generic step/drift basis."""
    ds = import_real(ROOT / "config" / "import" / f"{name}.yaml")
    assert ds["accel"].attrs["units"] == "m s-2"
    y = np.asarray(ds["accel"].values, float).copy()
    y[len(y) // 2:, 0] += 0.10
    ds2 = ds.copy()
    ds2["accel"] = (ds["accel"].dims, y, ds["accel"].attrs)
    rep, _ = dg.diagnose_dataset(ds2, None, FAST, path=f"{name} + step")
    assert rep["explained"] is False and rep["verdict"] in ("unexplained", "inconclusive"), rep["verdict_reason"]
    _limits_ok(rep)
