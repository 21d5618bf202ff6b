"""``calib diagnose`` freezes the objects of the libraries it imports (gc.freeze) so that the cyclic garbage
collector does not walk them again and again; afterwards the collector is as the command found it: enabled (or
not, as the caller had it), nothing left frozen -- for a finished diagnosis and for a refused input alike -- so a
process that goes on running (a test session, a notebook) collects its own garbage as before."""
from __future__ import annotations

import gc
import json

import numpy as np

from calib import cli
from calib.io import recording
from calib.sim.calibration_session import simulate_calibration_session

SHORT_SESSION = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}


def test_the_collector_is_left_as_found(tmp_path, capsys):
    rec = simulate_calibration_session(SHORT_SESSION, 5, tmp_path / "s.nc")
    nofig = tmp_path / "nofig.json"
    nofig.write_text(json.dumps({"figures": False}))
    assert gc.isenabled() and gc.get_freeze_count() == 0
    assert cli.main(["diagnose", str(rec), "--out", str(tmp_path / "fig")]) in (0, 1, 3)
    assert sorted(p.name for p in (tmp_path / "fig").glob("*.png")) == ["allan_deviation.png",
                                                                         "residuals_before_after.png"]
    assert gc.isenabled() and gc.get_freeze_count() == 0
    assert cli.main(["diagnose", str(rec), "--out", str(tmp_path / "nofig"), "--settings", str(nofig)]) in (0, 1, 3)
    assert gc.isenabled() and gc.get_freeze_count() == 0
    # a collector switched off by the caller stays off
    gc.disable()
    try:
        assert cli.main(["diagnose", str(rec), "--out", str(tmp_path / "off"), "--settings", str(nofig)]) in (0, 1, 3)
        assert not gc.isenabled() and gc.get_freeze_count() == 0
    finally:
        gc.enable()
    capsys.readouterr()


def test_a_refused_recording_leaves_nothing_frozen(tmp_path, capsys):
    rec = simulate_calibration_session(SHORT_SESSION, 6, tmp_path / "s.nc")
    ds = recording.load(rec)
    acc = np.asarray(ds["accel"].values, dtype=float)
    acc[100, 0] = np.nan                                         # a non-finite sample: refused, exit 2
    ds["accel"] = (ds["accel"].dims, acc, ds["accel"].attrs)
    bad = tmp_path / "bad.nc"
    ds.to_netcdf(bad)
    assert cli.main(["diagnose", str(bad), "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out" / "report.json").exists()
    assert gc.isenabled() and gc.get_freeze_count() == 0
    capsys.readouterr()
