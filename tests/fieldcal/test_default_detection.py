"""Defaults that work: ``calib fieldcal FILE`` without settings chooses the static-interval
detection itself (calib.fieldcal.default_detection) and either matches the tuned settings or exits 3 naming the
settings key to change.

Acceptance, over the static-pose protocols of ``conftest.protocol_session`` (initial rest 2-60 s, waits 1-5 s,
9-40 poses, noise x0.5-x10 of a typical MEMS IMU, SI or raw counts; the truth known): every session is run as
``calib fieldcal`` runs it -- :func:`calib.fieldcal.fieldcal_recording` without settings, then the result check
:func:`calib.signal.plausibility.check_fieldcal_result` (a refused result is written for inspection, exit 3) --
and compared with the tuned settings, the detection on the *true* static intervals (the norm fit on all their
samples). A session is **good** when it exits 0 and

* its calibration leaves a norm residual over the true static samples within 1 % of the tuned one's (which
  minimises it: the same samples for both, so that the comparison judges the calibrations, not which samples
  each fitted), and
* every accel scale factor lies within its stated interval, 3 x its standard error (``scale_factor_std`` of the
  fit), of the truth, the interval widened by the tuned settings' own error: the per-sample norm fit is biased
  by the noise at high noise and weak pose sets, by more than its standard error states, on the true intervals as
  much as on any (``benchmarks/bench_default_detection.py`` reports both coverages); what is tested here is the
  detection, not that estimator.

Sessions whose true intervals leave an accel parameter not determined (a pose set spanning too little:
``Determination``) have no tuned result to match; they must exit 3 or exit 0 with a plausible result, and are left
out of the rate. Asserted: at least 95 % of the other sessions are good, the rest exit 3 naming a settings key, and
no session exits 0 with a result outside the plausibility bounds.

Seeds: 0-199 tuned the constants of calib.fieldcal.default_detection (CONTAMINATION, ODD_MEAN_K, MIN_SUPPORT,
VALIDATION_VOTE, TIE_TOLERANCE, RANK_MAX_NFEV), with 1000-1011 and 2000-2079 looked at while writing it; the CI
test uses 10000-10029 and the slow one 10030-10229. Seeds 10146 and 10186 of the slow set (a spurious interval in
a permissive detection; a pose set on the edge of determining the model) failed a first version and led to
MIN_SUPPORT and to preferring a result that determines every parameter: the slow set is not wholly untouched.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import protocol_dataset, protocol_session

from calib.core.errors import CalibError, ResultCheckError
from calib.fieldcal import fieldcal_recording
from calib.fieldcal.accelerometer import fit_accel_norm, norm_residual_rms
from calib.io import recording
from calib.signal import plausibility

CI_SEEDS = range(10000, 10030)
SLOW_SEEDS = range(10030, 10230)
RESIDUAL_TOLERANCE = 0.01
K_SIGMA = 3.0
MIN_GOOD = 0.95


def tuned(s, ds):
    """The tuned settings' calibration: the norm fit on the true static intervals, all their samples."""
    acc = np.asarray(ds["accel"].values, dtype=float)
    return fit_accel_norm(acc, s["intervals"], s["gravity"], input_units="count" if s["units"] == "count" else "m s-2")


def settings_key_named(exc) -> bool:
    """Whether a refusal names a settings key of the field calibration to change."""
    text = f"{exc.field or ''} {exc.fix or ''}"
    return "detection." in text or "fieldcal.detection" in text


def judge(seed) -> dict:
    """One session run as ``calib fieldcal`` runs it, against the tuned settings and the truth."""
    s = protocol_session(seed)
    ds = protocol_dataset(s)
    ref = tuned(s, ds)
    counts = s["units"] == "count"
    out = {"seed": seed, "units": s["units"], "n_poses": s["n_poses"], "noise": s["noise"], "rest_s": s["rest_s"],
           "min_wait_s": s["min_wait_s"], "determinable": not ref.determination.held and
           bool(np.all(np.isfinite(ref.scale_factor_std)))}
    try:
        res = fieldcal_recording(ds, {"gravity_m_s2": s["gravity"]})
    except ResultCheckError as exc:
        return {**out, "exit": 3, "key_named": settings_key_named(exc), "message": exc.message}
    except CalibError as exc:
        return {**out, "exit": exc.exit_code, "message": exc.message}
    status = (res.detection_choice or {}).get("status")
    try:
        plausibility.check_fieldcal_result(res, counts, counts, "session")
    except ResultCheckError as exc:   # written for inspection, exit 3
        return {**out, "exit": 3, "key_named": settings_key_named(exc), "status": status, "message": exc.message}
    acc = np.asarray(ds["accel"].values, dtype=float)
    rel = norm_residual_rms(res.accel.apply(acc), s["gravity"], s["intervals"]) / ref.residual_rms - 1.0
    truth = np.asarray(s["accel_scale_factors"])
    se = np.asarray(res.accel.scale_factor_std, dtype=float)
    allowed = K_SIGMA * se + np.abs(np.asarray(ref.scale_factors) - truth)
    err = np.abs(np.asarray(res.accel.scale_factors) - truth)
    sf_ok = bool(np.all(np.isfinite(se)) and np.all(err <= allowed))
    ref_se = np.asarray(ref.scale_factor_std, dtype=float)
    return {**out, "exit": 0, "status": status, "residual_rel": float(rel), "sf_ok": sf_ok,
            "sf_in_stated_interval_of_truth": bool(np.all(err <= K_SIGMA * se)),
            "tuned_sf_in_stated_interval_of_truth": bool(np.all(np.abs(ref.scale_factors - truth)
                                                                <= K_SIGMA * ref_se)),
            "n_intervals": int(len(res.intervals)), "chosen": res.detection_choice["chosen"]["detection"],
            "chosen_poses": res.detection_choice["chosen"]["n_poses"]}


def good(r) -> bool:
    return r["exit"] == 0 and r["residual_rel"] <= RESIDUAL_TOLERANCE and r["sf_ok"]


def describe(rows) -> str:
    return "\n".join(f"{r['seed']}: {r['units']} {r['n_poses']} poses, noise x{r['noise']:.2f}, exit {r['exit']}"
                     + (f", residual {100 * r['residual_rel']:+.3f} %, scale factors {'in' if r['sf_ok'] else 'OUT'}"
                        if r["exit"] == 0 else f": {r.get('message', '')[:200]}") for r in rows)


def check_acceptance(rows):
    det = [r for r in rows if r["determinable"]]
    assert len(det) >= 0.8 * len(rows), describe(rows)           # the generator gives mostly determinable sessions
    for r in rows:
        assert r["exit"] in (0, 3), describe([r])                  # no input refusal, no crash
        if r["exit"] == 3:
            assert r["key_named"], describe([r])                   # names the settings key to change
        elif r.get("status") is not None:
            assert r["status"] == "passed", describe([r])          # a result the default marked failed exits 3
    for r in det:
        assert good(r) or r["exit"] == 3, describe([r])          # the rest exit 3
    n_good = sum(good(r) for r in det)
    assert n_good >= MIN_GOOD * len(det), describe([r for r in det if not good(r)])


@pytest.fixture(scope="module")
def ci_rows():
    return [judge(seed) for seed in CI_SEEDS]


def test_default_detection_matches_the_tuned_settings(ci_rows):
    check_acceptance(ci_rows)


@pytest.mark.slow
def test_default_detection_matches_the_tuned_settings_200_sessions():
    check_acceptance([judge(seed) for seed in SLOW_SEEDS])


# ------------------------------------------------------------------------------------------- protocol timing


def _few_pose_session():
    """Ten poses after a 20 s rest: fewer than the 12 distinct poses recommended, all of the protocol's."""
    return protocol_session(31, rest_s=20.0, n_poses=10, min_wait_s=3.0, noise=1.0, units="SI")


def test_protocol_timing_from_the_recording_is_used_and_reported(tmp_path):
    s = _few_pose_session()
    path = recording.write(protocol_dataset(s, protocol_attrs=True), tmp_path / "protocol.nc")
    r = fieldcal_recording(path, {"gravity_m_s2": s["gravity"]})   # the attributes survive the file
    ch = r.detection_choice
    assert ch["status"] == "passed"
    assert ch["protocol"]["initial_rest_s"] == pytest.approx(20.0)
    assert ch["protocol"]["min_wait_s"] == pytest.approx(3.0) and ch["protocol"]["n_poses"] == 10
    assert ch["protocol"]["source"] == {k: f"recording attribute protocol_{k}"
                                        for k in ("initial_rest_s", "min_wait_s", "n_poses")}
    assert "protocol initial_rest_s = 20" in ch["line"]
    # used: the rest fixes every variance rule's reference span and IMU-TK's initial samples, half the shortest
    # wait is a minimum interval length, and the poses + the rest make a complete detection
    dets = [d for c in ch["candidates"] for d in [c["detection"], *c["same_intervals_as"]]]
    assert all(d["init_s"] == pytest.approx(20.0) for d in dets if d["rule"] == "detect")
    assert any(d["rule"] == "imu_tk" and d["init_samples"] == 1999 for d in dets)
    assert any(d["rule"] == "detect" and d["min_interval_s"] == pytest.approx(1.5) for d in dets)
    assert ch["need_poses"] == 11 and ch["chosen"]["n_poses"] == 11 and len(r.intervals) == 11
    assert "none has" not in ch["line"]
    # the same session without the protocol: fewer poses than recommended, said
    r0 = fieldcal_recording(protocol_dataset(s), {"gravity_m_s2": s["gravity"]})
    assert "protocol" not in r0.detection_choice and r0.detection_choice["need_poses"] == 12
    assert "none has 12 distinct poses" in r0.detection_choice["line"] and len(r0.intervals) == 11
    assert any("the one with the most (11) is used" in n for n in r0.notes)


def test_protocol_section_of_the_settings_wins_over_the_recording():
    s = _few_pose_session()
    r = fieldcal_recording(protocol_dataset(s, protocol_attrs=True),
                           {"gravity_m_s2": s["gravity"], "protocol": {"initial_rest_s": 15.0}})
    p = r.detection_choice["protocol"]
    assert p["initial_rest_s"] == 15.0 and p["source"]["initial_rest_s"] == "settings protocol.initial_rest_s"
    assert p["source"]["n_poses"] == "recording attribute protocol_n_poses"
    assert all(c["detection"]["init_s"] == 15.0 for c in r.detection_choice["candidates"]
               if c["rule"] == "detect")
    with pytest.raises(ValueError, match="protocol.rest_s"):
        fieldcal_recording(protocol_dataset(s), {"protocol": {"rest_s": 15.0}})
    with pytest.raises(ValueError, match="protocol.n_poses"):
        fieldcal_recording(protocol_dataset(s), {"protocol": {"n_poses": -3}})


def test_choice_is_reproducible_from_its_settings():
    """The chosen detection, given as the settings' ``detection``, gives the same intervals and calibration."""
    s = protocol_session(32, rest_s=10.0, n_poses=16, min_wait_s=1.5, noise=2.0, units="count")
    ds = protocol_dataset(s)
    r = fieldcal_recording(ds, {"gravity_m_s2": s["gravity"]})
    chosen = r.detection_choice["chosen"]["detection"]
    again = fieldcal_recording(ds, {"gravity_m_s2": s["gravity"], "detection": chosen})
    np.testing.assert_array_equal(again.intervals, r.intervals)
    # the same minimum, reached from the ellipsoid start instead of the ranking's fit
    np.testing.assert_allclose(again.accel.scale_factors, r.accel.scale_factors, rtol=1e-8)
    assert again.detection_choice is None and "chosen without detection settings" in r.detection_rule
    assert r.summary()["detection_choice"]["chosen"] == r.detection_choice["chosen"]
    assert "candidates" not in r.summary()["detection_choice"]


# ------------------------------------------------------------------------------------------------ refusals


def test_a_static_recording_exits_3_naming_the_keys():
    s = protocol_session(33, rest_s=60.0, n_poses=0, noise=1.0, units="SI")
    with pytest.raises(ResultCheckError) as e:
        fieldcal_recording(protocol_dataset(s), {"gravity_m_s2": s["gravity"]})
    assert e.value.exit_code == 3 and e.value.field == "fieldcal.detection"
    assert "finds 9 distinct static poses" in e.value.message
    assert "record at least 12 distinct static poses" in e.value.fix and "fieldcal.detection.k" in e.value.fix


def test_an_implausible_default_result_is_returned_failed():
    """Accelerometer x counts tripled: no candidate gives plausible scale factors; the best ranked one is returned
    marked failed, and the result check of calib fieldcal refuses it (exit 3) naming the detection keys."""
    s = protocol_session(34, rest_s=20.0, n_poses=20, min_wait_s=2.0, noise=1.0, units="count")
    s["accel"][:, 0] *= 3
    r = fieldcal_recording(protocol_dataset(s), {"gravity_m_s2": s["gravity"]})
    assert r.detection_choice["status"] == "failed" and "returned for inspection" in r.detection_choice["line"]
    assert any("failed the result checks" in n for n in r.notes)
    with pytest.raises(ResultCheckError, match="accel scale factors") as e:
        plausibility.check_fieldcal_result(r, True, True, "session")
    assert "detection.threshold" in e.value.fix
    assert r.to_dataset().attrs["detection_choice_status"] == "failed"
    assert math.isfinite(r.accel.residual_rms)
