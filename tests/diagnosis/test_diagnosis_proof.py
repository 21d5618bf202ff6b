"""The concealed-effect proof of the diagnosis (calib.studies.diagnosis_proof, calib.studies.diagnosis_score):
its per-seed sessions are the simulator's own output, the scoring rules on closed cases, the workflow stage's
products."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

from calib.core import seeds
from calib.core.errors import ResultCheckError
from calib.io import recording
from calib.sim.calibration_session import build_calibration_simulator, simulate_calibration_session
from calib.studies import diagnosis_stage as diagnosis_study
from calib.studies import diagnosis_proof
from calib.studies.diagnosis_proof import FastSession, run_proof
from calib.studies.diagnosis_score import score

ROOT = Path(__file__).resolve().parents[2]
SHORT = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}


def test_fast_session_is_the_simulator(tmp_path):
    """The proof's per-seed generator, and the simulator's own seed API it rests on, give exactly the counts
    the simulator writes for that seed."""
    cfg = {**SHORT, "effects": {"time_offset": {"offset_s": 0.01}}, "conceal": True}
    path = simulate_calibration_session(cfg, 5, tmp_path / "s5.nc")
    ds = recording.load(path)
    fs = FastSession(cfg, tmp_path / "fast")
    fast = fs.dataset(5)
    # its end-to-end file is the simulator's own, byte for byte
    assert fs.path.read_bytes() == simulate_calibration_session(cfg, 0, tmp_path / "s0.nc").read_bytes()
    assert np.array_equal(ds["accel"].values, fast["accel"].values)
    assert np.array_equal(ds["gyro"].values, fast["gyro"].values)
    sim = build_calibration_simulator(cfg, 0)
    acc, gyr = sim.counts(5, clean=sim.clean_increments())
    assert acc.dtype == ds["accel"].values.dtype
    assert np.array_equal(acc, ds["accel"].values) and np.array_equal(gyr, ds["gyro"].values)
    acc2, _ = build_calibration_simulator(cfg, 5).counts()
    assert np.array_equal(acc2, ds["accel"].values)


def test_shared_noise_is_the_simulator(tmp_path):
    """Sessions of one unit share a seed's noise increments (kept once per process): a second session served from
    the kept noise, and a unit with other noise terms (never served another unit's noise), still give exactly the
    counts the simulator writes for that seed."""
    diagnosis_proof.clear_shared_noise()
    cfg_a = {**SHORT, "effects": {"time_offset": {"offset_s": 0.01}}, "conceal": True}
    cfg_b = {**SHORT, "effects": {"accel_cross_coupling": {}}, "conceal": True}
    noisier = {**SHORT, "effects": {}, "conceal": True, "noise": {"accel_bias_instability_ug": 50.0}}
    FastSession(cfg_a, tmp_path / "a").dataset(7)
    assert len(diagnosis_proof._NOISE) == 1
    for i, cfg in enumerate((cfg_b, noisier)):
        fast = FastSession(cfg, tmp_path / f"f{i}").dataset(7)
        ds = recording.load(simulate_calibration_session(cfg, 7, tmp_path / f"s{i}.nc"))
        assert np.array_equal(ds["accel"].values, fast["accel"].values)
        assert np.array_equal(ds["gyro"].values, fast["gyro"].values)
    assert len(diagnosis_proof._NOISE) == 2       # the noisier unit's noise is its own
    diagnosis_proof.clear_shared_noise()


def test_power_scan_session_reuse_equals_a_fresh_build(tmp_path):
    """The power scan shares one session's template, simulator and clean signal across effect sizes
    (FastSession base_of): the seeds' counts and truth equal those of a session built from scratch at that size;
    a different world (here the latitude) is never reused."""
    eff = {"accel_lever_arm": {"lever_arms_m": [[0.02, 0.0, 0.0], [0.0, 0.03, 0.0], [0.0, 0.0, -0.025]]}}
    half = {"accel_lever_arm": {"lever_arms_m": [[0.01, 0.0, 0.0], [0.0, 0.015, 0.0], [0.0, 0.0, -0.0125]]}}
    first = FastSession({**SHORT, "effects": eff, "conceal": True}, tmp_path / "a", physical=True)
    reused = FastSession({**SHORT, "effects": half, "conceal": True}, None, physical=True, base_of=first)
    fresh = FastSession({**SHORT, "effects": half, "conceal": True}, tmp_path / "b", physical=True)
    assert reused.sim is first.sim and first.reusable_for(fresh)
    for sd in (3, 4):
        a, b = reused.dataset(sd), fresh.dataset(sd)
        assert np.array_equal(a["accel"].values, b["accel"].values)
        assert np.array_equal(a["gyro"].values, b["gyro"].values)
        assert not np.array_equal(a["accel"].values, first.dataset(sd)["accel"].values)
        ta, tb = reused.truth_for(sd), fresh.truth_for(sd)
        ta.pop("generation_time_s"), tb.pop("generation_time_s")     # the simulator's wall time, not science
        assert ta == tb
    other = {**SHORT, "site": {"latitude_deg": 50.0, "height_m": 0.0}, "effects": half, "conceal": True}
    moved = FastSession(other, tmp_path / "c", physical=True, base_of=first)
    assert moved.sim is not first.sim and moved.sim.site.latitude_deg == 50.0


def test_seeds_on_the_end_to_end_geometry_score_as_from_scratch(tmp_path):
    """The proof's first seed of a session reuses the geometry of the session's end-to-end run (the simulator's
    file read back from disk): every seed's score row equals the row of a set-up from scratch."""
    from calib.diagnosis import DEFAULT_SETTINGS, diagnose_recording

    eff = {"accel_lever_arm": {"lever_arms_m": [[0.02, 0.0, 0.0], [0.0, 0.03, 0.0], [0.0, 0.0, -0.025]]}}
    fs = FastSession({**SHORT, "effects": eff, "conceal": True}, tmp_path / "a", physical=True)
    _, prob = diagnose_recording(fs.path, None, {"figures": False}, return_problem=True)
    assert prob is not None and prob.kind == "vector"
    st = {**DEFAULT_SETTINGS, "figures": False, "absent_bounds": False, "report_detail": False}
    rows = {}
    for how, g in (("fresh", None), ("reused", prob)):
        rows[how], p0 = diagnosis_proof._seed_rows(fs, "lever", "single", [21, 22], st, geometry_from=g)
        assert (p0.geom is prob.geom) == (g is not None)
        for r in rows[how]:
            r.pop("elapsed_s")
    assert rows["fresh"][0]["correct"] and json.dumps(rows["reused"], sort_keys=True) == json.dumps(rows["fresh"], sort_keys=True)


def test_geometry_reuse_gives_the_reports_of_a_fresh_set_up(tmp_path):
    """A recording of the same template diagnosed with the geometry of another one (geometry_from: the power
    scan) gives the report of a set-up from scratch, number for number."""
    from calib.diagnosis import diagnose_dataset

    eff = {"accel_cubic_nonlinearity": {"k3_ug_per_g3": [60.0, -40.0, 30.0]}}
    small = {**eff["accel_cubic_nonlinearity"], "k3_ug_per_g3": [30.0, -20.0, 15.0]}
    a = FastSession({**SHORT, "effects": eff, "conceal": True}, tmp_path / "a", physical=True)
    b = FastSession({**SHORT, "effects": {"accel_cubic_nonlinearity": small}, "conceal": True}, None,
                    physical=True, base_of=a)
    st = {"figures": False}
    _, pa = diagnose_dataset(a.dataset(11), None, st, path="p")
    fresh, _ = diagnose_dataset(b.dataset(12), None, st, path="p")
    reused, pb = diagnose_dataset(b.dataset(12), None, st, path="p", geometry_from=pa)
    assert pb.geom is pa.geom and pb.lib is not pa.lib
    fresh.pop("elapsed_s"), reused.pop("elapsed_s")
    assert json.dumps(reused, sort_keys=True) == json.dumps(fresh, sort_keys=True)   # NaN entries compare equal


def test_power_scan_after_its_session_reuses_it_and_equals_a_fresh_scan(tmp_path, monkeypatch):
    """A single-effect session's power scan run right after the session in one process (the workflow's job:
    proof_session, then power_scan) builds no simulator of its own: it takes the session's template, simulator,
    clean signal and geometry. Its rows are those of a scan that builds them from scratch."""
    built = []
    real = diagnosis_proof.sim_session.build_calibration_simulator
    monkeypatch.setattr(diagnosis_proof.sim_session, "build_calibration_simulator",
                        lambda *a, **k: built.append(1) or real(*a, **k))
    strip = lambda res: json.dumps([{k: ([{c: v for c, v in row.items() if c != "elapsed_s"} for row in x[k]]
                                         if k == "rows" else x[k]) for k in x if k not in ("t_build_s", "t_total_s")}
                                    for x in res], sort_keys=True)
    r = diagnosis_proof.proof_session("time_offset", tmp_path / "part", 2, 7, base=SHORT)
    assert len(built) == 1
    assert r["fisher"]["exact"] and not diagnosis_proof.sim_fisher._NUISANCE   # its base spectra not kept after use
    after = diagnosis_proof.power_scan(r, 2, 7, base=SHORT)
    assert len(built) == 1 and len(after) >= 2                # the session's simulator, no build of its own
    fresh = diagnosis_proof.power_scan(r, 2, 7, base=SHORT)    # nothing kept now: built from scratch
    assert len(built) == 2
    assert strip(after) == strip(fresh)
    # with a noise store the scan holds no seed's noise in memory: each scale reads it back from the store
    held = []
    real_rows = diagnosis_proof._seed_rows
    monkeypatch.setattr(diagnosis_proof, "_seed_rows",
                        lambda *a, **k: held.append(len(diagnosis_proof._NOISE)) or real_rows(*a, **k))
    (tmp_path / "noise").mkdir()
    stored = diagnosis_proof.power_scan(r, 2, 7, base=SHORT, store=tmp_path / "noise")
    assert len(held) == len(stored) >= 2 and set(held) == {0}
    # its 2 seeds, and the template seed with which its session's end-to-end file is written
    assert len(list((tmp_path / "noise").glob("*.npy"))) == 3
    assert strip(stored) == strip(fresh)


def test_skipping_absent_bounds_and_detail_changes_nothing_else(tmp_path):
    """The proof's per-seed runs skip the upper bounds of absent terms and the report's detail (where the misfit
    lies, absorbed fractions, angles of pairs without a found term, separations, the size of generic structures
    that are not significant): every other part of the report
    -- the verdict, the findings with their aliases and intervals, what the score reads -- is the same as with them,
    and the angles kept are the full report's."""
    from calib.diagnosis import diagnose_dataset

    fs = FastSession({**SHORT, "effects": {"accel_cubic_nonlinearity": {"k3_ug_per_g3": [60.0, -40.0, 30.0]}},
                      "conceal": True}, tmp_path, physical=True)
    full, _ = diagnose_dataset(fs.dataset(21), None, {"figures": False}, path="p")
    lean, _ = diagnose_dataset(fs.dataset(21), None, {"figures": False, "absent_bounds": False,
                                                      "report_detail": False}, path="p")
    assert full["found"] and full["absent"] and lean["absent"] is None
    assert score(full, fs.truth_for(21), "single") == score(lean, fs.truth_for(21), "single")
    found = {f["key"] for f in full["found"]}
    kept = [a for a in full["identifiability"]["pairwise_angles_deg"] if {a["a"], a["b"]} & found]
    assert kept and lean["identifiability"]["pairwise_angles_deg"] == kept
    assert full["locate"]["summary"] and not lean["locate"]["summary"]
    from calib.diagnosis import report_markdown
    assert "## " in report_markdown(lean)       # a lean report still renders
    for t_full, t_lean in zip(full["open_search"]["tests"], lean["open_search"]["tests"]):
        if t_lean["rms"] is None:      # the size of a generic structure: for the significant ones only
            assert not t_lean["significant"]
            t_full["rms"] = None
    # the size of the slow level a verdict needs is detail too (its bisection): which axes need one is not
    sl_full, sl_lean = full["adequacy"]["slow_noise"], lean["adequacy"]["slow_noise"]
    assert all(e["minimum_for_adequacy"] is None for e in sl_lean["levels"])
    for r, sl in ((full, sl_full), (lean, sl_lean)):
        if sl["statement"]:
            r["verdict_reason"] = r["verdict_reason"].replace(sl["statement"], "<slow-noise statement>")
        sl["statement"], sl["record_minutes_needed"] = None, None
        sl["levels"] = [{k: e[k] for k in ("sensor", "axis", "unit", "record_resolves_it")} for e in sl["levels"]]
    # the Cramer-Rao bounds beside the estimates are detail too
    assert "bounds" in full and "bounds" not in lean

    def without_bounds(o):
        if isinstance(o, dict):
            return {k: without_bounds(v) for k, v in o.items()
                    if k not in ("sigma_crb", "se_over_crb", "crb_note", "bounds_not_estimated")}
        return [without_bounds(v) for v in o] if isinstance(o, list) else o

    full.pop("bounds")
    full, lean = without_bounds(full), without_bounds(lean)
    for r in (full, lean):
        r.pop("absent"), r.pop("elapsed_s"), r.pop("locate"), r.pop("identifiability")
        r.get("settings", {}).pop("absent_bounds", None), r.get("settings", {}).pop("report_detail", None)
    assert json.dumps(lean, sort_keys=True) == json.dumps(full, sort_keys=True)


def test_score_closed_cases():
    truth = {"effects": {"accel_cubic_nonlinearity": {"k3_ug_per_g3": [20.0, -15.0, 10.0]}}}
    found = {"effect": "accel_cubic_nonlinearity", "sensor": "accel", "key": "accel_cubic_nonlinearity/accel",
             "aliases": [], "parameters": [{"name": "k3_ug_per_g3[x]", "value": 19.0, "ci95": [17.0, 21.0], "se": 1.0},
                                           {"name": "k3_ug_per_g3[y]", "value": -11.0, "ci95": [-13.0, -9.0],
                                            "se": 1.0}]}
    s = score({"found": [found]}, truth)
    assert s["correct"] and s["named_exactly"] and not s["false_discoveries"]
    assert [c["covered"] for c in s["coverage"]] == [True, False]
    other = dict(found, effect="accel_scale_asymmetry", key="accel_scale_asymmetry/accel",
                 aliases=[{"effect": "accel_cubic_nonlinearity", "key": "accel_cubic_nonlinearity/accel"}])
    s2 = score({"found": [other]}, truth)
    assert s2["correct"] and not s2["named_exactly"]
    assert score({"found": []}, {"effects": {}})["correct"]
    assert not score({"found": [found]}, {"effects": {}})["correct"]
    conf = {"effects": {"gravity_error": {"delta_g_m_s2": 5e-4}}}
    assert score({"found": [], "untestable": [{"effect": "gravity_error"}]}, conf, "confounded")["correct"]
    g1 = dict(found, effect="gravity_error", aliases=[])
    assert not score({"found": [g1], "untestable": []}, conf, "confounded")["correct"]


@pytest.mark.slow
def test_proof_100_seeds(tmp_path, noise_record):
    """The whole proof (every session of PROOF_SESSIONS, 100 seeds each, the unit's long static record as the
    measured slow noise, as the workflow runs it) on the study's proof root: its gate rejects none of its claims."""
    root = yaml.safe_load((ROOT / "config" / "seed_roots.yaml").read_text())["proof"]["study"]
    out = run_proof(tmp_path, n_seeds=100, seed=root, workers=2, settings={"noise_record": noise_record})
    assert diagnosis_study.rejected_claims(out["sessions"]) == []
    assert all(all(v for v in a.values()) for a in out["acceptance"].values())


def test_proof_stage_products(tmp_path):
    """The workflow's proof stage on the short path: a null session finds nothing, the hidden clock offset
    (10 ms, within the tested +-0.25 s) is named in every seed, and the per-seed netCDF, the power table and
    figure are written with labelled dimensions. Run in two worker processes (the pool, with the power scans queued
    as their sessions finish) and again in one: the same files (every worker seeds itself; the .test profile runs
    the workflow's proof on one thread, so this is where the pool is tested)."""
    base = {**SHORT, "revolutions": 1}
    outs = {}
    for w in (2, 1):
        d = tmp_path / f"workers{w}"
        run = lambda enforce: diagnosis_study.proof_stage(   # noqa: E731
            d, n_seeds=2, first_seed=7, sessions=["null_a", "time_offset"], power_seeds=2, workers=w, base=base,
            site=SHORT["site"], log=lambda *a: None, metrics_path=d / "proof.metrics.json", enforce=enforce)
        if w == 2:
            outs[w] = run(False)
        else:   # enforced, a rejected claim fails the stage with a short message, its files written (no noise
            # record here: the nulls are 'inconclusive', not 'adequate'; 2 intervals cannot test coverage)
            with pytest.raises(ResultCheckError, match=r"the proof's seeds reject \d+ of its claims: null_a: "
                               r"called_adequate_ge_95pct rejected .* \(and \d+ more: proof.md, section Gate\)"):
                run(True)
    for name in ("proof.json", "proof.csv", "proof.md", "power.csv", "proof_rows.json", "proof.metrics.json"):
        assert (tmp_path / "workers2" / name).read_bytes() == (tmp_path / "workers1" / name).read_bytes(), name
    with xr.open_dataset(tmp_path / "workers2" / "proof.nc") as a, xr.open_dataset(tmp_path / "workers1" / "proof.nc") as b:
        xr.testing.assert_identical(a.load(), b.load())
    tmp_path, out = tmp_path / "workers2", outs[2]
    nc = xr.open_dataset(tmp_path / "proof.nc")
    assert list(nc["session"].values) == ["null_a", "time_offset"] and list(nc["seed"].values) == [seeds.child_seed(7, "noise", k) for k in range(2)]
    assert int(nc["false_discovery"].sel(session="null_a").sum()) == 0
    assert int(nc["n_found"].sel(session="null_a").sum()) == 0
    assert nc["correct"].sel(session="time_offset").values.tolist() == [1, 1]
    assert "power_scale" in nc and (tmp_path / "power.png").stat().st_size > 0
    assert (tmp_path / "power.csv").read_text().startswith("effect,smallest_scale_80pct")
    # wall times never enter the scientific files, nor the name of a temporary folder (same config, same bytes)
    assert "elapsed" not in (tmp_path / "proof.json").read_text()
    for f in (tmp_path / "end_to_end").rglob("report.*"):
        assert "calib-proof-" not in f.read_text(), f
    assert json.loads((tmp_path / "end_to_end" / "null_a" / "report.json").read_text())["recording"].startswith("null_a")
    assert "total_s" in (tmp_path / "timings.json").read_text()
    assert out["acceptance"]["null_a"]["false_discoveries_le_5pct"]
    # two seeds of one single effect give 2 intervals: too few to test coverage, which the gate rejects (never skips)
    failed = diagnosis_study.rejected_claims(out["sessions"])
    assert any("coverage_consistent_with_95pct" in f and "fewer than 50" in f for f in failed), failed
    assert json.loads((tmp_path / "proof.metrics.json").read_text())["rejected_claims"] == failed


def test_unknown_settings_and_sessions_refused(tmp_path):
    with pytest.raises(ValueError, match="alpah"):
        diagnosis_study.check_settings({"alpah": 0.01})
    with pytest.raises(ValueError, match="no_such_session"):
        diagnosis_study.proof_stage(tmp_path, 1, 0, sessions=["no_such_session"], log=lambda *a: None)
