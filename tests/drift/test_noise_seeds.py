"""The noise-seed study of the drift stage (calib.studies.drift.run_noise_seeds) leaves its products only (its
scratch folder of one seed's recording at a time is removed again, however the run ends) and reports the estimators
against the independent Cramér–Rao bound."""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

from calib.drift import bound
from calib.studies import drift as drift_study

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def cfg():
    return yaml.safe_load((ROOT / ".test" / "config.yaml").read_text())


def _run(cfg, out, n=2, **kw):
    dcfg = {**cfg["drift"], "window_h": 0.25}
    return drift_study.run_noise_seeds(out / "seeds.nc", out / "seeds.csv", out / "z.png", out / "m.json",
                                       cfg["navigation_session"], cfg["site"], dcfg, n, 77, out / "scratch",
                                       log=lambda *a: None, **kw)


def test_no_scratch_folder_or_seed_file_is_left(tmp_path, cfg):
    _run(cfg, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json", "seeds.csv", "seeds.nc", "z.png"]


def test_an_interrupted_run_leaves_no_seed_file(tmp_path, cfg, monkeypatch):
    from calib.drift import psobe

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(psobe, "load_window", interrupted)   # after the seed's recording is written
    with pytest.raises(KeyboardInterrupt):
        _run(cfg, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_tables_carry_the_independent_bound_and_efficiency(tmp_path, cfg):
    """The noise-seed products carry the Cramér–Rao bound of calib.drift.bound for the session's noise (not the
    Kalman filter's covariance, which stays beside it under its own name), and the efficiency ratio is each
    estimator's spread over the seeds divided by the bound of the model it fits."""
    _run(cfg, tmp_path)
    sess = cfg["navigation_session"]
    q_g, q_a = bound.noise_psd(sess, sess["sample_rate_hz"])
    lat = math.radians(cfg["site"]["latitude_deg"])
    full = bound.drift_bound(0.25, 60.0, lat, np.eye(3), 0.0, q_g, q_a).sigma_deg_h()
    known = bound.drift_bound(0.25, 60.0, lat, np.eye(3), 0.0, q_g, q_a, accel_bias_known=True).sigma_deg_h()
    with xr.open_dataset(tmp_path / "seeds.nc") as ds:
        assert np.allclose(ds["crb"].values, full, rtol=1e-9)
        assert np.allclose(ds["crb_accel_bias_known"].values, known, rtol=1e-9)
        assert not np.allclose(ds["kalman_sigma"].values, full, rtol=1e-6)
        est = ds["estimate"]
        for m in ds["estimator"].values:
            ref = known if m == "pso" else full
            assert np.allclose(ds["efficiency"].sel(estimator=m).values,
                               est.sel(estimator=m).values.std(0, ddof=1) / ref, rtol=1e-9)
    rows = list(csv.DictReader(open(tmp_path / "seeds.csv")))
    assert {r["estimator"] for r in rows} == {"kalman", "lls_with_accel_bias", "pso"}
    for r in rows:
        assert float(r["crb_deg_h"]) == pytest.approx(full["xyz".index(r["axis"])], rel=1e-5)


def test_blocks_of_seeds_hold_the_numbers_of_one_run(tmp_path, cfg):
    """Every seed draws from its own streams (its index): seeds 0..2 run as blocks [0, 1) and [1, 3), written for
    the gathering job and read back, give the estimates of one run over the three seeds to the bit, and the
    gathered products are those of one run, byte for byte."""
    dcfg = {**cfg["drift"], "window_h": 0.25}
    sess, site = cfg["navigation_session"], cfg["site"]
    one = drift_study.noise_seed_block(sess, site, dcfg, 77, 0, 3, tmp_path / "s", progress=False)
    parts = []
    for first, stop in ((1, 3), (0, 1)):   # in any order
        b = drift_study.noise_seed_block(sess, site, dcfg, 77, first, stop, tmp_path / f"s{first}", progress=False)
        parts.append(drift_study.write_noise_seed_block(b, tmp_path / "parts" / f"{first}_{stop}.json"))
    blocks = drift_study.read_noise_seed_blocks(parts)
    for m in drift_study.NOISE_SEED_ESTIMATORS:
        joined = np.concatenate([b["estimates"][m] for b in blocks])
        assert joined.tobytes() == one["estimates"][m].tobytes(), m
    assert all(b["geometry"] == one["geometry"] for b in blocks)
    (tmp_path / "one").mkdir()
    (tmp_path / "gathered").mkdir()
    _run(cfg, tmp_path / "one", 3)
    g = tmp_path / "gathered"
    drift_study.noise_seed_products(blocks, g / "seeds.nc", g / "seeds.csv", g / "z.png", g / "m.json", sess, dcfg,
                                    3, 77, log=lambda *a: None, workdir=tmp_path / "s")
    for name in ("seeds.csv", "m.json"):
        assert (g / name).read_bytes() == (tmp_path / "one" / name).read_bytes()
    with xr.open_dataset(g / "seeds.nc") as a, xr.open_dataset(tmp_path / "one" / "seeds.nc") as b:
        xr.testing.assert_identical(a, b)
    assert not (tmp_path / "s").exists()   # the study's scratch folder, empty, is removed by the gathering


@pytest.mark.parametrize("spans, n, message", [
    ([(0, 2), (3, 5)], 5, "seeds 2 .. 2 missing or given twice"),
    ([(0, 3), (2, 5)], 5, "seeds 2 .. 2 missing or given twice"),
    ([(1, 5)], 5, "seeds 0 .. 0 missing or given twice"),
    ([(0, 2), (2, 4)], 5, "drift.noise_seeds: 5 seeds configured, the blocks hold seeds 0 .. 3"),
])
def test_gathering_refuses_missing_or_repeated_seeds(tmp_path, cfg, spans, n, message):
    """The gathering job names the seeds a set of blocks lacks or holds twice, and writes nothing."""
    blocks = [{"first": a, "stop": b, "estimates": {m: np.zeros((b - a, 3)) for m in drift_study.NOISE_SEED_ESTIMATORS},
               "kalman_sigma": np.ones((b - a, 3)), "geometry": {}} for a, b in spans]
    with pytest.raises(ValueError, match=re.escape(message)):
        drift_study.noise_seed_products(blocks, tmp_path / "seeds.nc", tmp_path / "seeds.csv", tmp_path / "z.png",
                                        tmp_path / "m.json", cfg["navigation_session"], cfg["drift"], n, 77)
    assert list(tmp_path.iterdir()) == []


def test_gathering_refuses_blocks_of_different_windows(tmp_path, cfg):
    blocks = [{"first": a, "stop": b, "estimates": {m: np.zeros((1, 3)) for m in drift_study.NOISE_SEED_ESTIMATORS},
               "kalman_sigma": np.ones((1, 3)), "geometry": {"n_steps": n}} for a, b, n in ((0, 1, 7200), (1, 2, 1800))]
    with pytest.raises(ValueError, match="their windows differ"):
        drift_study.noise_seed_products(blocks, tmp_path / "seeds.nc", tmp_path / "seeds.csv", tmp_path / "z.png",
                                        tmp_path / "m.json", cfg["navigation_session"], cfg["drift"], 2, 77)
