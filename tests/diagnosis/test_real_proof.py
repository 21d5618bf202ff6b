"""Real recordings as proof bases: the block resampling and the injection against their definitions, detection
limits (calib.diagnosis.limits) and the injection proof (calib.studies.real_proof) on a shared recording, the
refusal of degenerate explanations. Expected answers are properties of the injected physics or of the definitions,
never numbers captured from the diagnosis."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib.core import seeds
from calib.diagnosis import limits
from calib.studies import real_proof as rp
from calib.studies.diagnosis_real import import_real

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT.parent / "shared" / "data"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"shared real-data directory {REAL} is missing")


@pytest.fixture(scope="module")
def mikoff():
    return limits.ProofBase(import_real(ROOT / "config" / "import" / "mikoff_imu0.yaml"), name="mikoff_imu0")


@needs_real
def test_block_resampling_keeps_each_segment_mean_level_and_leaves_the_rest(mikoff):
    y = mikoff.resample(seeds.stream(41, "test"), block_s=1.0)
    static = np.zeros(len(y), bool)
    for idx in mikoff.segments:
        static[idx] = True
        a, b = mikoff.y[idx], y[idx]
        # the same samples' noise, re-ordered by blocks: the spread is kept, the mean moves by about sigma/sqrt(m)
        assert np.allclose(b.std(0), a.std(0), rtol=0.25)
        lim = 8.0 * a.std(0) * np.sqrt(100.0 / len(idx))       # generous: 1 s blocks of correlated noise
        assert np.all(np.abs(b.mean(0) - a.mean(0)) <= lim)
    assert np.array_equal(y[~static], mikoff.y[~static])
    assert not np.array_equal(y[static], mikoff.y[static])


@needs_real
def test_injection_is_the_transfer_function_on_the_recovered_input(mikoff):
    y = mikoff.y
    out = mikoff.inject(y, {"effect": "accel_quadratic_nonlinearity", "axis": "y", "value": 3000.0})
    g = mikoff.gain[1]
    u = (y[:, 1] - mikoff.b[1]) / g
    assert np.allclose((out[:, 1] - mikoff.b[1]) / g - u, 3000e-6 * u ** 2, rtol=0, atol=1e-12)
    assert np.array_equal(out[:, [0, 2]], y[:, [0, 2]])
    step = mikoff.inject(y, {"effect": "bias_step", "axis": "z", "ug": 500.0})
    d = (step[:, 2] - y[:, 2]) / mikoff.gain[2] * 1e6
    assert np.allclose(np.unique(np.round(d, 6)), [0.0, 500.0])


@needs_real
def test_limits_and_proof_on_a_real_recording(mikoff):
    """On mikoff imu0 (22 static poses): the untouched recording names nothing; a quadratic nonlinearity on x has
    a finite detection limit; at twice it the term is named in every injection and its interval holds the injected
    value; out-of-library effects at twice the size at which their misfit is seen are never explained; nothing
    degenerate is accepted."""
    assert mikoff.baseline["verdict"] == "adequate" and not mikoff.baseline["found"]
    lim = limits.detection_limits(mikoff, reps=4, seed=5101, effects=["accel_quadratic_nonlinearity"], axes=("x",),
                                  progress=False)
    k2 = [r for r in lim if r["kind"] == "library"][0]
    assert k2["detectable"] and 2.0 * abs(k2["baseline_se"]) <= abs(k2["limit"]) <= 20.0 * abs(k2["baseline_se"])
    res = rp.prove(mikoff, lim, n_inject=8, n_out=2, seed=5102, progress=False)
    acc = rp.acceptance(res)
    assert all(v is not False for v in acc.values()), (acc, res)
    assert res["in_library"][0]["named"] == 8


@needs_real
def test_a_recording_with_too_few_poses_says_not_detectable_at_any_magnitude():
    base = limits.ProofBase(import_real(ROOT / "config" / "import" / "smac_adis16405.yaml"), name="adis")
    lim = limits.detection_limits(base, reps=2, seed=1, axes=("x",), progress=False)
    assert lim and all(r["limit"] is None and not r["detectable"] for r in lim)
    assert all(r.get("experiment") for r in lim if r["kind"] == "library")
    md = "\n".join(limits.limits_markdown(lim))
    assert "not detectable at any magnitude" in md


def test_degenerate_explanations_are_flagged():
    ok = {"found": [{"key": "k", "effect": "accel_quadratic_nonlinearity", "parameters": [{"name": "a", "value": 1.0}]}],
          "goodness_of_fit": {"after": {"chi2": 10.0, "dof": 12}}}
    assert limits.degenerate_accepted(ok) == []
    g = {"found": [{"key": "gravity_error", "effect": "gravity_error",
                    "parameters": [{"name": "delta_g_m_s2", "value": 4.9}]}],
         "goodness_of_fit": {"after": {"chi2": 1e-23, "dof": 12}}}
    bad = limits.degenerate_accepted(g)
    assert len(bad) == 2 and "4.9" in bad[0] and "dof" in bad[1]


@needs_real
def test_the_stage_gives_the_same_files_with_one_or_two_workers(tmp_path):
    """The real-recording proof stage (the workflow's rule; the .test profile runs it on one thread) writes the same
    bytes whether its recordings run in two forked workers or one after the other: a usable proof base (mikoff) and
    one with too few poses (smac), each seeded by its own name."""
    files = {}
    for w in (2, 1):
        out = tmp_path / f"w{w}"
        rp.real_proof_stage(out, ROOT / "config" / "import", reps=2, n_inject=2, n_out=1, axes=("x",),
                            recordings=["mikoff_imu0", "smac_adis16405"], workers=w, enforce=False,
                            log=lambda *a: None)
        files[w] = {p.name: p.read_bytes() for p in sorted(out.iterdir())}
    assert sorted(files[2]) == ["limits.csv", "limits.png", "real_proof.json", "real_proof.md"]
    assert files[2] == files[1]
    assert [r["usable"] for r in json.loads(files[2]["real_proof.json"])["recordings"]] == [True, False]
