"""What the diagnosis refuses (verdict 'inconclusive' with the reason, never a finding), and its report files
through the command line ``calib diagnose``."""
from __future__ import annotations

import json

import numpy as np

from calib import cli
from calib import diagnosis as dg
from calib.io import recording
from calib.sim import effects
from calib.sim.calibration_session import simulate_calibration_session

SHORT = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}
FAST = {"figures": False}


def test_too_few_segments_is_inconclusive(tmp_path):
    cfg = {**SHORT, "positions_per_phase": 1, "step_deg": 90.0}
    path = simulate_calibration_session(cfg, 1, tmp_path / "few.nc")
    rep = dg.diagnose_recording(path, tmp_path / "out", FAST)
    assert rep["verdict"] == "inconclusive"
    assert "static segments" in rep["verdict_reason"]
    assert rep["found"] == []
    assert (tmp_path / "out" / "report.json").exists() and (tmp_path / "out" / "report.md").exists()


def test_too_short_is_inconclusive(tmp_path):
    cfg = {**SHORT, "dwell_s": 1.0, "rotation_rates_deg_s": [], "transition_s": [0.5, 0.2], "move_rate_deg_s": 90.0}
    path = simulate_calibration_session(cfg, 1, tmp_path / "short.nc")
    rep = dg.diagnose_recording(path, tmp_path / "out", FAST)
    assert rep["verdict"] == "inconclusive"
    assert "lasts" in rep["verdict_reason"] or "static" in rep["verdict_reason"]
    assert rep["found"] == []


def test_flat_data_missing_sigma_is_inconclusive(tmp_path):
    path = simulate_calibration_session({**SHORT, "conceal": True}, 1, tmp_path / "s.nc")
    ds = recording.load(path)
    ds["accel"] = (ds["accel"].dims, np.full(ds["accel"].shape, 1000, dtype=np.int32), ds["accel"].attrs)
    rep, _ = dg.diagnose_dataset(ds, tmp_path, FAST, path="flat")
    assert rep["verdict"] == "inconclusive"
    assert rep["found"] == []
    assert json.loads((tmp_path / "report.json").read_text())["verdict"] == "inconclusive"


def test_unreadable_file_is_inconclusive(tmp_path):
    bad = tmp_path / "bad.nc"
    bad.write_text("not netcdf")
    rep = dg.diagnose_recording(bad, tmp_path / "out", FAST)
    assert rep["verdict"] == "inconclusive"
    assert "cannot read" in rep["verdict_reason"]
    # the entry point on a path without an output directory: the same refusal, nothing written
    rep2 = dg.diagnose(bad, FAST)
    assert rep2["verdict"] == "inconclusive" and "cannot read" in rep2["verdict_reason"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.nc", "out"]


def test_report_files_and_cli(tmp_path, noise_record):
    path = simulate_calibration_session(
        {**SHORT, "effects": {"accel_scale_asymmetry": {"asym_ppm": [150.0, -120.0, 90.0]}}, "conceal": True}, 8,
        tmp_path / "a.nc")
    settings = tmp_path / "settings.json"
    settings.write_text(json.dumps({"figures": True}))
    code = cli.main(["diagnose", str(path), "--out", str(tmp_path / "out"), "--settings", str(settings),
                     "--noise-record", noise_record])
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert code == 1 and rep["verdict"] == "missing_physics" and rep["explained"] is True
    assert "accel_scale_asymmetry" in {f["effect"] for f in rep["found"]}
    md = (tmp_path / "out" / "report.md").read_text()
    assert "accel_scale_asymmetry" in md and "Untestable" in md
    assert (tmp_path / "out" / "residuals_before_after.png").stat().st_size > 0
    for eid in effects.REGISTRY:        # every library id appears verbatim in the report
        assert eid in json.dumps(rep)


def test_cli_settings_override_reaches_the_report(tmp_path):
    """A settings file's value is the one the report records; an unreadable input exits with 2 and writes no
    report."""
    bad = tmp_path / "bad.nc"
    bad.write_text("not netcdf")
    settings = tmp_path / "s.yaml"
    settings.write_text("alpha: 0.0001\nfigures: false\n")
    code = cli.main(["diagnose", str(bad), "--out", str(tmp_path / "refused"), "--settings", str(settings)])
    assert code == 2 and not (tmp_path / "refused").exists()
    path = simulate_calibration_session(SHORT, 1, tmp_path / "s.nc")
    code = cli.main(["diagnose", str(path), "--out", str(tmp_path / "out"), "--settings", str(settings)])
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert code in (0, 1, 3) and rep["settings"]["alpha"] == 0.0001 and rep["settings"]["figures"] is False
