"""The noise-seed study of the drift stage (calib.studies.drift.run_noise_seeds) leaves its products only (its
scratch folder of one seed's recording at a time is removed again, however the run ends) and reports the estimators
against the independent Cramér–Rao bound."""
from __future__ import annotations

import csv
import math
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


def _run(cfg, out, **kw):
    dcfg = {**cfg["drift"], "window_h": 0.25}
    return drift_study.run_noise_seeds(out / "seeds.nc", out / "seeds.csv", out / "z.png", out / "m.json",
                                       cfg["navigation_session"], cfg["site"], dcfg, 2, 77, out / "scratch",
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
