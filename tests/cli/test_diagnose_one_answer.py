"""One answer per file: ``calib diagnose`` runs what ``calib fieldcal`` runs before any verdict (its unit, rate and
plausibility checks and its default static detection), a refused input writes no report, a single absurd sample
is refused before ``calibrate``'s fit, and the messages name only numbers that were computed.

The shared real recordings (../shared/data, mikoff_mpu9150: InvenSense MPU-9150, rad/s, no segment table) give the
two answers to compare; the synthetic ones are made here."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import yaml

from calib import cli
from calib.fieldcal import default_detection
from calib.io import recording
from calib.sim.calibration_session import simulate_calibration_session

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
IMPORT = ROOT / "config" / "import"
SMALL_CONFIG = ROOT / ".test" / "config.yaml"
SHORT_SESSION = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}
shared = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared real-data directory {DATA} missing")


def run(capsys, *argv):
    """``calib ARGV`` in-process: (exit code, standard output, standard error)."""
    code = cli.main(["-q", *[str(a) for a in argv]])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


def imported(tmp_path, capsys, monkeypatch, name, change=None):
    """The shared recording of import settings ``name`` imported into ``tmp_path`` (``change``: edits the settings
    first, as a user's copy); returns (recording, settings file)."""
    s = yaml.safe_load((IMPORT / f"{name}.yaml").read_text())
    if change:
        change(s)
    settings = tmp_path / f"{name}.yaml"
    settings.write_text(yaml.safe_dump(s))
    monkeypatch.chdir(IMPORT)   # the settings' data paths are relative to the shared data folder
    rec = tmp_path / f"{name}.nc"
    code, _, err = run(capsys, "import", settings, rec)
    assert code == 0, err
    return rec, settings


@shared
def test_diagnose_refuses_the_units_mistake_fieldcal_refuses_and_writes_nothing(tmp_path, capsys, monkeypatch):
    """The gyro's rad/s declared as deg/s: calib fieldcal refuses (exit 2, the fix named); calib diagnose gives the
    same refusal (it called the file 'adequate', exit 0) and writes no report."""
    rec, _ = imported(tmp_path, capsys, monkeypatch, "mikoff_imu0",
                      lambda s: s["gyro"].update(units="deg s-1"))
    code_f, _, err_f = run(capsys, "fieldcal", rec)
    assert code_f == 2 and "gyro.units" in err_f and "declare gyro.units: 'rad s-1'" in err_f, err_f
    out = tmp_path / "diag"
    code_d, stdout, err_d = run(capsys, "diagnose", rec, "--out", out)
    assert code_d == 2 and stdout == "", err_d
    assert err_d.split("error: ", 1)[1] == err_f.split("error: ", 1)[1]   # the same refusal, word for word
    assert not out.exists()


@shared
@pytest.mark.parametrize("name", ["mikoff_imu0", "mikoff_imu2"])
def test_diagnose_tests_the_static_intervals_fieldcal_finds(tmp_path, capsys, monkeypatch, name):
    """A recording without a segment table (hand-held poses): calib diagnose tests the static intervals the default
    detection of calib fieldcal finds on the same file -- the same number, named as their source -- not those of a
    detection of its own."""
    rec, _ = imported(tmp_path, capsys, monkeypatch, name)
    res = tmp_path / "fc.nc"
    code, summary, err = run(capsys, "fieldcal", rec, "--out", res)
    assert code == 0, err
    n = json.loads(summary)["n_static_intervals"]
    out = tmp_path / "diag"
    code, _, err = run(capsys, "diagnose", rec, "--out", out)
    assert code in (0, 1, 3), err
    rep = json.loads((out / "report.json").read_text())
    assert rep["segments_from"].startswith(f"the {n} static intervals of calib fieldcal's default static detection")
    # the same intervals as the result file's: diagnosing on them explicitly gives the same report
    out2 = tmp_path / "diag2"
    code2, _, err = run(capsys, "diagnose", rec, "--out", out2, "--fieldcal", res)
    rep2 = json.loads((out2 / "report.json").read_text())
    assert code2 == code and rep2["verdict"] == rep["verdict"]
    assert rep2["observations"] == rep["observations"] and rep2["goodness_of_fit"] == rep["goodness_of_fit"]


@shared
def test_an_import_settings_rate_other_than_the_recording_s_is_refused(tmp_path, capsys, monkeypatch):
    """calib fieldcal --settings with an import-settings file: its sample_rate_hz (1200) against the recording's
    declared 100 Hz is refused with both rates and the fix, not silently ignored; the same rate passes."""
    rec, settings = imported(tmp_path, capsys, monkeypatch, "mikoff_imu1")
    s = yaml.safe_load(settings.read_text())
    s["sample_rate_hz"] = 1200
    other = tmp_path / "other_rate.yaml"
    other.write_text(yaml.safe_dump(s))
    code, stdout, err = run(capsys, "fieldcal", rec, "--settings", other)
    assert code == 2 and stdout == ""
    assert "sample_rate_hz" in err and "1200 Hz" in err and "100 Hz" in err and "re-import" in err, err
    code, _, err = run(capsys, "fieldcal", rec, "--settings", settings)
    assert code == 0, err


def test_a_refused_recording_gets_no_report(tmp_path, capsys):
    """A NaN at one sample: calib diagnose exits 2 naming the sample and writes neither report.json nor report.md
    (nor its folder); an earlier report in the folder stays as it was."""
    rec = simulate_calibration_session(SHORT_SESSION, 8, tmp_path / "s.nc")
    ds = recording.load(rec)
    ds["accel"] = (ds["accel"].dims, ds["accel"].values.astype(np.float64), ds["accel"].attrs)
    del ds.attrs["_path"]
    bad = recording.write(ds, tmp_path / "nan.nc")
    with netCDF4.Dataset(bad, "a") as nc:   # (the writer refuses a NaN: set afterwards, as a logger would leave it)
        nc["accel"][321, 2] = np.nan
    out = tmp_path / "diag"
    code, stdout, err = run(capsys, "diagnose", bad, "--out", out)
    assert code == 2 and stdout == "" and "sample 321" in err, err
    assert not out.exists()
    out.mkdir()
    (out / "report.md").write_text("earlier report\n")
    code, _, err = run(capsys, "diagnose", bad, "--out", out)
    assert code == 2 and sorted(p.name for p in out.iterdir()) == ["report.md"]
    assert (out / "report.md").read_text() == "earlier report\n"


def test_a_single_absurd_count_sample_is_refused_before_calibrate_s_fit(tmp_path, capsys):
    """One accelerometer sample of 1e30 counts in a calibration session: validate and calibrate refuse it (exit 2)
    by its index before any fit, and calibrate writes nothing; the same file without it passes validate."""
    rec = simulate_calibration_session(SHORT_SESSION, 8, tmp_path / "s.nc")
    ds = recording.load(rec)
    acc = ds["accel"].values.astype(np.float64)
    acc[4321, 1] = 1e30
    ds["accel"] = (ds["accel"].dims, acc, ds["accel"].attrs)
    del ds.attrs["_path"]
    bad = recording.write(ds, tmp_path / "spike.nc")
    code, _, err = run(capsys, "validate", rec)
    assert code == 0, err
    code, _, err = run(capsys, "validate", bad)
    assert code == 2 and "accel: sample 4321:" in err and "spike" in err, err
    out = tmp_path / "cal"
    code, stdout, err2 = run(capsys, "calibrate", bad, "--out", out, "--quick", "--config", SMALL_CONFIG)
    assert code == 2 and stdout == "" and "accel: sample 4321:" in err2, err2
    assert not out.exists()


def _candidate(n_intervals):
    iv = np.array([[1000 * i, 1000 * i + 500] for i in range(n_intervals)])
    return default_detection.Candidate("detect", {"rule": "detect", "window_s": 0.5, "k": 10.0, "min_interval_s": 1.0},
                                       iv, None)


def test_the_no_choice_message_names_only_poses_that_were_counted():
    """Distinct poses are counted on a candidate's accel fit, which needs enough intervals to run: a best candidate
    of 4 intervals was never fitted, so the message says its poses were not counted (it said '0 distinct
    poses')."""
    cands = [_candidate(4), _candidate(2)]
    acc = np.tile([0.0, 0.0, 9.81], (5000, 1))
    ranking = default_detection.rank(cands, acc, 9.81, need=12, accel_counts=False, min_poses=9)
    assert all(c.residual is None for c in cands)   # neither was fitted: no pose was counted
    msg = str(default_detection.no_choice_error(cands, "rec.nc", ranking, default_detection.Protocol()))
    assert "with 4 intervals, distinct poses not counted" in msg, msg
    assert not re.search(r"\b0 distinct poses", msg), msg
    assert "finds 9 distinct static poses, the fewest the 9-parameter accelerometer model needs" in msg


def test_the_no_choice_message_does_not_call_fewer_than_9_poses_enough_for_9_parameters():
    """The gravity norm gives one equation per distinct pose, so the 9-parameter accelerometer model needs 9: with
    fieldcal.min_intervals 3 the message says the settings asked for 3, not that 3 is the fewest the model needs."""
    cands = [_candidate(2)]
    acc = np.tile([0.0, 0.0, 9.81], (5000, 1))
    ranking = default_detection.rank(cands, acc, 9.81, need=12, accel_counts=False, min_poses=3)
    msg = str(default_detection.no_choice_error(cands, "rec.nc", ranking, default_detection.Protocol()))
    assert "3 distinct static poses, the fewest" not in msg, msg
    assert "finds 3 distinct static poses, as fieldcal.min_intervals asks" in msg
    assert "the 9-parameter accelerometer model needs 9" in msg


@pytest.mark.skipif(shutil.which("snakemake", path=str(Path(sys.executable).parent)) is None,
                    reason="the workflow extra (snakemake) is not installed")
@pytest.mark.parametrize("fieldcal, calibrated", [(None, True), ({"gravity_m_s2": 9.81}, True), (False, False)])
def test_a_real_recording_study_calibrates_unless_told_not_to(tmp_path, fieldcal, calibrated):
    """A real-recording study config without a fieldcal: key runs the field calibration with its default settings
    (and the diagnosis then tests its intervals); only fieldcal: false skips it. Snakemake's dry run lists the
    jobs."""
    rec = {"import": str(IMPORT / "mikoff_imu0.yaml")}
    if fieldcal is not None:
        rec["fieldcal"] = fieldcal
    cfg = tmp_path / "study.yaml"
    cfg.write_text(yaml.safe_dump({"results": str(tmp_path / "results"), "recording": rec,
                                   "seeds": {"data": 1, "calibration": 1000, "drift": 2000}}))
    out = subprocess.run([str(Path(sys.executable).parent / "snakemake"), "-n", "--nolock", "--quiet", "rules",
                          "--configfile", str(cfg)], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    jobs = {line.split()[0] for line in out.stdout.splitlines() if re.match(r"^[a-z_]+\s+\d+$", line.strip())}
    assert "diagnose" in jobs and ("fieldcal" in jobs) == calibrated, out.stdout
