"""Detection limits and the real-recording proof read in the field's units: an accelerometer asymmetry is reported as
the scale factor asymmetry (K+ - K-) / Kbar of IEEE Std 1293 (``scale_factor_asymmetry_ppm``), twice the internal
``asym_ppm`` d of the term d |y| the injections use (kept only where labelled as the internal model parameter).

The truth is the injection itself: the readings of a shared recording with an asymmetry injected, K+ and K- taken
from them by the definition (output over input for inputs above and below zero), never a number the reporting code
printed."""
from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

from calib import cli
from calib.diagnosis import limits
from calib.studies import real_proof as rp
from calib.studies.diagnosis_real import import_real

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT.parent / "shared" / "data"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"shared real-data directory {REAL} is missing")
ASYM = "accel_scale_asymmetry"


@pytest.fixture(scope="module")
def mikoff():
    return limits.ProofBase(import_real(ROOT / "config" / "import" / "mikoff_imu0.yaml"), name="mikoff_imu0")


@pytest.fixture(scope="module")
def asym_rows(mikoff):
    """The detection limit of the asymmetry on x, as the proof uses it (internal asym_ppm)."""
    return limits.detection_limits(mikoff, reps=2, seed=7301, effects=[ASYM], axes=("x",), out_of_library=False,
                                   progress=False)


def measured_asymmetry_ppm(base, internal_value: float, axis: int = 0) -> float:
    """(K+ - K-) / Kbar in ppm of an asymmetry of internal size ``internal_value`` injected into ``base``'s readings on
    ``axis``: K+ and K- the ratios of injected to untouched input (bias removed) over the samples with input above
    +0.3 g and below -0.3 g."""
    y0 = base.y
    y1 = base.inject(y0, {"effect": ASYM, "axis": "xyz"[axis], "value": internal_value})
    u0 = y0[:, axis] - base.b[axis]
    u1 = y1[:, axis] - base.b[axis]
    g = 0.3 * base.gain[axis]
    assert (u0 > g).sum() > 100 and (u0 < -g).sum() > 100, "the recording turns this axis through +-1 g"
    kp = np.median(u1[u0 > g] / u0[u0 > g])
    km = np.median(u1[u0 < -g] / u0[u0 < -g])
    return float((kp - km) / (0.5 * (kp + km)) * 1e6)


def _products(tmp_path, result):
    rp.real_proof_products(tmp_path, [result], enforce=False, log=lambda *a: None)
    return (list(csv.DictReader(io.StringIO((tmp_path / "limits.csv").read_text()))),
            json.loads((tmp_path / "real_proof.json").read_text()), (tmp_path / "real_proof.md").read_text())


@needs_real
def test_an_asymmetry_limit_row_carries_the_standard_name_and_twice_the_internal_limit(mikoff, asym_rows, tmp_path):
    (row,) = asym_rows
    assert row["parameter"] == "asym_ppm[x]" and row["detectable"], row
    lim, se = row["limit"], row["baseline_se"]
    # the reported figure is the standard one: the internal limit injected gives (K+ - K-)/Kbar = 2 x it
    assert measured_asymmetry_ppm(mikoff, lim) == pytest.approx(2.0 * lim, rel=1e-6)
    result = {"recording": "mikoff_imu0", "usable": False, "why": "limits only", "limits": asym_rows,
              "baseline": {"verdict": "adequate", "reason": "", "found": []}}
    rows, js, md = _products(tmp_path, result)
    (r,) = rows
    assert r["parameter"] == "scale_factor_asymmetry_ppm[x]"
    assert r["detection_limit"] == f"{2.0 * lim:.6g}" and r["baseline_se"] == f"{2.0 * se:.6g}"
    assert "asym_ppm" not in (tmp_path / "limits.csv").read_text()
    (jr,) = js["recordings"][0]["limits"]
    assert jr["parameter"] == "scale_factor_asymmetry_ppm[x]" and jr["limit"] == 2.0 * lim
    assert [p["value"] for p in jr["points"]] == [2.0 * p["value"] for p in row["points"]]
    assert jr["internal_model_parameter"]["parameter"] == "asym_ppm[x]"
    assert jr["internal_model_parameter"]["limit"] == lim
    (line,) = [x for x in md.splitlines() if x.startswith(f"| {ASYM} | x |")]
    assert "| scale_factor_asymmetry_ppm[x] |" in line and f"| {abs(2.0 * lim):.4g} |" in line


@needs_real
def test_calib_diagnose_limits_reports_the_standard_asymmetry(mikoff, asym_rows, tmp_path, monkeypatch):
    """``calib diagnose FILE --limits``: report.json and report.md give the asymmetry limit as the standard figure
    (the limits themselves are the fixture's, so the command measures none again)."""
    rec = tmp_path / "mikoff.nc"
    assert cli.main(["import", str(ROOT / "config" / "import" / "mikoff_imu0.yaml"), str(rec)]) == 0
    monkeypatch.setattr(limits, "detection_limits", lambda base, **kw: asym_rows)
    cli.main(["diagnose", str(rec), "--out", str(tmp_path / "out"), "--limits", "--limits-reps", "2"])
    (r,) = json.loads((tmp_path / "out" / "report.json").read_text())["detection_limits"]["rows"]
    lim = asym_rows[0]["limit"]
    assert r["parameter"] == "scale_factor_asymmetry_ppm[x]" and r["limit"] == 2.0 * lim
    assert r["internal_model_parameter"]["parameter"] == "asym_ppm[x]" and r["internal_model_parameter"]["limit"] == lim
    md = (tmp_path / "out" / "report.md").read_text()
    assert f"| {ASYM} | x | scale_factor_asymmetry_ppm[x] | {abs(2.0 * lim):.4g} |" in md


@needs_real
def test_an_injected_8_ppm_asymmetry_is_reported_as_8(mikoff, asym_rows, tmp_path):
    """The proof at twice a limit of 2 ppm internal injects d = 4 ppm: a scale factor asymmetry of 8 ppm in the
    readings, which the products report as 8, not 4."""
    row = {**asym_rows[0], "limit": 2.0, "detectable": True}
    res = rp.prove(mikoff, [row], n_inject=2, n_out=0, seed=7302, factor=2.0, progress=False)
    truth = measured_asymmetry_ppm(mikoff, 2.0 * row["limit"])      # what prove injects: factor x limit
    assert truth == pytest.approx(8.0, rel=1e-6)
    result = {"recording": "mikoff_imu0", "usable": True, "limits": [row], "proof": res,
              "acceptance": rp.acceptance(res), "baseline": {"verdict": "adequate", "reason": "", "found": []}}
    _, js, md = _products(tmp_path, result)
    (q,) = js["recordings"][0]["proof"]["in_library"]
    assert q["values"]["x"] == pytest.approx(truth, rel=1e-6)
    assert q["parameter"] == "scale_factor_asymmetry_ppm"
    assert q["internal_model_parameter"]["values"]["x"] == pytest.approx(truth / 2.0, rel=1e-6)
    assert f"| {ASYM}, scale_factor_asymmetry_ppm (x: 8) |" in md
