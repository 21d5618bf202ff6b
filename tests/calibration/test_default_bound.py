"""The Cramér–Rao bound beside the default calibration's estimates (``default_calibration.json`` / ``.nc``): on a
simulated session with white noise of known density, the accelerometer biases' bound is the closed form of the
session's symmetric pose design, and the spread of the default estimates over noise seeds is the bound; what the
windows cannot give is None with its reason, never a number."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

from calib.calibration import bound as cb
from calib.calibration import objectives as ob
from calib.core.triad import PARAM_NAMES
from calib.signal import segments
from calib.sim.calibration_session import (build_calibration_simulator, calibration_session_channels,
                                           calibration_session_dataset)
from calib.sim.fisher import mean_noise_models
from calib.sim.static_session import static_counts_dataset
from calib.studies import calibration as cs
from calib.studies import stages

ROOT = Path(__file__).resolve().parents[2]
SITE = {"latitude_deg": 30.58, "height_m": 0.0}
#: white noise only (no bias instability, no quantisation): the window means are independent with std N / sqrt(T)
WHITE = {"accel_vrw_ug_rthz": 10.0, "accel_bias_instability_ug": 0.0, "gyro_arw_deg_rth": 0.002,
         "gyro_bias_instability_deg_h": 0.0, "accel_bias_corr_time_s": 300.0, "gyro_bias_corr_time_s": 600.0,
         "bias_model": "gauss_markov", "quantize": False}
DWELL_S = 10.0
#: 24 static positions of 10 s and one revolution per rotation window of the default unit
SESSION = {"sample_rate_hz": 100.0, "dwell_s": DWELL_S, "revolutions": 1, "noise": WHITE}
N_SEEDS = 40


@pytest.fixture(scope="module")
def ccfg():
    c = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())["calibration"]
    return {**c, "NP": 30, "EG": 200}


@pytest.fixture(scope="module")
def session():
    sim = build_calibration_simulator(stages.calibration_cfg(SESSION, SITE), 1)
    return sim, sim.clean_increments(), calibration_session_channels(sim)


def _inputs(session, seed):
    sim, clean, channels = session
    ds = cs._as_loaded(calibration_session_dataset(sim, seed, clean, channels), Path("s.nc"))
    return segments.extract(ds)


def _written(tmp_path, inp, ccfg, seed=7, noise=None):
    d = cs.default_calibration(inp, ccfg, seed, noise=noise)
    cs.write_default(d, tmp_path / "d.json", tmp_path / "d.nc", None, {"accel": None, "gyro": None},
                     bound=cs.default_bound(inp, d, noise))
    return d, json.loads((tmp_path / "d.json").read_text())


def test_accel_bias_bound_is_the_closed_form_of_the_pose_design(tmp_path, session, ccfg):
    """The 24 positions are three circles of 8 poses 45 deg apart (gravity in the y-z, x-z and x-y planes of the
    body): every pose has its antipode, so sum u = 0 and the biases decouple from K E. The norm model sees only the
    radial component of each mean (the direction takes the tangential ones): b_i = sigma / sqrt(sum_m u_m,i^2) =
    sigma / sqrt(8); with known directions (vector model) every mean counts, b_i = sigma / sqrt(24) = the white
    density / sqrt(total static time), the std of one mean over all static samples. sigma = N / sqrt(T) from the
    simulator's white noise."""
    inp = _inputs(session, 100)
    st = inp.accel_static
    u = st.true_inputs() / st.reference
    assert st.n == 24 and np.allclose(st.duration_s, DWELL_S)
    assert np.allclose(u.sum(0), 0.0, atol=1e-12) and np.allclose(u.T @ u, 8.0 * np.eye(3), atol=1e-9)
    N = mean_noise_models(session[0])["accel"].N  # white density [count s-1 s^1/2]
    sigma = N / math.sqrt(DWELL_S)
    _, out = _written(tmp_path, inp, ccfg)
    got = out["accel"]["sigma_crb"]
    for i, ax in enumerate("xyz"):
        # the bound takes sigma measured from the session's Allan deviation: a few per cent from the truth
        assert got[f"b{ax}"] == pytest.approx(sigma[i] / math.sqrt(8.0), rel=0.04)
    assert out["accel"]["bound"]["observe"] == "norm" and out["accel"]["bound"]["windows"] == 24
    assert "no long static record" in out["accel"]["bound"]["noise"]
    # the same windows and noise, directions known: the mean over every static sample
    obs = cb.independent_observations(cb.session_groups(st), [st.sigma])
    M, b = ob.Form("paper12").KE_b(np.array(list(out["accel_body_vector"].values())))
    vec = cb.bound("accel", M, b, [obs], "vector", "paper12").as_dict()
    for i, ax in enumerate("xyz"):
        assert vec[f"b{ax}"] == pytest.approx(N[i] / math.sqrt(24 * DWELL_S), rel=0.04)


def test_spread_of_the_default_estimates_over_seeds_is_the_bound(tmp_path, session, ccfg):
    """White noise, independent means: eq. 7 (equal noise on the axes, near-equal scale factors) and eq. 25 are
    about efficient, so over 40 noise seeds the std of every default estimate lies within [0.7, 1.6] sigma_crb
    (the std of a std over 40 draws: 11 %); the reported standard errors agree with the bound (se_over_crb)."""
    est = {"accel": [], "gyro": []}
    first = None
    for k in range(N_SEEDS):
        inp = _inputs(session, 100 + k)
        if k == 0:
            d, first = _written(tmp_path, inp, ccfg, seed=7)
        else:
            d = cs.default_calibration(inp, ccfg, 7 + k)
        est["accel"].append(d["accel"].x)
        est["gyro"].append(d["gyro"].x)
    for sensor in ("accel", "gyro"):
        names = first[sensor]["parameters"].keys()
        sd = np.std(est[sensor], axis=0, ddof=1)
        crb = np.array([first[sensor]["sigma_crb"][n] for n in names])
        ratio = sd / crb
        assert np.all((ratio >= 0.7) & (ratio <= 1.6)), dict(zip(names, ratio))
        se = np.array([first[sensor]["standard_errors"][n] for n in names])
        assert np.allclose([first[sensor]["se_over_crb"][n] for n in names], se / crb, rtol=1e-12)
        assert all(0.7 <= first[sensor]["se_over_crb"][n] <= 1.6 for n in names)
    assert first["gyro"]["bound"]["observe"] == "vector" and first["gyro"]["bound"]["form"] == "paper12"


def test_the_netcdf_carries_the_bound_per_labelled_parameter(tmp_path, session, ccfg):
    inp = _inputs(session, 100)
    _, out = _written(tmp_path, inp, ccfg)
    with xr.open_dataset(tmp_path / "d.nc", engine="netcdf4") as ds:
        acc = ds["accel_sigma_crb"]
        assert list(acc[acc.dims[0]].values) == list(out["accel"]["parameters"])
        assert np.allclose(acc.values, list(out["accel"]["sigma_crb"].values()), rtol=1e-12)
        gyr = ds["gyro_se_over_crb"]
        assert gyr.dims == ("parameter",) and list(ds["parameter"].values) == list(PARAM_NAMES)
        assert np.allclose(gyr.values, [out["gyro"]["se_over_crb"][n] for n in PARAM_NAMES], rtol=1e-12)
        assert ds["gyro_sigma_crb"].attrs["observe"] == "vector"


def test_what_the_windows_do_not_give_is_null_with_a_reason(tmp_path, session, ccfg):
    """Without nominal attitudes the gyros' vector model has no known inputs: every gyro entry is None with the
    reason; the accelerometers' norm model then takes the directions from the estimate and gives the same bound.
    A bound with undetermined parameters (the paper's 12 from the norm: the triad's rotation) gives None with the
    reason beside the estimates, never a number."""
    inp = _inputs(session, 100)
    _, ref = _written(tmp_path, inp, ccfg)
    bare = dataclasses.replace(inp, accel_static=dataclasses.replace(inp.accel_static, attitude=None),
                               gyro_static=dataclasses.replace(inp.gyro_static, attitude=None))
    d = cs.default_calibration(bare, ccfg, 7)
    b = cs.default_bound(bare, d, None)
    assert all(v is None for v in b["gyro"]["sigma_crb"].values())
    assert all(v is None for v in b["gyro"]["se_over_crb"].values())
    assert all("nominal attitudes" in r for r in b["gyro"]["null_reason"].values())
    assert b["gyro"]["block"]["not_available"]
    for n, v in b["accel"]["sigma_crb"].items():
        assert v == pytest.approx(ref["accel"]["sigma_crb"][n], rel=0.02)
    assert "implied by the estimate" in b["accel"]["block"]["inputs"]

    st = inp.accel_static
    obs = cb.independent_observations(cb.session_groups(st), [st.sigma])
    M, bb = ob.Form("paper12").KE_b(np.array(list(ref["accel_body_vector"].values())))
    p12 = cb.bound("accel", M, bb, [obs], "norm", "paper12")
    rows = cb.beside_estimates(PARAM_NAMES, np.ones(12), p12, "")
    for n in PARAM_NAMES[:9]:
        assert rows["sigma_crb"][n] is None and rows["se_over_crb"][n] is None
        assert "rotation of the whole triad" in rows["null_reason"][n]
    assert all(rows["sigma_crb"][n] > 0 for n in ("bx", "by", "bz")) and not {"bx", "by", "bz"} & set(
        rows["null_reason"])


def test_with_a_noise_record_the_bound_uses_the_measured_noise(tmp_path, ccfg):
    """The default unit's noise (white, quantisation, Gauss-Markov bias correlated between windows) and a 2 h
    static record of it: the bound uses the noise model the calibration fitted, and agrees with the bound from
    the simulator's own noise (:func:`calib.sim.fisher.mean_noise_models`) at the same estimate within the
    accuracy of the fitted noise (25 %), while the windows' own sigmas (no slow bias) give a bias bound below."""
    session = {k: v for k, v in SESSION.items() if k != "noise"}
    cfg = stages.calibration_cfg(session, SITE)
    sim = build_calibration_simulator(cfg, 1)
    inp = segments.extract(cs._as_loaded(calibration_session_dataset(sim, 100, sim.clean_increments(),
                                                                     calibration_session_channels(sim)),
                                         Path("s.nc")))
    check = {"duration_h": 2.0, "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}}
    rec = static_counts_dataset(stages.static_check_cfg(check, session, SITE), 101, path=tmp_path / "l.nc")
    noise = cs.noise_models(inp, rec, ccfg)
    d, out = _written(tmp_path, inp, ccfg, noise=noise)
    assert "long static record" in out["accel"]["bound"]["noise"] and out["gyro"]["bound"]["noise"].startswith(
        "the noise model")
    true_b = cs.default_bound(inp, d, mean_noise_models(sim))
    seg_b = cs.default_bound(inp, d, None)
    for sensor in ("accel", "gyro"):
        for n, v in out[sensor]["sigma_crb"].items():
            assert v == pytest.approx(true_b[sensor]["sigma_crb"][n], rel=0.25), (sensor, n)
    for n in ("bx", "by", "bz"):
        assert seg_b["accel"]["sigma_crb"][n] < out["accel"]["sigma_crb"][n]
