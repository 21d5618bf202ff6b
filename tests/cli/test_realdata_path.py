"""The real-data path as a user walks it: one YAML holds the import settings and the field calibration's
section; diagnose tests the static intervals the field calibration used (one answer per file)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

from calib import cli

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
pytestmark = pytest.mark.skipif(not (DATA / "imu_tk_xsens").is_dir(), reason=f"shared recording {DATA} missing")


def test_one_yaml_imports_calibrates_and_diagnoses_on_the_same_intervals(tmp_path, capsys):
    s = yaml.safe_load((ROOT / "config" / "import" / "imu_tk_xsens.yaml").read_text())
    s["fieldcal"] = {"gravity_m_s2": 9.81744, "detection": {"rule": "imu_tk"}}
    settings = tmp_path / "xsens.yaml"
    settings.write_text(yaml.safe_dump(s))
    rec, fc, out = tmp_path / "rec.nc", tmp_path / "fc.nc", tmp_path / "diag"
    assert cli.main(["-q", "import", str(settings), str(rec)]) == 0          # the fieldcal section is accepted
    assert cli.main(["-q", "fieldcal", str(rec), "--settings", str(settings), "--out", str(fc)]) == 0
    capsys.readouterr()
    with xr.open_dataset(fc) as d:
        intervals = np.asarray(d["static_intervals"].values)
        assert d.attrs["detection_rule"].startswith("IMU-TK")                 # the section's rule was used
    code = cli.main(["-q", "diagnose", str(rec), "--out", str(out), "--fieldcal", str(fc)])
    assert code in (0, 1, 3)
    rep = json.loads((out / "report.json").read_text())
    assert rep["segments_from"] == f"the {len(intervals)} static intervals of {fc}"
    assert rep["observations"]["static_segments"] == len(intervals)
    assert json.loads(capsys.readouterr().out)["verdict"] == rep["verdict"]


def test_diagnose_refuses_a_file_that_is_not_a_field_calibration(tmp_path, capsys):
    rec = tmp_path / "x.nc"
    assert cli.main(["-q", "simulate", "calibration", str(rec)]) == 0
    code = cli.main(["diagnose", str(rec), "--out", str(tmp_path / "d"), "--fieldcal", str(rec)])
    err = capsys.readouterr().err
    assert code == 2 and "static_intervals" in err and "calib fieldcal" in err and "Traceback" not in err
