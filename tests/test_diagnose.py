"""Mismatch diagnosis (calib.diagnosis.diagnose, calib.diagnosis.signatures).

Every expected value is the truth injected into the simulator (the effect parameters of calib.sim.effects), a
closed form, or a property of the input (too short, flat); never a number captured from the diagnosis.
Sessions are short (20 s positions, one revolution per rotation) to keep the file under a minute.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from calib.diagnosis import diagnose as dg
from calib.sim import effects
from calib.io import recording
from calib.diagnosis import signatures as sg
from calib.sim import simulator as simulate

#: a short Liu 2021 session: 24 positions of 20 s, +-10/20/30 deg/s about x, y, z, one revolution each
SHORT = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}
FAST = {"figures": False}


def _session(effects_cfg, **extra):
    return {**SHORT, **extra, "effects": effects_cfg, "conceal": True}


@pytest.fixture(scope="module")
def null_session(tmp_path_factory):
    return dg.FastSession(_session({}), tmp_path_factory.mktemp("null"))


@pytest.fixture(scope="module")
def shared(null_session):
    """Geometry, covariance structure and effect library of the short path (shared by every session of it:
    the library depends on the path and the base K E only)."""
    _, prob = dg.diagnose_dataset(null_session.dataset(0), None, FAST, path="seed 0")
    return prob


def _diagnose(fsess, seed, library_from=None):
    rep, prob = dg.diagnose_dataset(fsess.dataset(seed), None, FAST, path=f"seed {seed}",
                                    library_from=library_from)
    return rep, prob


def _truth_in_interval(rep, eid, truth_params, widen=1.0):
    """Every reported parameter of the found term ``eid``: truth inside value +- widen * 1.96 se."""
    f = [x for x in rep["found"] if x["effect"] == eid]
    assert f, f"{eid} not found: {[x['key'] for x in rep['found']]}"
    checked = 0
    for p in f[0]["parameters"]:
        tv = dg._truth_value(truth_params, p["name"])
        assert tv is not None
        half = widen * 1.96 * p["se"]
        assert abs(p["value"] - tv) <= half, f"{p['name']}: {p['value']} +- {half} vs truth {tv}"
        checked += 1
    assert checked > 0


def test_fast_session_is_the_simulator(null_session, tmp_path):
    """The proof's per-seed generator gives exactly the counts the simulator writes for that seed."""
    path = simulate.simulate_calibration_session(_session({}), 5, tmp_path / "s5.nc")
    ds = recording.load(path)
    fast = null_session.dataset(5)
    assert np.array_equal(ds["accel"].values, fast["accel"].values)
    assert np.array_equal(ds["gyro"].values, fast["gyro"].values)


def test_geometry_whole_revolutions_and_noise_free_base_model(tmp_path):
    """Noise-free session: windows span whole revolutions (table angle at sample mid-times) and the base model
    with the true K E, b reproduces every observation (mean, cos, sin) to the sample-averaging attenuation
    of the harmonics (sinc of half the angle step, < 2e-6 relative)."""
    quiet = {"accel_vrw_ug_rthz": 0.0, "accel_bias_instability_ug": 0.0, "gyro_arw_deg_rth": 0.0,
             "gyro_bias_instability_deg_h": 0.0, "quantize": False}
    path = simulate.simulate_calibration_session({**SHORT, "noise": quiet}, 0, tmp_path / "q.nc")
    ds = recording.load(path)
    geom = sg.build_geometry(ds)
    for w in geom.rotation:
        step = abs(w.rate_deg_s) * geom.dt
        span = abs(np.degrees(w.theta_mid[-1] - w.theta_mid[0])) + step
        assert span == pytest.approx(360.0 * w.revolutions, abs=1e-6)
    y, _ = sg.reduce_data(geom, ds)
    xr, ones = sg.reduced_inputs(geom)
    X = sg.base_design(geom, xr, ones)
    a, g = simulate.sensor_models("liu2021")
    theta = np.concatenate([a.KE.ravel(), a.b, g.KE.ravel(), g.b])
    res = y - X @ theta
    scale = np.abs(y).max()
    assert np.max(np.abs(res)) < 2e-6 * scale


def test_null_session_is_adequate(null_session, shared):
    rep, _ = _diagnose(null_session, 11, library_from=shared)
    assert rep["verdict"] == "adequate", rep["verdict_reason"]
    assert rep["found"] == []
    assert rep["goodness_of_fit"]["before"]["p"] > 0.01
    ids = {u["effect"] for u in rep["untestable"]}
    assert "gravity_error" in ids          # the scale factors absorb a wrong g on any path


EFFECT_CASES = {
    "accel_quadratic_nonlinearity": {"accel_quadratic_nonlinearity": {"k2_ug_per_g2": [80.0, -60.0, 50.0]}},
    "gyro_g_sensitivity": {"gyro_g_sensitivity": {
        "G_deg_h_per_g": [[0.08, 0.03, -0.02], [-0.03, 0.06, 0.02], [0.02, -0.02, 0.09]]}},
    "time_offset": {"time_offset": {"offset_s": 0.02}},
    "bias_drift": {"bias_drift": {"accel_warmup_ug": [200.0, -150.0, 120.0], "accel_tau_s": 600.0,
                                  "accel_trend_ug_per_h": [0.0, 0.0, 0.0], "gyro_warmup_deg_h": [0.0, 0.0, 0.0],
                                  "gyro_trend_deg_h_per_h": [0.0, 0.0, 0.0]}},
}


@pytest.mark.parametrize("eid", list(EFFECT_CASES))
def test_injected_effect_is_found_with_its_magnitude(eid, tmp_path, shared):
    cfg = EFFECT_CASES[eid]
    fs = dg.FastSession(_session(cfg), tmp_path)
    rep, _ = _diagnose(fs, 3, library_from=shared)
    assert rep["verdict"] == "missing_physics"
    keys = [f["effect"] for f in rep["found"]]
    assert eid in keys, (keys, rep["verdict_reason"])
    truth = effects.resolve(cfg)[eid]
    # several parameters per term on one fixed seed: each inside its interval widened to 99 % (2.58 sigma)
    _truth_in_interval(rep, eid, truth, widen=2.576 / 1.96)
    # the model with the term fits within the noise
    assert rep["goodness_of_fit"]["after"]["p"] >= 0.01
    # nothing unrelated is named
    assert all(eid in dg._group(f) or f["effect"] == eid for f in rep["found"])


def test_gravity_error_is_untestable_not_named(tmp_path, shared):
    cfg = {"gravity_error": {"delta_g_m_s2": 2e-3}}
    fs = dg.FastSession(_session(cfg), tmp_path)
    rep, _ = _diagnose(fs, 4, library_from=shared)
    assert all(f["effect"] != "gravity_error" for f in rep["found"])
    unt = {u["effect"]: u for u in rep["untestable"]}
    assert "gravity_error" in unt
    assert unt["gravity_error"]["absorbed_fraction"] > 0.999
    assert "scale" in unt["gravity_error"]["why"]
    assert rep["found"] == []               # a wrong g changes nothing the path can see


def test_latitude_and_g_sensitivity_alike_on_rotation_sums_only(null_session, shared):
    """The report says which segments separate the look-alikes: on rotation means alone latitude error and
    gyro g-sensitivity are much closer than with the static positions and harmonics."""
    rep, _ = _diagnose(null_session, 12, library_from=shared)
    sep = rep["identifiability"]["separations"][0]
    assert sep["angle_deg_rotation_means_only"] < sep["angle_deg_all_segments"]
    assert any(s["segment"].startswith(("P", "ROT")) for s in sep["separating_segments_latitude"])


def test_too_few_segments_is_inconclusive(tmp_path):
    cfg = {**SHORT, "positions_per_phase": 1, "step_deg": 90.0}
    path = simulate.simulate_calibration_session(cfg, 1, tmp_path / "few.nc")
    rep = dg.diagnose_recording(path, tmp_path / "out", FAST)
    assert rep["verdict"] == "inconclusive"
    assert "static segments" in rep["verdict_reason"]
    assert rep["found"] == []
    assert (tmp_path / "out" / "report.json").exists() and (tmp_path / "out" / "report.md").exists()


def test_too_short_is_inconclusive(tmp_path):
    cfg = {**SHORT, "dwell_s": 1.0, "rotation_rates_deg_s": [], "transition_s": [0.5, 0.2], "move_rate_deg_s": 90.0}
    path = simulate.simulate_calibration_session(cfg, 1, tmp_path / "short.nc")
    rep = dg.diagnose_recording(path, tmp_path / "out", FAST)
    assert rep["verdict"] == "inconclusive"
    assert "lasts" in rep["verdict_reason"] or "static" in rep["verdict_reason"]
    assert rep["found"] == []


def test_flat_data_missing_sigma_is_inconclusive(null_session, tmp_path):
    ds = null_session.dataset(1)
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


def test_norm_model_without_attitudes_finds_quadratic(tmp_path):
    """Drop the nominal attitudes: the accelerometer norm model (Liu 2021 eq. 7) still names the injected
    quadratic nonlinearity and brackets its magnitude."""
    cfg = {"accel_quadratic_nonlinearity": {"k2_ug_per_g2": [400.0, -300.0, 250.0]}}
    fs = dg.FastSession(_session(cfg), tmp_path)
    ds = fs.dataset(2).drop_vars(["nominal_attitude"])
    rep, _ = dg.diagnose_dataset(ds, None, FAST, path="no attitudes")
    assert rep["model"] == "norm"
    _truth_in_interval(rep, "accel_quadratic_nonlinearity", effects.resolve(cfg)["accel_quadratic_nonlinearity"],
                       widen=2.576 / 1.96)
    unt = {u["effect"] for u in rep["untestable"]}
    assert {"latitude_error", "time_offset", "gyro_g_sensitivity"} <= unt


def test_score_closed_cases():
    truth = {"effects": {"accel_cubic_nonlinearity": {"k3_ug_per_g3": [20.0, -15.0, 10.0]}}}
    found = {"effect": "accel_cubic_nonlinearity", "sensor": "accel", "key": "accel_cubic_nonlinearity/accel",
             "aliases": [], "parameters": [{"name": "k3_ug_per_g3[x]", "value": 19.0, "ci95": [17.0, 21.0], "se": 1.0},
                                           {"name": "k3_ug_per_g3[y]", "value": -11.0, "ci95": [-13.0, -9.0],
                                            "se": 1.0}]}
    s = dg.score({"found": [found]}, truth)
    assert s["correct"] and s["named_exactly"] and not s["false_discoveries"]
    assert [c["covered"] for c in s["coverage"]] == [True, False]
    other = dict(found, effect="accel_scale_asymmetry", key="accel_scale_asymmetry/accel",
                 aliases=[{"effect": "accel_cubic_nonlinearity", "key": "x"}])
    s2 = dg.score({"found": [other]}, truth)
    assert s2["correct"] and not s2["named_exactly"]
    assert dg.score({"found": []}, {"effects": {}})["correct"]
    assert not dg.score({"found": [found]}, {"effects": {}})["correct"]
    conf = {"effects": {"gravity_error": {"delta_g_m_s2": 5e-4}}}
    assert dg.score({"found": [], "untestable": [{"effect": "gravity_error"}]}, conf, "confounded")["correct"]
    g1 = dict(found, effect="gravity_error", aliases=[])
    assert not dg.score({"found": [g1], "untestable": []}, conf, "confounded")["correct"]


def test_report_files_and_cli(tmp_path):
    path = simulate.simulate_calibration_session(
        _session({"accel_scale_asymmetry": {"asym_ppm": [150.0, -120.0, 90.0]}}), 8, tmp_path / "a.nc")
    code = dg.main([str(path), "--out", str(tmp_path / "out")])
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert code == 1 and rep["verdict"] == "missing_physics"
    assert "accel_scale_asymmetry" in {f["effect"] for f in rep["found"]}
    md = (tmp_path / "out" / "report.md").read_text()
    assert "accel_scale_asymmetry" in md and "Untestable" in md
    assert (tmp_path / "out" / "residuals_before_after.png").stat().st_size > 0
    for eid in effects.REGISTRY:        # every library id appears verbatim in the report
        assert eid in json.dumps(rep)


@pytest.mark.slow
def test_proof_100_seeds(tmp_path):
    out = dg.run_proof(tmp_path, n_seeds=100, workers=2)
    for s in out["sessions"]:
        if s["kind"] == "single":
            assert s["rate"] >= 0.95, s
            lo, hi = s["coverage_ci99"]
            assert lo <= 0.95 <= hi, s
            assert s["chi2_after_p_ge_0.01"] >= 0.95, s
        elif s["kind"] == "null":
            assert s["false_discovery_rate"] <= 0.05, s
        else:
            assert s["attributed_to_one"] == 0, s


def test_proof_stage_products(tmp_path):
    """The workflow's proof stage on the short path: a null session finds nothing, the hidden clock offset
    (10 ms, within the tested +-0.25 s) is named in every seed, and the per-seed netCDF, the power table and
    figure are written with labelled dimensions."""
    from calib.studies import diagnosis as ds_

    base = {**SHORT, "revolutions": 1}
    out = ds_.proof_stage(tmp_path, n_seeds=3, first_seed=7, sessions=["null_a", "time_offset"], power_seeds=2,
                          workers=1, base=base, site=SHORT["site"], log=lambda *a: None,
                          metrics_path=tmp_path / "proof.metrics.json")
    import xarray as xr

    nc = xr.open_dataset(tmp_path / "proof.nc")
    assert list(nc["session"].values) == ["null_a", "time_offset"] and list(nc["seed"].values) == [7, 8, 9]
    assert int(nc["false_discovery"].sel(session="null_a").sum()) == 0
    assert int(nc["n_found"].sel(session="null_a").sum()) == 0
    assert nc["correct"].sel(session="time_offset").values.tolist() == [1, 1, 1]
    assert "power_scale" in nc and (tmp_path / "power.png").stat().st_size > 0
    assert (tmp_path / "power.csv").read_text().startswith("effect,smallest_scale_80pct")
    # wall times never enter the scientific files
    assert "elapsed" not in (tmp_path / "proof.json").read_text()
    assert "total_s" in (tmp_path / "timings.json").read_text()
    assert out["acceptance"]["null_a"]["false_discoveries_le_5pct"]


def test_unknown_settings_and_sessions_refused(tmp_path):
    from calib.studies import diagnosis as ds_

    with pytest.raises(ValueError, match="alpah"):
        ds_.check_settings({"alpah": 0.01})
    with pytest.raises(ValueError, match="no_such_session"):
        ds_.proof_stage(tmp_path, 1, 0, sessions=["no_such_session"], log=lambda *a: None)


# ---------------------------------------------------------------------------------------------------------
# real recordings (../shared/data): the injection test and the intervals of the field calibration
# ---------------------------------------------------------------------------------------------------------
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"shared real-data directory {REAL} is missing")


@needs_real
def test_injected_quadratic_found_on_top_of_the_real_xsens_data():
    """A known quadratic nonlinearity added to the real IMU-TK Xsens session (in the sensor model its own norm
    calibration identifies) is named, and the difference between the estimates with and without it brackets
    the injected value in its 95 % interval."""
    ds = dg._import_real(ROOT / "config" / "import" / "imu_tk_xsens.yaml")
    rep0, prob = dg.diagnose_dataset(ds, None, FAST, path="xsens")
    assert rep0["model"] == "norm"
    inj = {"k2_ug_per_g2": [4000.0, -3000.0, 2500.0]}
    rep1, _ = dg.diagnose_dataset(dg.inject_accel_term(ds, prob, "accel_quadratic_nonlinearity", inj), None, FAST,
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
    from calib.signal import detect
    from calib.ingest import importers

    ds = importers.import_dataset(importers.load_settings(ROOT / "config" / "import" / "mikoff_imu0.yaml"))
    path = recording.write(ds, tmp_path / "imu0.nc")
    iv = np.asarray(detect.detect_in_recording(ds).intervals)
    assert len(iv) >= 14
    rep = dg.diagnose_recording(path, tmp_path / "a", FAST, intervals=iv[:14], intervals_source="test")
    assert rep["observations"]["static_segments"] == 14
    rep = dg.diagnose_recording(path, tmp_path / "b", FAST, intervals=iv[:5])
    assert rep["verdict"] == "inconclusive" and "only 5 static segments" in rep["verdict_reason"]
    assert "at least 10" in rep["verdict_reason"]
