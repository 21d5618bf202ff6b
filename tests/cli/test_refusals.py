"""What the command line refuses, and how: each case asserts the exit code (2 bad input, 3 implausible result),
that the message names the file / field / likely mistake, and that nothing is left behind -- no partial or
hidden temporary file, no earlier output replaced.

The recordings come from the simulator at small sizes: a 36 s stationary session (physical increments,
He 2019's navigation-grade unit, rewritten here in the units under test) and the short Liu 2021 calibration
session (counts)."""
from __future__ import annotations

import collections
import errno
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from calib import cli
from calib.cli.shared import check_recording
from calib.core import earth
from calib.io import chunked_reading, in_memory, recording, validation
from calib.io.netcdf import write_netcdf
from calib.signal import plausibility
from calib.sim.calibration_session import simulate_calibration_session
from calib.sim.static_session import simulate_static_session

ROOT = Path(__file__).resolve().parents[2]
SMALL_CONFIG = ROOT / ".test" / "config.yaml"
SITE = {"latitude_deg": 30.58, "height_m": 0.0}
SHORT_SESSION = {"site": SITE, "dwell_s": 20.0, "revolutions": 1}
FS = 100.0


# --------------------------------------------------------------------------- helpers


def run(capsys, *argv):
    """``calib ARGV`` in-process: (exit code, stderr)."""
    code = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def leftovers(folder):
    """Hidden or partial files left in ``folder`` (recursively)."""
    return sorted(str(p) for p in Path(folder).rglob("*") if p.name.startswith(".") or p.name.endswith(".part"))


@pytest.fixture(scope="module")
def static_rates(tmp_path_factory):
    """A 36 s stationary session from the simulator as rates: accel [m s-2], gyro [rad s-1] (Earth rate seen)."""
    path = tmp_path_factory.mktemp("sim") / "static.nc"
    simulate_static_session({"mode": "physical", "duration_h": 0.01, "site": SITE,
                             "attitude_deg": {"pitch": 10.0, "roll": -5.0, "yaw": 30.0}}, 7, path)
    ds = recording.load(path)
    return ds["accel"].values * FS, ds["gyro"].values * FS


@pytest.fixture(scope="module")
def count_session(tmp_path_factory):
    """The short Liu 2021 calibration session (counts, segment table)."""
    return simulate_calibration_session(SHORT_SESSION, 8, tmp_path_factory.mktemp("cal") / "session.nc")


def physical(folder, name, accel, gyro, accel_units="m s-2", gyro_units="rad s-1", accel_kind="rate",
             gyro_kind="rate", time=None, validated=True, encoding=None):
    ds = recording.make_dataset(accel, gyro, sample_rate_hz=FS, latitude_deg=SITE["latitude_deg"],
                                accel_units=accel_units, gyro_units=gyro_units, accel_kind=accel_kind,
                                gyro_kind=gyro_kind, time=time)
    for var, enc in (encoding or {}).items():
        ds[var].encoding.update(enc)
    path = Path(folder) / name
    if validated:
        return recording.write(ds, path)
    return write_netcdf(ds, path)


# --------------------------------------------------------------------------- physical plausibility (exit 2)


@pytest.mark.parametrize("case, expected", [
    ("m_s2_as_g", "data in m s-2 declared as 'g'"),
    ("g_as_m_s2", "data in g declared as 'm s-2'"),
    ("rate_as_increment", "rates (m s-2) declared as sample_kind 'increment'"),
    ("counts_as_m_s2", "raw counts declared as a physical unit"),
    ("m_s2_as_counts", "physical data (m s-2) declared as counts"),
    ("rad_s_as_deg_s", "data in rad/s declared as degrees"),
    ("deg_s_as_rad_s", "data in degrees declared as radians"),
])
def test_units_mistake_is_named(tmp_path, capsys, static_rates, case, expected):
    acc, gyr = static_rates
    kw = {}
    if case == "m_s2_as_g":
        kw = dict(accel_units="g")
    elif case == "g_as_m_s2":
        acc = acc / earth.STANDARD_GRAVITY
    elif case == "rate_as_increment":
        kw = dict(accel_units="m s-1", accel_kind="increment", gyro_units="rad", gyro_kind="increment")
        gyr = gyr / FS
    elif case == "counts_as_m_s2":
        acc = np.round(acc / earth.STANDARD_GRAVITY * 13942.0)    # Liu 2021's unit: ~13942 count s-1 per g
    elif case == "m_s2_as_counts":
        kw = dict(accel_units="count")
    elif case == "rad_s_as_deg_s":
        kw = dict(gyro_units="deg s-1")
    elif case == "deg_s_as_rad_s":                                 # a MEMS-like 0.5 deg/s bias, in deg/s
        gyr = np.degrees(gyr) + np.array([0.5, -0.3, 0.2])
    path = physical(tmp_path, "r.nc", acc, gyr, **kw)
    code, err = run(capsys, "validate", path)
    assert code == 2
    assert f"calib validate: error: {path}: " in err and expected in err
    assert leftovers(tmp_path) == []


def test_the_same_data_in_the_right_units_pass(tmp_path, capsys, static_rates):
    acc, gyr = static_rates
    for name, kw, a, g in (("si.nc", {}, acc, gyr),
                           ("g.nc", dict(accel_units="g", gyro_units="deg s-1"), acc / earth.STANDARD_GRAVITY,
                            np.degrees(gyr)),
                           ("inc.nc", dict(accel_units="m s-1", accel_kind="increment", gyro_units="rad",
                                           gyro_kind="increment"), acc / FS, gyr / FS)):
        code, err = run(capsys, "validate", physical(tmp_path, name, a, g, **kw))
        assert code == 0, err


def test_single_absurd_sample_is_named_by_index(tmp_path, capsys, static_rates):
    acc, gyr = static_rates
    acc = acc.copy()
    acc[123] = [0.0, 0.0, 2000.0 * earth.STANDARD_GRAVITY]
    code, err = run(capsys, "validate", physical(tmp_path, "spike.nc", acc, gyr))
    assert code == 2 and "sample 123" in err and "exceeds 1000 g" in err


def test_force_turns_a_plausibility_refusal_into_a_warning(tmp_path, capsys, static_rates):
    acc, gyr = static_rates
    path = physical(tmp_path, "r.nc", acc, gyr, accel_units="g")
    code, err = run(capsys, "validate", path, "--force")
    assert code == 0 and "warning:" in err and "declared as 'g'" in err


# --------------------------------------------------------------------------- time coordinate, masked samples (exit 2)


def test_time_gap_is_refused_with_index_time_and_size(tmp_path, capsys, static_rates):
    acc, gyr = static_rates
    t = np.arange(len(acc)) / FS
    t[1500:] += 0.5
    path = physical(tmp_path, "gap.nc", acc, gyr, time=t, validated=False)
    code, err = run(capsys, "validate", path)
    assert code == 2
    assert "time gap of 0.51 s" in err and "between samples 1499 and 1500" in err and "t = 14.990000 s" in err


def test_declared_rate_against_the_least_squares_clock(tmp_path, capsys, static_rates):
    acc, gyr = static_rates
    jitter = np.random.default_rng(3).uniform(-0.2, 0.2, len(acc)) / 102.0   # jitter the median step would not see
    t = np.arange(len(acc)) / 102.0 + jitter                                  # really 102 Hz, declared 100 Hz
    code, err = run(capsys, "validate", physical(tmp_path, "clock.nc", acc, gyr, time=t, validated=False))
    assert code == 2 and "declared 100 Hz but the time coordinate gives 102" in err and "least-squares" in err
    t = np.arange(len(acc)) / 100.5 + jitter * 102.0 / 100.5                  # 0.5 %: within the 1 % tolerance
    code, err = run(capsys, "validate", physical(tmp_path, "ok.nc", acc, gyr, time=t, validated=False))
    assert code == 0, err


def test_masked_fill_value_sample_is_refused_by_index(tmp_path, capsys, static_rates):
    acc, gyr = static_rates
    acc = acc.copy()
    acc[77, 1] = np.nan                       # written as the _FillValue, never recorded
    path = physical(tmp_path, "masked.nc", acc, gyr, validated=False, encoding={"accel": {"_FillValue": -9999.0}})
    code, err = run(capsys, "validate", path)
    assert code == 2 and "masked sample (_FillValue -9999) at sample 77" in err


# --------------------------------------------------------------------------- files, folders, settings (exit 2)


def test_missing_folder_and_truncated_recordings(tmp_path, capsys, count_session):
    code, err = run(capsys, "validate", tmp_path / "nothere.nc")
    assert code == 2 and "nothere.nc: recording not found" in err
    code, err = run(capsys, "validate", tmp_path)                        # IsADirectoryError
    assert code == 2 and "is a folder, not a recording" in err
    cut = tmp_path / "cut.nc"
    cut.write_bytes(Path(count_session).read_bytes()[:5000])
    code, err = run(capsys, "validate", cut)
    assert code == 2 and "truncated or not netCDF" in err
    # a problem of the whole file names the file, not a placeholder variable
    assert f"{cut}: not a readable netCDF file" in err and "variable" not in err


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads and writes regardless of permissions")
def test_permission_denied(tmp_path, capsys, count_session):
    p = tmp_path / "locked.nc"
    shutil.copy(count_session, p)
    p.chmod(0)
    code, err = run(capsys, "validate", p)
    assert code == 2 and "permission denied" in err
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    code, err = run(capsys, "simulate", "calibration", ro / "x.nc", "--config", SMALL_CONFIG)
    assert code == 2 and "not writable" in err


def test_malformed_yaml_names_file_and_line(tmp_path, capsys):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("results: x\nseeds: {data: 1\nsite: [\n")
    code, err = run(capsys, "simulate", "calibration", tmp_path / "x.nc", "--config", cfg)
    assert code == 2 and f"{cfg}: line 3: malformed YAML" in err
    code, err = run(capsys, "import", cfg, tmp_path / "x.nc")
    assert code == 2 and f"{cfg}: line 3: malformed YAML" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.yaml"]


@pytest.mark.parametrize("edit, key, allowed", [
    (("calibration", "runs", -1), "calibration.runs", "allowed: integer >= 1"),
    (("navigation", "nav_rate_hz", "fast"), "navigation.nav_rate_hz", "number"),
    (("site", "latitude", 30.0), "site.latitude", "allowed: keys"),
])
def test_one_bad_config_key_is_summarised(tmp_path, capsys, edit, key, allowed):
    import yaml

    cfg = yaml.safe_load(SMALL_CONFIG.read_text())
    section, name, value = edit
    cfg[section][name] = value
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    code, err = run(capsys, "simulate", "calibration", tmp_path / "x.nc", "--config", path)
    assert code == 2
    assert f"{path}: {key} (line " in err and allowed in err
    assert len(err.splitlines()) <= 3 and "$defs" not in err and "properties" not in err   # never the schema dump
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cfg.yaml"]


def test_malformed_json_settings_and_missing_config(tmp_path, capsys, count_session):
    s = tmp_path / "s.json"
    s.write_text('{"figures": false,\n "alpha": }')
    code, err = run(capsys, "diagnose", count_session, "--out", tmp_path / "out", "--settings", s)
    assert code == 2 and f"{s}: line 2: malformed JSON" in err
    code, err = run(capsys, "simulate", "calibration", tmp_path / "x.nc", "--config", tmp_path / "none.yaml")
    assert code == 2 and "config file not found" in err and "--config" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]


@pytest.mark.parametrize("text, field, said", [
    ('{"report_detial": false}', "report_detial", "unknown setting"),         # a misspelt name
    ('{"report_detail": "no"}', "report_detail", '"no" is not true or false'),  # a string for a switch
    ('{"alpha": 2}', "alpha", "2 is not a number in (0, 1]"),                   # a probability above 1
    ('{"max_steps": 1.5}', "max_steps", "1.5 is not a whole number"),           # a count with a fraction
    ('{"max_offset_s": -0.1}', "max_offset_s", "-0.1 is not a number >= 0"),
])
def test_diagnosis_settings_are_checked_by_name_type_and_range(tmp_path, capsys, count_session, text, field, said):
    """A settings file the diagnosis would have read wrongly -- a misspelt name silently ignored, "no" taken as a
    true switch -- is refused in one line naming the file, the setting, what is wrong and the default; exit 2 and
    nothing written."""
    s = tmp_path / "s.json"
    s.write_text(text)
    code, err = run(capsys, "diagnose", count_session, "--out", tmp_path / "out", "--settings", s)
    assert code == 2, err
    assert f"{s}: {field}: {said}" in err and "fix:" in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]


def test_navigate_refuses_a_zero_rate_and_a_calibration_of_the_wrong_kind(tmp_path, capsys, count_session):
    out = tmp_path / "nav.nc"
    for opt in (["--nav-rate", "0"], ["--output-interval", "-1"], ["--nav-rate", "nan"]):
        code, err = run(capsys, "navigate", count_session, "--out", out, *opt)
        assert code == 2 and f"{opt[0]} must be positive" in err
    js = tmp_path / "x.json"
    js.write_text("{}")
    code, err = run(capsys, "navigate", count_session, "--out", out, "--calibration", js)
    assert code == 2 and "not a netCDF calibration file" in err and "default_calibration.nc" in err
    code, err = run(capsys, "navigate", count_session, "--out", out, "--calibration", count_session)
    assert code == 2 and "is a recording" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.json"]


def test_simulate_hours_must_be_positive_and_at_most_240(tmp_path, capsys, monkeypatch):
    out = tmp_path / "nav.nc"
    for hours, message in (("0", "--hours must be positive"), ("-1", "--hours must be positive"),
                           ("nan", "--hours must be positive"), ("300", "pass --force")):
        code, err = run(capsys, "simulate", "navigation", out, "--config", SMALL_CONFIG, "--hours", hours)
        assert code == 2 and message in err, (hours, err)
    code, err = run(capsys, "simulate", "calibration", out, "--config", SMALL_CONFIG, "--hours", "1")
    assert code == 2 and "--hours applies to 'navigation' and 'static_check'" in err
    # a long recording that does not fit on the disk is refused before anything is written
    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**12, 10**12 - 10**8, 10**8))
    code, err = run(capsys, "simulate", "navigation", out, "--config", SMALL_CONFIG, "--hours", "10")
    assert code == 2 and "GB but only 0.10 GB are free" in err
    assert list(tmp_path.iterdir()) == []


def test_output_folder_is_never_created_silently(tmp_path, capsys, count_session):
    folder = tmp_path / "missing" / "sub"
    code, err = run(capsys, "simulate", "calibration", folder / "x.nc", "--config", SMALL_CONFIG)
    assert code == 2 and f"{folder}: folder of the recording does not exist" in err and "mkdir -p" in err
    settings = tmp_path / "imp.yaml"
    settings.write_text("format: mikoff\nfile: nothing.log\n")
    code, err = run(capsys, "import", settings, folder / "x.nc")
    assert code == 2 and f"{folder}: folder of the recording does not exist" in err
    code, err = run(capsys, "navigate", count_session, "--out", folder / "nav.nc")
    assert code == 2 and "folder of the navigation output does not exist" in err
    assert not (tmp_path / "missing").exists()


def test_write_failure_leaves_no_partial_file_and_keeps_the_earlier_output(tmp_path, capsys, monkeypatch):
    out = tmp_path / "nav.nc"
    out.write_bytes(b"earlier good output")
    real_replace = os.replace

    def read_only(src, dst):
        if str(dst) == str(out):
            raise OSError(errno.EROFS, "Read-only file system", str(dst))
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", read_only)
    code, err = run(capsys, "simulate", "navigation", out, "--config", SMALL_CONFIG, "--hours", "0.005")
    assert code == 2 and f"{out}: Read-only file system" in err
    assert out.read_bytes() == b"earlier good output"
    assert leftovers(tmp_path) == []


def test_interrupt_removes_the_partial_file_and_keeps_the_earlier_output(tmp_path, capsys, monkeypatch):
    out = tmp_path / "nav.nc"
    out.write_bytes(b"earlier good output")
    real_append = recording.LongRecordingWriter.append

    def interrupted(self, *a, **k):
        real_append(self, *a, **k)
        raise KeyboardInterrupt

    monkeypatch.setattr(recording.LongRecordingWriter, "append", interrupted)
    code, err = run(capsys, "simulate", "navigation", out, "--config", SMALL_CONFIG, "--hours", "0.005")
    assert code == 130 and "interrupted by SIGINT" in err
    assert out.read_bytes() == b"earlier good output"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nav.nc"]


def test_diagnose_interrupted_after_its_figures_leaves_the_earlier_report_whole(tmp_path, capsys, count_session,
                                                                              monkeypatch):
    """The report's figures and its two files are one set: an interrupt once the figures are drawn (here: while the
    Markdown is made, the last step) leaves the earlier run's report and figures as they were, none of this run's
    (a served run interrupted there once left new figures beside no report)."""
    from calib.diagnosis import run as diagnosis_run

    out = tmp_path / "diag"
    out.mkdir()
    earlier = {"report.json": '{"verdict": "adequate"}\n', "report.md": "earlier report\n",
               "allan_deviation.png": "earlier figure"}
    for name, text in earlier.items():
        (out / name).write_text(text)

    def interrupted(rep):
        assert (out / "residuals_before_after.png").exists() is False   # drawn, not yet in place
        raise KeyboardInterrupt

    monkeypatch.setattr(diagnosis_run, "report_markdown", interrupted)
    code, err = run(capsys, "diagnose", count_session, "--out", out)
    assert code == 130 and "interrupted by SIGINT" in err
    assert {p.name: p.read_text() for p in out.iterdir()} == earlier
    assert leftovers(tmp_path) == []


def test_simulate_interrupted_at_its_truth_file_writes_neither(tmp_path, capsys, monkeypatch):
    """A recording and its truth sidecar are one set: interrupted while the truth is written, neither appears."""
    from calib.sim import static_session

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(static_session, "write_json", interrupted)
    code, err = run(capsys, "simulate", "static_check", tmp_path / "s.nc", "--config", SMALL_CONFIG, "--hours", "0.005")
    assert code == 130 and "interrupted by SIGINT" in err
    assert sorted(os.listdir(tmp_path)) == []


def test_diagnose_on_bad_input_exits_2_and_keeps_an_earlier_report(tmp_path, capsys, static_rates):
    acc, gyr = static_rates
    bad = physical(tmp_path, "bad.nc", acc, gyr, accel_units="g")
    out = tmp_path / "diag"
    out.mkdir()
    (out / "report.json").write_text('{"verdict": "adequate"}\n')
    (out / "report.md").write_text("earlier report\n")
    code, err = run(capsys, "diagnose", bad, "--out", out)
    assert code == 2 and "declared as 'g'" in err
    assert (out / "report.json").read_text() == '{"verdict": "adequate"}\n'
    assert (out / "report.md").read_text() == "earlier report\n"
    assert leftovers(tmp_path) == []
    fresh = tmp_path / "fresh"              # a refused input writes no report anywhere
    code, err = run(capsys, "diagnose", bad, "--out", fresh)
    assert code == 2 and "declared as 'g'" in err and not fresh.exists()


# --------------------------------------------------------------------------- implausible results (exit 3)


@pytest.mark.filterwarnings("ignore:parameter\\(s\\) on a search bound")
def test_calibration_outside_the_plausible_range_exits_3(tmp_path, capsys, count_session):
    """Accelerometer x counts tripled: the default calibration ends on Liu 2021's search bounds; it is written
    for inspection and the command exits 3 naming the settings."""
    ds = recording.load(count_session)
    acc = ds["accel"].values.astype(np.int64)
    acc[:, 0] *= 3
    ds["accel"] = (ds["accel"].dims, acc.astype(np.int32), ds["accel"].attrs)
    del ds.attrs["_path"]
    rec = recording.write(ds, tmp_path / "tripled.nc")
    out = tmp_path / "cal"
    code, err = run(capsys, "calibrate", rec, "--out", out, "--quick", "--config", SMALL_CONFIG)
    assert code == 3
    assert "calib calibrate: result check failed:" in err and "on the search bounds" in err
    assert "calibration.default_method" in err
    assert (out / "default_calibration.nc").exists() and leftovers(tmp_path) == []


def test_calibrate_interrupted_before_its_default_calibration_writes_nothing(tmp_path, capsys, count_session,
                                                                             monkeypatch):
    """The calibration study's products (optimizer runs, tables, figures, the default calibration) are one set: an
    interrupt once the runs, tables and figures are written, before the default calibration, leaves none of them."""
    from calib.studies import calibration as calibration_study

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(calibration_study, "write_default", interrupted)
    out = tmp_path / "cal"
    code, err = run(capsys, "calibrate", count_session, "--out", out, "--quick", "--config", SMALL_CONFIG)
    assert code == 130 and "interrupted by SIGINT" in err
    assert sorted(os.listdir(tmp_path)) == []   # not even the folders made for the products


def test_field_calibration_with_implausible_scale_factors_exits_3(tmp_path, capsys, count_session):
    ds = recording.load(count_session)
    acc = ds["accel"].values.astype(np.int64)
    acc[:, 0] *= 3
    ds["accel"] = (ds["accel"].dims, acc.astype(np.int32), ds["accel"].attrs)
    del ds.attrs["_path"]
    rec = recording.write(ds, tmp_path / "tripled.nc")
    out = tmp_path / "fieldcal.nc"
    code, err = run(capsys, "fieldcal", rec, "--out", out)
    assert code == 3 and "field calibration implausible: accel scale factors" in err
    assert "detection.threshold" in err
    assert out.exists() and leftovers(tmp_path) == []


def test_non_finite_navigation_exits_3_and_keeps_the_earlier_output(tmp_path, capsys):
    """A count calibration with scale factors of 1e-300: the navigation overflows; nothing replaces the earlier
    output."""
    import xarray as xr

    from calib.core.triad import liu2021_model

    rec = tmp_path / "static.nc"
    simulate_static_session({"mode": "counts", "duration_h": 0.002, "site": SITE}, 3, rec)
    vec = {s: liu2021_model(s).to_vector() for s in ("accel", "gyro")}
    vec["accel"][0:3] = 1e-300
    cal = tmp_path / "tiny.nc"
    xr.Dataset({s: (("parameter",), v) for s, v in vec.items()}).to_netcdf(cal)
    out = tmp_path / "nav.nc"
    out.write_bytes(b"earlier good output")
    code, err = run(capsys, "navigate", rec, "--calibration", cal, "--out", out, "--output-interval", "1")
    assert code == 3 and "non-finite values in" in err and "--nav-rate" in err
    assert out.read_bytes() == b"earlier good output" and leftovers(tmp_path) == []


def test_gyro_units_checked_against_the_table_angle(tmp_path):
    """A turntable session in physical units (the simulator's counts mapped through its true model): the gyro's
    integrated rotation over the rotation segments matches the recorded table angle (ratio within 1 %); the same
    rates declared in degrees are refused by that ratio (pi/180), the mistake named."""
    import math

    from calib.core.triad import liu2021_model
    from calib.signal import plausibility

    sess = simulate_calibration_session(
        {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 10.0, "revolutions": 1}, 3, tmp_path / "c.nc")
    ds = recording.load(sess)
    fs = float(ds.attrs["sample_rate_hz"])
    gyr = liu2021_model("gyro").inverse(np.asarray(ds["gyro"].values, float) * fs) * math.pi / 180.0 / 3600.0
    acc = liu2021_model("accel").inverse(np.asarray(ds["accel"].values, float) * fs) * 9.80665
    phys = ds.copy()
    phys["gyro"] = (ds["gyro"].dims, gyr, {"sample_kind": "rate", "units": "rad s-1"})
    phys["accel"] = (ds["accel"].dims, acc, {"sample_kind": "rate", "units": "m s-2"})
    good = recording.write(phys, tmp_path / "phys.nc")
    res = plausibility.check_recording(good)
    assert abs(res.table_angle_ratio - 1.0) < 0.01
    bad = phys.copy()
    bad["gyro"].attrs["units"] = "deg s-1"
    path = recording.write(bad, tmp_path / "deg.nc")
    res = plausibility.check_recording(path, force=True)
    assert res.table_angle_ratio == pytest.approx(math.pi / 180.0, rel=0.01)
    assert any("table turned" in w and "radians declared as degrees" in w for w in res.warnings)


def test_a_file_name_that_is_not_utf8_is_refused_by_name_with_the_fix(tmp_path, capsys, count_session):
    """The netCDF library opens and creates UTF-8 paths only, and Python keeps a name that is not valid UTF-8 as
    lone surrogates. Reading such a file, diagnosing it and writing to such a name end in exit 2 with a message
    naming the file (its bad byte escaped, as the terminal shows it) and the fix -- not the library's encoding
    error, not 'truncated or not netCDF' -- and nothing is left behind (a refused input gets no report)."""
    rec = tmp_path / os.fsdecode(b"rec\xff.nc")
    shutil.copy(count_session, rec)
    code, err = run(capsys, "validate", rec)
    assert code == 2 and "rec\\udcff.nc" in err and "is not valid UTF-8" in err and "fix: rename it" in err
    assert "truncated" not in err and "codec" not in err
    out = tmp_path / "diag"
    code, err = run(capsys, "diagnose", rec, "--out", out)
    assert code == 2 and "is not valid UTF-8" in err and "codec" not in err and not out.exists()
    before = sorted(os.listdir(tmp_path))
    code, err = run(capsys, "simulate", "calibration", tmp_path / os.fsdecode(b"sim\xff.nc"), "--config",
                    SMALL_CONFIG)
    assert code == 2 and "sim\\udcff.nc" in err and "is not valid UTF-8" in err and "fix: choose a name" in err
    assert sorted(os.listdir(tmp_path)) == before and leftovers(tmp_path) == []


@pytest.mark.parametrize("with_calibration", [True, False])
def test_units_and_calibration_that_do_not_pair_are_refused_before_any_sample_is_read(tmp_path, capsys, monkeypatch,
                                                                                      with_calibration):
    """A recording in physical units given a count calibration, or raw counts given none: refused (exit 2) with the
    command's own fix at once, before any sample is read (the check of every sample takes 12-21 s on a 240 h
    recording): here a read of the samples fails the test."""

    import xarray as xr

    from calib.core.triad import liu2021_model

    if with_calibration:
        rec = tmp_path / "nav.nc"
        assert cli.main(["simulate", "navigation", str(rec), "--config", str(ROOT / ".test" / "config.yaml"),
                         "--hours", "0.002"]) == 0
        cal = tmp_path / "cal.nc"
        xr.Dataset({s: (("parameter",), liu2021_model(s).to_vector()) for s in ("accel", "gyro")}).to_netcdf(cal)
        extra, fix = ["--calibration", cal], "calib navigate without --calibration"
    else:
        rec = tmp_path / "static.nc"
        simulate_static_session({"mode": "counts", "duration_h": 0.002, "site": SITE}, 3, rec)
        extra, fix = [], "calib navigate --calibration default_calibration.nc"
    capsys.readouterr()

    def no_samples(*a, **k):
        raise AssertionError("the command read samples before the refusal")

    monkeypatch.setattr(validation, "_validate_body", no_samples)
    monkeypatch.setattr(recording, "iter_raw_chunks", no_samples)
    code, err = run(capsys, "navigate", rec, *extra, "--out", tmp_path / "out.nc")
    assert code == 2 and fix in err and "calibration" in err, err
    assert not (tmp_path / "out.nc").exists()


#: the modules that call read_header by name: a count of its calls patches each
HEADER_READERS = (recording, validation, chunked_reading, in_memory)


def count_calls(monkeypatch, name, *modules) -> list:
    """Replace function ``name`` in each of ``modules`` (the same function, imported by name) by a wrapper of the
    first's that notes each call; returns the list of notes."""
    calls, fn = [], getattr(modules[0], name)

    def counted(*a, **k):
        calls.append(1)
        return fn(*a, **k)

    for m in modules:
        monkeypatch.setattr(m, name, counted)
    return calls


def test_the_samples_are_read_once_for_the_format_and_the_plausibility_checks(tmp_path, monkeypatch):
    """`_check_recording` validates every sample and judges their magnitudes on one read of the file, with the
    judgement of a separate read; a file known as validated (reuse_validation) is read once for the judgement."""
    acc = np.tile([0.0, 0.0, 9.79], (3000, 1)) + np.random.default_rng(1).normal(0, 1e-3, (3000, 3))
    gyr = np.tile(np.radians([0.0, 0.002, 0.003]), (3000, 1))
    rec = physical(tmp_path, "r.nc", acc, gyr)
    reads = count_calls(monkeypatch, "iter_raw_chunks", recording, validation)
    headers = count_calls(monkeypatch, "read_header", *HEADER_READERS)
    h, pl = check_recording(rec, False, "recording")
    assert len(reads) == 1
    assert len(headers) == 1   # the header too (a long recording's time coordinate is read whole for its checks)
    separate = plausibility.check_recording(rec, recording.validate(rec))
    assert len(reads) == 3
    assert (pl.describe(), pl.warnings, pl.n_quiet_blocks) == (separate.describe(), separate.warnings,
                                                                separate.n_quiet_blocks)
    with recording.reuse_validation():
        check_recording(rec, False, "recording")
        del reads[:]
        check_recording(rec, False, "recording")
    assert len(reads) == 1


def test_navigate_checks_every_sample_before_the_navigation(tmp_path, capsys, monkeypatch):
    """`calib navigate` checks every sample before it navigates: a clean recording is navigated after one check; a
    masked sample is refused by its index (exit 2) before any navigation, and nothing replaces the earlier
    output."""
    from calib.studies import navigation_stage as navigation_study

    clean = tmp_path / "clean.nc"
    assert cli.main(["simulate", "navigation", str(clean), "--config", str(ROOT / ".test" / "config.yaml"),
                     "--hours", "0.005"]) == 0
    ds = recording.load(clean)
    ds["accel"].values[77, 1] = np.nan
    ds["accel"].encoding["_FillValue"] = -9999.0
    masked = write_netcdf(ds, tmp_path / "masked.nc")
    checks = count_calls(monkeypatch, "_validate_body", validation)
    navigations = count_calls(monkeypatch, "navigate_file", navigation_study)
    capsys.readouterr()
    code, err = run(capsys, "navigate", clean, "--out", tmp_path / "nav.nc", "--output-interval", "1")
    assert code == 0 and (tmp_path / "nav.nc").exists(), err
    assert (len(checks), len(navigations)) == (1, 1)
    out = tmp_path / "earlier.nc"
    out.write_bytes(b"earlier output")
    code, err = run(capsys, "navigate", masked, "--out", out, "--output-interval", "1")
    assert code == 2 and "masked sample (_FillValue -9999) at sample 77" in err, err
    assert len(navigations) == 1   # refused before the navigation
    assert out.read_bytes() == b"earlier output" and leftovers(tmp_path) == []


def test_navigate_reads_the_recording_s_header_once_beside_its_check(tmp_path, capsys, monkeypatch):
    """`calib navigate` reads the header (for a recording with a time coordinate: the whole time array, differenced
    and fitted) once for the navigation and once for the sample check: the early units check, the progress bar and
    the navigation share the first read."""
    from calib.studies import navigation_stage as navigation_study

    rec = tmp_path / "nav.nc"
    assert cli.main(["simulate", "navigation", str(rec), "--config", str(ROOT / ".test" / "config.yaml"),
                     "--hours", "0.005"]) == 0
    reads = count_calls(monkeypatch, "read_header", *HEADER_READERS, navigation_study)
    code, err = run(capsys, "navigate", rec, "--out", tmp_path / "out.nc", "--output-interval", "1")
    assert code == 0 and (tmp_path / "out.nc").exists(), err
    assert len(reads) == 2, len(reads)


def test_navigate_reads_the_calibration_file_once(tmp_path, capsys, monkeypatch):
    """`calib navigate --calibration FILE` opens the calibration once: its kind check, the early units check and the
    navigation share that read (three opens before). Counted on xarray's opening of that file."""
    import xarray as xr

    from calib.core.triad import liu2021_model

    rec = tmp_path / "static.nc"
    simulate_static_session({"mode": "counts", "duration_h": 0.002, "site": SITE}, 3, rec)
    cal = tmp_path / "cal.nc"
    xr.Dataset({s: (("parameter",), liu2021_model(s).to_vector()) for s in ("accel", "gyro")}).to_netcdf(cal)
    opens, open_dataset = [], xr.open_dataset

    def counted(path, *a, **k):
        if Path(path) == cal:
            opens.append(1)
        return open_dataset(path, *a, **k)

    monkeypatch.setattr(xr, "open_dataset", counted)
    code, err = run(capsys, "navigate", rec, "--calibration", cal, "--out", tmp_path / "out.nc",
                    "--output-interval", "1")
    assert code == 0 and (tmp_path / "out.nc").exists(), err
    assert len(opens) == 1, len(opens)


def test_no_recorded_attitude_is_refused_with_the_command_s_option(tmp_path, capsys, static_rates):
    acc, gyr = static_rates
    code, err = run(capsys, "navigate", physical(tmp_path, "r.nc", acc, gyr), "--out", tmp_path / "nav.nc")
    assert code == 2 and "no initial attitude" in err and "calib navigate --align" in err, err
