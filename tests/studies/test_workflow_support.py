"""Determinism, tracking and config validation, including config errors."""
import hashlib
import json
import math
from pathlib import Path

import numba
import numpy as np
import pytest
import xarray as xr
import yaml

from calib.figures import style as figures
from calib.nav import strapdown
from calib.studies import calibration as calibration_study
from calib.studies import stages, tracking
from calib.core.earth import DEG_PER_H

ROOT = Path(__file__).resolve().parents[2]


def _md5(p):
    return hashlib.md5(Path(p).read_bytes()).hexdigest()


@pytest.mark.parametrize("ext", ["png", "svg", "pdf"])
def test_figures_are_byte_identical(tmp_path, ext):
    import matplotlib.pyplot as plt

    paths = []
    for i in range(2):
        fig, ax = plt.subplots()
        ax.plot(np.arange(50), np.sin(np.arange(50) / 5.0), label="a")
        ax.legend()
        ax.set_title("determinism")
        paths.append(figures.save(fig, tmp_path / f"f{i}.{ext}"))
    assert _md5(paths[0]) == _md5(paths[1])
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_multistream_navigation_independent_of_thread_count():
    """Streams are independent, so the parallel loop gives bit-identical results for 1 and 2 threads."""
    rng = np.random.default_rng(3)
    lat = math.radians(30.58)
    n = 2000
    Dth = np.tile([0.0, 7.292115e-5 * math.cos(lat) * 0.1, 7.292115e-5 * math.sin(lat) * 0.1], (n, 1))
    Dth += rng.normal(0, 1e-8, Dth.shape)
    Dv = np.tile([0.0, 0.0, 0.9793], (n, 1)) + rng.normal(0, 1e-6, Dth.shape)
    X = rng.uniform(-0.03, 0.03, (30, 3)) * DEG_PER_H
    init = strapdown.NavInit(lat=lat)
    old = numba.get_num_threads()
    outs = []
    for t in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
        numba.set_num_threads(t)
        outs.append(strapdown.navigate_multi(Dth, Dv, 0.1, init, X, out_every=10)[0])
    numba.set_num_threads(old)
    assert np.array_equal(outs[0], outs[1])


def test_calibration_study_rerun_is_identical(tmp_path):
    """The same config gives xarray-identical netCDF and byte-identical figures, with 1 or 2 workers."""
    cfg = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    s = cfg["calibration_session"]
    s.update(dwell_s=5.0, revolutions=1, rotation_rates_deg_s=[30.0])
    rec = tmp_path / "s.nc"
    stages.simulate_calibration(s, cfg["site"], 7, rec, tmp_path / "s.truth.json")
    cc = dict(cfg["calibration"], runs=2, NP=20, EG=20, methods=["ide", "ide_lsq"])
    for k, workers in (("a", 1), ("b", 2)):  # and whatever the number of worker processes
        calibration_study.run_study(rec, tmp_path / "s.truth.json", tmp_path / k, cc, 11, prov={"seed": 11},
                                    workers=workers)
    for p in sorted((tmp_path / "a").rglob("*")):
        q = tmp_path / "b" / p.relative_to(tmp_path / "a")
        if p.suffix == ".nc":
            with xr.open_dataset(p) as x, xr.open_dataset(q) as y:
                xr.testing.assert_identical(x.load(), y.load())
        elif p.suffix in (".png", ".csv", ".json") and p.name != "timings.csv":
            assert _md5(p) == _md5(q), p.name


def test_schema_refuses_unknown_key_naming_it():
    from snakemake.utils import validate

    cfg = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    validate(cfg, str(ROOT / "src" / "calib" / "resources" / "config.schema.yaml"))
    cfg["drift"]["particle_count"] = 30
    with pytest.raises(Exception, match="particle_count"):
        validate(cfg, str(ROOT / "src" / "calib" / "resources" / "config.schema.yaml"))
    cfg = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    cfg["site"]["latitude_deg"] = 95.0
    with pytest.raises(Exception, match="95"):
        validate(cfg, str(ROOT / "src" / "calib" / "resources" / "config.schema.yaml"))


def test_tracking_two_runs_side_by_side(tmp_path, monkeypatch):
    """Two runs with different configs are stored with their metrics and read back through the client."""
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    res = tmp_path / "results"
    (res / "drift").mkdir(parents=True)
    ids = []
    for k, ac in ((1, 91.5), (2, 97.25)):
        (res / "drift" / "pso.metrics.json").write_text(json.dumps({"Ac_of_mean_pct": {"x": ac}}))
        ids.append(tracking.collect(res, {"seeds": {"drift": k}, "drift": {"tests": 50}}, run_name=f"run{k}",
                                    artifacts=False))
    import mlflow

    client = mlflow.MlflowClient(tracking.tracking_uri(res))
    runs = {r.info.run_id: r for r in client.search_runs([client.get_experiment_by_name("calib").experiment_id])}
    assert set(ids) <= set(runs)
    assert runs[ids[0]].data.params["seeds.drift"] == "1" and runs[ids[1]].data.params["seeds.drift"] == "2"
    assert runs[ids[0]].data.metrics["drift.pso.Ac_of_mean_pct.x"] == 91.5
    assert runs[ids[1]].data.metrics["drift.pso.Ac_of_mean_pct.x"] == 97.25


def test_unreachable_tracking_uri_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "http://127.0.0.1:9")  # discard port: nothing listens
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "0")
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_TIMEOUT", "2")
    (tmp_path / "keep.nc").write_bytes(b"science")
    with pytest.raises(tracking.TrackingError, match="unreachable|failed"):
        tracking.collect(tmp_path, {"a": 1}, artifacts=False)
    assert (tmp_path / "keep.nc").read_bytes() == b"science"
