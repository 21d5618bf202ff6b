"""The Cramér–Rao bound beside every estimate of ``calib diagnose`` (report.json ``sigma_crb``, ``se_over_crb``,
``bounds``; report.md's σ_CRB column).

Truth: closed forms of the information of window means under white noise, the dense covariance ``W^T Sigma W``
of a random walk, the spread of the estimates of a linear term over 30 noise seeds of one synthetic session, and
the bound of the same window reductions computed from the simulator's own path and noise
(:mod:`calib.studies.diagnosis_efficiency`: per-sample derivatives of the physical injection path, the simulator's
noise settings), which shares neither the library's signatures nor the noise the diagnosis measures.
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from calib import diagnosis as dg
from calib.diagnosis import bound
from calib.diagnosis.geometry import Window
from calib.diagnosis.report import report_markdown
from calib.studies import diagnosis_efficiency as de
from calib.studies.diagnosis_proof import FastSession

SHORT = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}
FAST = {"figures": False}
#: a linear term the short path determines well: accelerometer K2 per axis [ug/g^2]
K2 = {"accel_quadratic_nonlinearity": {"k2_ug_per_g2": [30.0, -20.0, 25.0]}}
SEEDS = range(1, 31)


def _static_geometry(m: int, n: int, dt: float = 0.01, gap: int = 50):
    """One accelerometer axis observed through ``m`` static means of ``n`` samples each."""
    wins = []
    for k in range(m):
        w = Window("static", f"S{k}", k, k * (n + gap), k * (n + gap) + n)
        w.W = np.full((n, 1), 1.0 / n)
        wins.append(w)
    return SimpleNamespace(windows=wins, dt=dt, obs={"blocks": {(0, 0): np.arange(m)}})


def _noise(N: float, Q: float = 0.0, slow=(math.inf, 0.0)):
    return SimpleNamespace(N={"accel": [N]}, Q={"accel": [Q]}, slow={"accel": [slow]})


def test_white_noise_step_bound_is_the_closed_form():
    """A step of size s on the second half of m static means of n samples (bias free), white noise sigma per
    sample: the step is the difference of two means of n m / 2 samples each, sigma_CRB = 2 sigma / sqrt(n m)."""
    m, n, dt, N = 8, 400, 0.01, 0.05
    sigma = N / math.sqrt(dt)                     # per-sample standard deviation of the rate reading
    geom = _static_geometry(m, n, dt)
    step = (np.arange(m) >= m // 2).astype(float)
    J = bound.information(geom, _noise(N), np.column_stack([step, np.ones(m)]))
    (b_step, why), (b_bias, _) = bound.bounds_from(J, 2)
    assert why == ""
    assert b_step == pytest.approx(2.0 * sigma / math.sqrt(n * m), rel=1e-10)
    # the bias with the step free: the mean of the first half alone
    assert b_bias == pytest.approx(sigma / math.sqrt(n * m / 2), rel=1e-10)


def test_a_term_the_bias_can_replace_gets_no_number():
    """A bias-like term (a constant on every mean) beside the free bias: the information does not determine it."""
    m, n = 6, 200
    geom = _static_geometry(m, n)
    J = bound.information(geom, _noise(0.05), np.column_stack([np.ones(m), np.ones(m)]))
    (b, why), _ = bound.bounds_from(J, 2)
    assert b is None and why == bound.NOT_DETERMINED
    J0 = bound.information(geom, _noise(0.05), np.column_stack([np.zeros(m), np.ones(m)]))
    (b0, why0), _ = bound.bounds_from(J0, 2)
    assert b0 is None and why0 == bound.NO_SIGNATURE


@pytest.mark.parametrize("quant", [0.0, 0.37])
def test_random_walk_and_quantisation_match_the_dense_covariance(quant):
    """``W^T Sigma W`` of means and harmonic-like rows under white noise, a carried remainder (scale ``quant``) and
    a random walk started at the first window (Cov = rw (min(i, j) - i_first + 1)), against the dense sum."""
    rng = np.random.default_rng(5)
    rows, i = [], 7
    for n, k in ((30, 1), (45, 3), (20, 2), (60, 1)):
        W = rng.normal(size=(n, k))
        rows += [(i, i + n, np.ascontiguousarray(W[:, q])) for q in range(k)]
        i += n + (1 if n == 45 else 9)            # two windows back to back share a carried remainder
    T = i + 5
    white, rw = 0.8, 0.003
    Wd = np.zeros((T, len(rows)))
    for r, (a, b, w) in enumerate(rows):
        Wd[a:b, r] = w
    idx = np.arange(T)
    S = white * np.eye(T) + rw * np.clip(np.minimum.outer(idx, idx) - rows[0][0] + 1, 0, None)
    S += quant / 12.0 * (2.0 * np.eye(T) - np.eye(T, k=1) - np.eye(T, k=-1))
    got = bound.reduction_covariance(rows, white, 0.0, 0.0, quant, rw_var=rw)
    np.testing.assert_allclose(got, Wd.T @ S @ Wd, rtol=1e-10, atol=1e-12)


def _session(effects, tmp):
    return FastSession({**SHORT, "effects": effects, "conceal": True}, tmp, physical=True)


def _simulator_bound(fs, effects, fitted) -> dict:
    """The bound of the diagnosis's window reductions from the simulator's path and its true noise, as fitted."""
    (eid, params), = effects.items()
    info = de.information_pair(fs.cfg, eid, params, fs.sim, fs.clean_base, fs.template["temperature"].values,
                               fs.template)
    return de.bounds_pair(info, free=fitted)["reduced"]


@pytest.fixture(scope="module")
def k2_session(tmp_path_factory):
    return _session(K2, tmp_path_factory.mktemp("k2"))


@pytest.fixture(scope="module")
def k2_reports(k2_session):
    fs = k2_session
    _, shared = dg.diagnose_dataset(fs.dataset(SEEDS[0]), None, FAST, path="seed")
    return [dg.diagnose_dataset(fs.dataset(s), None, FAST, path=f"seed {s}", library_from=shared)[0] for s in SEEDS]


def test_bound_matches_the_spread_of_the_estimates(k2_reports):
    """Over 30 noise seeds the estimates of K2 spread as the bound says (std / mean sigma_CRB in [0.7, 1.5]), and the
    reported ratio se / sigma_CRB is the two numbers' quotient."""
    vals, crb = {}, {}
    for rep in k2_reports:
        f = [x for x in rep["found"] if x["effect"] == "accel_quadratic_nonlinearity"]
        if not f:
            continue
        for p in f[0]["parameters"]:
            assert p["se_over_crb"] == pytest.approx(p["se"] / p["sigma_crb"], rel=1e-12)
            vals.setdefault(p["name"], []).append(p["value"])
            crb.setdefault(p["name"], []).append(p["sigma_crb"])
    assert len(vals) == 3 and min(len(v) for v in vals.values()) >= 25
    for name, v in vals.items():
        ratio = np.std(v, ddof=1) / np.mean(crb[name])
        assert 0.7 <= ratio <= 1.5, f"{name}: spread / bound = {ratio:.3g}"


def test_bound_matches_the_simulators_own_bound(k2_session, k2_reports):
    """The reported sigma_CRB (library signatures, the noise the diagnosis measured; mean over the seeds) agrees with
    the bound of the same reductions from the simulator's path and true noise within 10 %."""
    crb = {}
    for rep in k2_reports:
        for f in rep["found"]:
            for p in f["parameters"] if f["effect"] == "accel_quadratic_nonlinearity" else ():
                crb.setdefault(p["name"], []).append(p["sigma_crb"])
    ref = _simulator_bound(k2_session, K2, set(crb))
    assert set(ref) == set(crb)
    for name, v in crb.items():
        assert np.mean(v) == pytest.approx(ref[name], rel=0.10), name


def test_drift_bound_profiles_the_time_constant(tmp_path):
    """A warm-up whose time constant the diagnosis profiles: the reported bound of its amplitudes (the time constant
    a free column at the estimated amplitudes) agrees with the simulator's bound with the time constant free
    within 15 %; the trends it holds at zero are listed apart."""
    eff = {"bias_drift": {"accel_warmup_ug": [300.0, -200.0, 250.0], "accel_tau_s": 300.0}}
    fs = _session(eff, tmp_path)
    rep, _ = dg.diagnose_dataset(fs.dataset(1), None, FAST, path="seed 1")
    f = next(x for x in rep["found"] if x["key"] == "bias_drift/accel")
    assert rep["bounds"]["shape_parameters_free"] == 1
    pars = {p["name"]: p for p in f["parameters"]}
    ref = _simulator_bound(fs, eff, set(pars))
    for name, p in pars.items():
        assert p["sigma_crb"] == pytest.approx(ref[name], rel=0.15), name
    assert {b["name"] for b in f["bounds_not_estimated"]} == set(f["undetermined_parameters"])


def test_report_states_the_bound_and_shows_it(k2_reports):
    rep = next(r for r in k2_reports if r["found"])
    b = rep["bounds"]
    assert b["computed"] is True and b["stream_bound"]["computed"] is False and b["stream_bound"]["why"]
    assert {"what", "observations", "noise", "nuisances", "ratio"} <= set(b)
    for p in rep["base_parameters"]:
        assert p["sigma_crb"] > 0 and p["se_over_crb"] == pytest.approx(p["se_before"] / p["sigma_crb"])
    md = report_markdown(rep)
    assert "σ_CRB" in md
    p = rep["found"][0]["parameters"][0]
    row = next(line for line in md.splitlines() if line.startswith(f"| {p['name']} |"))
    assert f"{p['sigma_crb']:.3g}" in row


def test_a_null_session_bounds_nothing(tmp_path):
    fs = FastSession({**SHORT, "effects": {}, "conceal": True}, tmp_path)
    rep, _ = dg.diagnose_dataset(fs.dataset(11), None, FAST, path="seed 11")
    assert rep["found"] == [] and rep["bounds"]["computed"] is False
    assert all("sigma_crb" not in p for p in rep["base_parameters"])


def test_a_bound_that_cannot_be_formed_changes_nothing_else(k2_session, monkeypatch):
    """When the information cannot be factorised the report says why and carries no partial bound; the verdict
    and the findings are those without it."""
    ds = k2_session.dataset(SEEDS[0])
    ref, _ = dg.diagnose_dataset(ds, None, FAST, path="seed")

    def fail(*a, **k):
        raise np.linalg.LinAlgError("Matrix is not positive definite")

    monkeypatch.setattr(bound, "information", fail)
    rep, _ = dg.diagnose_dataset(ds, None, FAST, path="seed")
    assert rep["bounds"]["computed"] is False and "not positive definite" in rep["bounds"]["why"]
    assert rep["verdict"] == ref["verdict"] and [f["key"] for f in rep["found"]] == [f["key"] for f in ref["found"]]
    assert not any("sigma_crb" in p for f in rep["found"] for p in f["parameters"])
    assert not any("sigma_crb" in p for p in rep["base_parameters"])
