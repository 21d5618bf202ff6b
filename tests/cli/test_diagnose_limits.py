"""``calib diagnose FILE --limits`` on shared recordings: the detection limits land in report.json and report.md,
a recording with too few poses says "not detectable at any magnitude" with the experiment, and a bad
``--limits-reps`` is refused by argparse (exit 2)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from calib import cli

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT.parent / "shared" / "data"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"shared real-data directory {REAL} is missing")


@needs_real
def test_limits_of_a_recording_with_too_few_poses(tmp_path, capsys):
    rec = tmp_path / "adis.nc"
    assert cli.main(["import", str(ROOT / "config" / "import" / "imucal_ferraris_A.yaml"), str(rec)]) == 0
    code = cli.main(["diagnose", str(rec), "--out", str(tmp_path / "out"), "--limits", "--limits-reps", "2"])
    assert code == 3                                   # inconclusive: 6 static segments cannot test anything
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    rows = rep["detection_limits"]["rows"]
    assert {r["effect"] for r in rows} >= {"accel_quadratic_nonlinearity", "accel_cubic_nonlinearity",
                                           "accel_scale_asymmetry"}
    assert all(r["limit"] is None and r["why"] for r in rows)
    assert all(r.get("experiment") for r in rows if r["kind"] == "library")
    md = (tmp_path / "out" / "report.md").read_text()
    assert "not detectable at any magnitude" in md and "Traceback" not in capsys.readouterr().err


def test_limits_reps_below_two_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["diagnose", str(tmp_path / "x.nc"), "--out", str(tmp_path), "--limits", "--limits-reps", "1"])
    assert e.value.code == 2
    assert "at least 2 repetitions" in capsys.readouterr().err
