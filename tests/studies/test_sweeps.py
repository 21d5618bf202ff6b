"""Parameter sweeps: sweep files, Paramspace points, the point functions, the gather, the rules."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

from calib.studies import stages
from calib.studies import sweep_summary, sweeps

ROOT = Path(__file__).resolve().parents[2]
SWEEP_SCHEMA = ROOT / "workflow" / "schemas" / "sweep.schema.yaml"
STUDY_SCHEMA = ROOT / "src" / "calib" / "resources" / "config.schema.yaml"


def _study():
    return yaml.safe_load((ROOT / ".test" / "config.yaml").read_text())


def _write(tmp_path, doc, name="s.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(doc))
    return p


def _load(path):
    return sweeps.load(path, _study(), SWEEP_SCHEMA, STUDY_SCHEMA)


# ---- sweep files -------------------------------------------------------------------------------------
def test_schema_and_library_name_the_same_parameters():
    schema = yaml.safe_load(SWEEP_SCHEMA.read_text())
    kinds = {}
    for branch in schema["allOf"]:
        kind = branch["if"]["properties"]["kind"]["const"]
        props = branch["then"]["properties"]
        assert set(props["grid"]["properties"]) == set(props["fixed"]["properties"])
        kinds[kind] = set(props["grid"]["properties"])
    assert kinds == {k: set(sweeps.parameter_names(k)) for k in sweeps.KINDS}
    assert set(schema["properties"]["kind"]["enum"]) == set(sweeps.KINDS)


@pytest.mark.parametrize("section", ["grid", "fixed"])
def test_unknown_parameter_is_refused_naming_it(tmp_path, section):
    doc = {"name": "x", "kind": "calibration", "grid": {"NP": [10, 20]}}
    doc.setdefault(section, {})["particles"] = [5] if section == "grid" else 5  # a drift parameter
    with pytest.raises(sweeps.SweepError, match=rf"{section}\.particles: unknown sweep parameter 'particles'"):
        _load(_write(tmp_path, doc))


def test_out_of_range_and_clashing_values_are_refused(tmp_path):
    with pytest.raises(sweeps.SweepError, match=r"grid\.NP\.0: 3 is less than the minimum of 5"):
        _load(_write(tmp_path, {"name": "x", "kind": "calibration", "grid": {"NP": [3, 10]}}))
    with pytest.raises(sweeps.SweepError, match=r"EG both swept \(grid\) and fixed"):
        _load(_write(tmp_path, {"name": "x", "kind": "calibration", "grid": {"EG": [5]}, "fixed": {"EG": 6}}))
    with pytest.raises(sweeps.SweepError, match=r"kind"):
        _load(_write(tmp_path, {"name": "x", "kind": "navigation", "grid": {"EG": [5]}}))


def test_base_is_checked_against_the_study_schema(tmp_path):
    doc = {"name": "x", "kind": "calibration", "grid": {"NP": [10]}, "base": {"calibration": {"Np": 10}}}
    with pytest.raises(sweeps.SweepError, match=r"base\.calibration: Additional properties .*'Np'"):
        _load(_write(tmp_path, doc))


def test_shipped_sweep_files_load():
    for p in sorted((ROOT / "config" / "sweeps").glob("*.yaml")):
        s = sweeps.load(p, _study(), SWEEP_SCHEMA, STUDY_SCHEMA)
        assert len(s.points) >= 12


def test_points_sessions_and_point_config(tmp_path):
    doc = {"name": "x", "kind": "calibration", "fixed": {"method": "de_rand1"},
           "grid": {"NP": [10, 20], "EG": [5], "noise_scale": [1, 10], "seed": [3]}}
    s = _load(_write(tmp_path, doc))
    study = _study()
    # data parameters first in the path; grid order otherwise; one point per combination
    assert s.columns == ["noise_scale", "seed", "NP", "EG"]
    assert s.points == ["noise_scale~1_seed~3_NP~10_EG~5", "noise_scale~1_seed~3_NP~20_EG~5",
                        "noise_scale~10_seed~3_NP~10_EG~5", "noise_scale~10_seed~3_NP~20_EG~5"]
    assert s.sessions == ["noise_scale~1_seed~3", "noise_scale~10_seed~3"]
    assert s.session_of(s.points[3]) == "noise_scale~10_seed~3"
    c = s.point_config(s.points[3])
    assert c["calibration"]["NP"] == 20 and c["calibration"]["EG"] == 5 and c["seeds"]["data"] == 3
    assert c["sweep"] == {"method": "de_rand1", "problem": "accel"}
    n0, n1 = study["calibration_session"]["noise"], c["calibration_session"]["noise"]
    for k in ("accel_vrw_ug_rthz", "accel_bias_instability_ug", "gyro_arw_deg_rth", "gyro_bias_instability_deg_h"):
        assert n1[k] == pytest.approx(10 * n0[k])
    assert n1["accel_bias_corr_time_s"] == n0["accel_bias_corr_time_s"]
    sc = s.session_config("noise_scale~10_seed~3")
    assert sc["seed"] == stages.session_seed(3, "calibration_session") and sc["session"]["noise"] == n1
    with pytest.raises(sweeps.SweepError, match="not a point"):
        s.values("NP~999")

    d = _load(_write(tmp_path, {"name": "d", "kind": "drift_pso", "base": {"drift": {"window_h": 0.7}},
                                "grid": {"particles": [4], "generations": [2, 3]}}, "d.yaml"))
    assert d.sessions == ["session~base"] and d.session_of(d.points[1]) == "session~base"
    c = d.point_config(d.points[1])
    # the session's noise is the study's navigation_session stream of seeds.data; the session is exactly the window
    assert c["seeds"]["data"] == study["seeds"]["data"]
    assert d.session_config(d.sessions[0])["seed"] == stages.session_seed(study["seeds"]["data"], "navigation_session")
    assert c["navigation_session"]["duration_h"] == 0.7 and c["drift"]["pso"]["generations"] == 3


# ---- the minimiser of J ------------------------------------------------------------------------------
class _LinearCost:
    """Errors exactly linear in the compensation: e(c) = e0 + H c per channel (unit 'rad': no scaling)."""

    unit = "rad"

    def __init__(self, H, e0, weights):
        self.H, self.e0, self.weights = H, e0, tuple(weights)
        self.win = type("W", (), {"lat0": 0.5, "h0": 0.0})()

    def errors(self, X):
        e = self.e0[None] + np.einsum("knj,sj->skn", self.H, np.atleast_2d(X))  # (S, 4, T)
        return {"vE": e[:, 0], "vN": e[:, 1], "lat": e[:, 2], "lon": e[:, 3]}

    def J(self, X):
        e = self.errors(X)
        return sum(w * np.abs(e[k]).sum(-1) for w, k in zip(self.weights, ("vE", "vN", "lat", "lon")))


def test_argmin_J_is_the_minimiser_of_the_linear_model():
    rng = np.random.default_rng(5)
    H = rng.normal(size=(4, 30, 3))
    inside = np.array([0.011, -0.004, 0.02])
    cost = _LinearCost(H, -np.einsum("knj,j->kn", H, inside), [1.0, 2.0, 1.0, 10.0])
    c, J = sweeps.argmin_J(cost, -0.03, 0.03)
    np.testing.assert_allclose(c, inside, atol=1e-9)  # J = 0 exactly there
    assert J == pytest.approx(0.0, abs=1e-9)
    # minimiser outside the box: the LP answer is the best point of the box (J is convex)
    outside = np.array([0.011, -0.004, 0.08])
    cost = _LinearCost(H, -np.einsum("knj,j->kn", H, outside) + rng.normal(0, 1e-3, (4, 30)), [1, 1, 1, 10])
    c, J = sweeps.argmin_J(cost, -0.03, 0.03)
    assert np.all(np.abs(c) <= 0.03 + 1e-12)
    assert J == pytest.approx(cost.J(c)[0], rel=1e-9)
    trials = rng.uniform(-0.03, 0.03, (4000, 3))
    corners = np.array(np.meshgrid(*[[-0.03, 0.03]] * 3)).reshape(3, -1).T
    assert J <= cost.J(np.vstack([trials, corners])).min() + 1e-9


# ---- point functions on small synthetic sessions -------------------------------------------------------
def test_drift_point_without_noise_recovers_the_true_drift(tmp_path):
    """No accelerometer bias and almost no gyro noise: the minimiser of J is the true drift."""
    study = _study()
    session = dict(study["navigation_session"], duration_h=0.5, accel_bias_m_s2=[0.0, 0.0, 0.0],
                   gyro_noise={"model": "arw", "arw_deg_rth": 1e-7})
    stages.simulate_navigation(session, study["site"], 7, tmp_path / "n.nc", tmp_path / "n.json")
    dcfg = dict(study["drift"], window_h=0.5, tests=2, pso=dict(study["drift"]["pso"], particles=6, generations=3))
    cfg = {"seeds": study["seeds"], "site": study["site"], "navigation_session": session, "drift": dcfg}
    ds = sweeps.run_point("drift_pso", tmp_path / "n.nc", None, cfg, {"particles": 6}, tmp_path / "p.nc")
    truth = np.array(session["gyro_drift_deg_h"])
    # what is left is the (tiny) gyro noise: a few Cramer-Rao bounds at most (an unmodelled accelerometer bias
    # of 0.001 m/s^2 would move it by the whole search range)
    assert np.all(np.abs(ds["argmin_J"].values - truth) < 4 * ds["crb"].values)
    assert np.all(ds["crb"].values < 0.01 * np.abs(truth))  # so the check above is tight
    assert ds.sizes == {"test": 2, "axis": 3, "generation": 4}
    assert np.all(ds["J"].values >= ds["J_min"].values)  # nothing beats the minimiser
    assert np.all(ds["crb"].values > 0)
    with xr.open_dataset(tmp_path / "p.nc", engine="netcdf4") as f:
        assert json.loads(f.attrs["point"]) == {"particles": 6}


def test_calibration_point_least_squares_reaches_the_optimum(tmp_path):
    """With least squares every run reaches L*, and (K E)(K E)^T is recovered to the noise level."""
    study = _study()
    session = dict(study["calibration_session"], dwell_s=5.0, rotation_rates_deg_s=[])
    stages.simulate_calibration(session, study["site"], 11, tmp_path / "c.nc", tmp_path / "c.json")
    cfg = {"seeds": study["seeds"], "site": study["site"], "calibration_session": session,
           "calibration": dict(study["calibration"], runs=2, NP=10, EG=5),
           "sweep": {"method": "lsq", "problem": "accel"}}
    ds = sweeps.calibration_point(tmp_path / "c.nc", tmp_path / "c.json", cfg)
    assert float(ds["success_pct"]) == 100.0
    assert float(ds["L_star"]) <= ds["L"].values.min()
    # accelerometer white noise 10 ug/sqrt(Hz) over 5 s: a position mean is good to ~5e-6 g, the Gram
    # matrix (relative) to the same order; 1e-4 is 20 times that
    assert np.all(ds["gram_rel_error"].values < 1e-4)
    assert ds["estimate"].shape == (2, 12)


# ---- gather ------------------------------------------------------------------------------------------
def test_gather_puts_every_point_at_its_coordinates(tmp_path):
    grid = {"NP": [10, 20, 40], "EG": [5, 50]}
    values, paths = [], []
    for NP in grid["NP"]:
        for EG in grid["EG"]:
            ds = xr.Dataset({"success_pct": ((), NP + EG / 1000), "mean_L_over_L_star": ((), 1.0 + NP * EG),
                             "mean_L": ((), 2.0 * NP), "L_star": ((), 1.0),
                             "history": (("run", "generation"), np.full((2, EG + 1), float(NP)))},
                            coords={"run": [0, 1], "generation": np.arange(EG + 1)})
            p = tmp_path / f"p{NP}_{EG}.nc"
            ds.to_netcdf(p)
            values.append({"NP": NP, "EG": EG})
            paths.append(p)
    out = sweep_summary.gather("calibration", "t", paths, values, ["NP", "EG"], tmp_path / "s.nc", tmp_path / "s.csv",
                               tmp_path / "s.png", tmp_path / "m.json", attrs={"sweep_file": "t.yaml"})
    assert list(out["success_pct"].dims) == ["NP", "EG"]
    for v in values:
        assert float(out["success_pct"].sel(v)) == v["NP"] + v["EG"] / 1000
        h = out["history"].sel(v).values
        assert np.all(h[:, : v["EG"] + 1] == v["NP"]) and np.all(np.isnan(h[:, v["EG"] + 1:]))
    with xr.open_dataset(tmp_path / "s.nc", engine="netcdf4") as f:
        assert json.loads(f.attrs["swept"]) == ["NP", "EG"] and f.attrs["sweep_file"] == "t.yaml"
    assert len((tmp_path / "s.csv").read_text().splitlines()) == 1 + len(values)
    assert json.loads((tmp_path / "m.json").read_text())["points"] == 6
    assert (tmp_path / "s.png").stat().st_size > 0


# ---- the rules ---------------------------------------------------------------------------------------
def _snakemake(args, cwd, timeout=300):
    env = {**os.environ, "CALIB_TRACKING": "0"}
    env.pop("SNAKEMAKE_PROFILE", None)
    return subprocess.run([sys.executable, "-m", "snakemake", "-s", str(ROOT / "Snakefile"), *args], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=timeout)


def test_sweep_rules_gather_the_points(tmp_path):
    """`snakemake sweeps` with a 2-point drift sweep: one session, two point jobs, one labelled netCDF."""
    sweep = _write(tmp_path, {"name": "tiny", "kind": "drift_pso", "base": {"drift": {"window_h": 0.25, "tests": 1}},
                              "fixed": {"generations": 3}, "grid": {"particles": [4, 8]}}, "tiny.yaml")
    cfg = _study()
    cfg.update(results=str(tmp_path / "results"), sweeps=[str(sweep)])
    cfgfile = _write(tmp_path, cfg, "config.yaml")
    work = tmp_path / "work"
    work.mkdir()
    r = _snakemake(["sweeps", "-c2", "--directory", str(work), "--configfile", str(cfgfile)], tmp_path)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    res = tmp_path / "results" / "sweeps" / "tiny"
    with xr.open_dataset(res / "sweep.nc", engine="netcdf4") as ds:
        assert dict(ds["rms_error_in_bounds"].sizes) == {"particles": 2}
        assert ds.sizes["generation"] == 4 and json.loads(ds.attrs["fixed"]) == {"generations": 3}
        for p in (4, 8):
            with xr.open_dataset(res / "points" / f"particles~{p}.nc", engine="netcdf4") as pt:
                assert json.loads(pt.attrs["point"]) == {"particles": p}
                np.testing.assert_array_equal(ds["estimate"].sel(particles=p).values, pt["estimate"].values)
    assert (res / "summary.png").stat().st_size > 0
    assert not list((res / "sessions").glob("*.nc"))  # the session is temporary

    # a sweep file naming an unknown parameter stops the workflow before anything runs, naming it
    _write(tmp_path, {"name": "tiny", "kind": "drift_pso", "grid": {"particles": [4], "swarm": [1]}}, "tiny.yaml")
    r = _snakemake(["sweeps", "-n", "--directory", str(work), "--configfile", str(cfgfile)], tmp_path)
    assert r.returncode != 0 and "grid.swarm: unknown sweep parameter 'swarm'" in r.stdout + r.stderr
