"""Repeated norm diagnoses of one recording (the real-recording proof's repetitions and injections): what is reused
across them -- the geometry, the window means of the input-free terms, the whitened rival columns -- and the rival
search that solves only the rivals that can win give the numbers of a diagnosis from scratch, bit for bit."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from calib import diagnosis as dg
from calib.diagnosis import generic
from calib.diagnosis.limits import ProofBase
from calib.studies.diagnosis_real import import_real

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT.parent / "shared" / "data"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"shared real-data directory {REAL} is missing")


class _Prob:
    """What the rival search reads of a problem: the whitened data and their count."""

    def __init__(self, yw):
        self.yw = yw

    @property
    def n(self):
        return self.yw.size

    def wcache(self, key, fn):
        return self.yw


class _Fit:
    def __init__(self, k):
        self.k = k


def _every_rival(prob, f0, base, cands):
    """The first smallest BIC over every rival, each solved by lstsq (the definition)."""
    out = []
    for name, Sw, extra in cands:
        chi2, bic = generic._bic_with_whitened(prob, f0, Sw, base)
        out.append((name, chi2, bic if extra is None else bic + extra))
    return min(out, key=lambda c: c[2])


def _rivals(rng, m, X, y, kind):
    """Rival column sets of widths 1, 2, 3 and 6 around a design: random ones, one in the design's span (rank
    deficient), exact duplicates (equal BICs: the first must win), and, for ``kind == "planted"``, the columns that
    made the data (a clear winner)."""
    cands = []
    for j in range(40):
        w = (1, 2, 3, 6)[j % 4]
        cands.append((f"random {j}", rng.standard_normal((m, w)), None if j % 5 == 0 else math.log(m)))
    cands.append(("in the span", X[:, :2] @ rng.standard_normal((2, 3)), math.log(m)))
    cands.append(("zero column", np.zeros((m, 1)), math.log(m)))
    cands.insert(7, ("duplicate", cands[3][1].copy(), cands[3][2]))
    if kind == "planted":
        cands.insert(20, ("planted", y[:, None] - X @ rng.standard_normal((X.shape[1], 1)), math.log(m)))
    return cands


@pytest.mark.parametrize("kind", ["noise", "planted", "scaled"])
@pytest.mark.parametrize("seed", range(6))
def test_rival_search_gives_the_rival_every_lstsq_gives(kind, seed):
    """The rival of smallest BIC, its chi-square and BIC are those of lstsq over every rival, for designs of very
    different column scales (whitened designs are), rank-deficient and duplicated rivals and a planted winner."""
    rng = np.random.default_rng(seed)
    m, p = 22, 9
    X = rng.standard_normal((m, p))
    if kind == "scaled":
        X *= np.logspace(-3, 4, p)[None, :]
    y = X @ rng.standard_normal(p) + rng.standard_normal(m) * (1e-3 if kind == "scaled" else 1.0)
    prob, f0 = _Prob(y), _Fit(p)
    base = (X, int(np.linalg.matrix_rank(X)))
    cands = _rivals(rng, m, X, y, kind)
    got = generic._best_rival(prob, f0, base, cands)
    assert got == _every_rival(prob, f0, base, cands)
    if kind == "planted":
        assert got[0] == "planted"


def test_rival_search_solves_every_rival_when_the_design_is_rank_deficient():
    rng = np.random.default_rng(3)
    X = rng.standard_normal((22, 9))
    X[:, 4] = X[:, 3]
    y = rng.standard_normal(22)
    base = (X, int(np.linalg.matrix_rank(X)))
    assert generic._projected_bics(_Prob(y), _Fit(9), base, [("a", rng.standard_normal((22, 2)), None)]) is None
    cands = _rivals(rng, 22, X, y, "noise")
    assert generic._best_rival(_Prob(y), _Fit(9), base, cands) == _every_rival(_Prob(y), _Fit(9), base, cands)


def _report(rep):
    return json.dumps({k: v for k, v in rep.items() if k != "elapsed_s"}, sort_keys=True, default=str)


@needs_real
def test_norm_diagnosis_on_a_shared_geometry_is_the_diagnosis_from_scratch():
    """A resampled repetition with an injected term diagnosed on the baseline's geometry (what the proof does) gives
    the report of the same recording diagnosed from scratch, bit for bit; so does the baseline diagnosed again on
    its own geometry after repetitions have used it."""
    ds = import_real(ROOT / "config" / "import" / "imu_tk_xsens.yaml")
    base = ProofBase(ds, {"figures": False}, name="xsens")
    st = {**base.settings, "absent_bounds": False}
    for k, spec in enumerate([{"effect": "accel_cubic_nonlinearity", "axis": "y", "value": 3000.0},
                              {"effect": "bias_step", "axis": "x", "ug": 3000.0}]):
        y = base.inject(base.resample(np.random.default_rng(k)), spec)
        shared, prob = dg.diagnose_dataset(base.dataset(y), None, st, path="rep", geometry_from=base.prob)
        assert prob.geom is base.prob.geom
        fresh, prob2 = dg.diagnose_dataset(base.dataset(y), None, st, path="rep")
        assert prob2.geom is not base.prob.geom
        assert _report(shared) == _report(fresh)
        assert np.array_equal(prob.X0, prob2.X0)
        for c, c2 in zip(prob.lib, prob2.lib):
            assert (c.S is None and c2.S is None) or np.array_equal(c.S, c2.S)
            assert all(np.array_equal(c.S_by_tau[t], c2.S_by_tau[t]) for t in c.S_by_tau)
    again, _ = dg.diagnose_dataset(ds, None, base.settings, path="xsens (untouched)", geometry_from=base.prob)
    assert _report(again) == _report(base.baseline)


def test_resample_is_the_block_bootstrap_of_each_segment():
    """The block bootstrap (segment mean plus circularly shifted blocks of the segment's own noise), written out
    from its definition, against ProofBase.resample for the same random stream."""
    rng = np.random.default_rng(0)
    n, fs = 400, 10.0
    y = rng.standard_normal((n, 3)) + np.arange(3)
    base = ProofBase.__new__(ProofBase)
    base.y, base.fs = y, fs
    base.segments = [np.arange(10, 90), np.arange(120, 127), np.concatenate([np.arange(200, 230), np.arange(240, 260)])]
    for block_s in (1.0, 0.35):
        for seed in range(3):
            want = y.copy()
            r = np.random.default_rng(seed)
            for idx in base.segments:
                m = idx.size
                L = max(1, min(int(round(block_s * fs)), m // 4))
                e = y[idx] - y[idx].mean(axis=0)
                starts = r.integers(0, m, size=-(-m // L))
                take = np.concatenate([(s + np.arange(L)) % m for s in starts])[:m]
                want[idx] = y[idx].mean(axis=0) + e[take]
            assert np.array_equal(base.resample(np.random.default_rng(seed), block_s), want)


@needs_real
def test_a_repetition_dataset_holds_its_samples_and_leaves_the_recording_untouched():
    ds = import_real(ROOT / "config" / "import" / "imu_tk_xsens.yaml")
    base = ProofBase(ds, {"figures": False}, name="xsens")
    before = np.array(ds["accel"].values, copy=True)
    y = base.y + 1.0
    d = base.dataset(y)
    want = y / base.fs if ds["accel"].attrs.get("sample_kind") == "increment" else y
    assert np.array_equal(d["accel"].values, want)
    assert d["accel"].attrs == ds["accel"].attrs and d["accel"].dims == ds["accel"].dims
    assert np.array_equal(ds["accel"].values, before)
    assert all(d[k] is not None and np.array_equal(d[k].values, ds[k].values) for k in ds.data_vars if k != "accel")
