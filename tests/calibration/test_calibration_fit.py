"""Calibration against known truth (Liu 2021 Tables 1 and 3 as the synthetic unit's parameters).

Static means come from the closed-form model N = K E x + b at Liu 2021's 24 attitudes (§2.2) plus Gaussian
noise of known sigma; rotation pairs from the whole-revolution means of eqs. 23-24. The checks: separate LS
and the identified norm form recover the truth within their standard errors, eq. 25 is exact on noise-free
means, the ranks are 9 of 12 (paper's norm form) and 3 of 9 (L_gm), the z-scores over many noise seeds are
standard normal, and bad input gives clear errors.
"""
import json
import math
import types
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.signal import lfilter

from calib.calibration import covariance as cv
from calib.calibration import fit as cal
from calib.core import earth
from calib.calibration import identifiability as idf
from calib.calibration import objectives as ob
from calib.signal import segments as sg
from calib.signal import synthetic_means as synth
from calib.io.recording import make_dataset
from calib.core.triad import liu2021_model
from calib.core.rotations import axis_angle
from calib.io import recording as recording_io
from calib.signal import allan
from calib.signal import noisecov as nc
from calib.studies import calibration as cs
from calib.studies import stages

ACC = liu2021_model("accel")
GYR = liu2021_model("gyro")
ATT = idf.liu2021_attitudes()
AXES, RATES = idf.liu2021_rotation_plan()
SIG_A = 0.5  # count s-1 per static mean (~36 micro-g)
SIG_G = 80.0  # count s-1 (~0.01 deg/h)


def tri9_truth(model):
    L, _ = ob.lower_triangular_gauge(model.KE)
    return ob.Form("tri9").from_KE_b(L, model.b)


def accel_static(seed, sigma=SIG_A):
    return synth.synthetic_static(ACC, ATT, sigma, np.random.default_rng(seed), sensor="accel")


def gyro_data(seed):
    rng = np.random.default_rng(seed)
    st = synth.synthetic_static(GYR, ATT, SIG_G, rng, sensor="gyro")
    pr = synth.synthetic_pairs(GYR, AXES, RATES, SIG_G, rng)
    return st, pr


# ---------------------------------------------------------------------------------------------------------
# the 24-position path itself
# ---------------------------------------------------------------------------------------------------------
def test_liu2021_attitudes_follow_section_2_2():
    north = np.array([0.0, 1.0, 0.0])
    for ph in range(3):
        for k in range(8):
            C = ATT[8 * ph + k]
            assert np.allclose(C @ C.T, np.eye(3)) and np.linalg.det(C) == pytest.approx(1.0)
            assert np.allclose(C[:, ph], north)  # body axis ph points north throughout phase ph
        # consecutive positions differ by 45 deg about that axis
        R = ATT[8 * ph].T @ ATT[8 * ph + 1]
        assert np.allclose(R, axis_angle(np.eye(3)[ph], math.radians(45.0)))
    assert np.allclose(ATT[0][:, 2], [0, 0, 1]) and np.allclose(ATT[8][:, 2], [0, 0, 1])  # POS1: z up


# ---------------------------------------------------------------------------------------------------------
# accelerometer
# ---------------------------------------------------------------------------------------------------------
def test_separate_accel_recovers_truth():
    r = cal.separate_accel(accel_static(21))
    z = (r.x - ACC.to_vector()) / r.se
    assert np.all(np.abs(z) < 4.0)
    assert r.rank == 12 and r.dof == 3 * (24 - 4)
    assert r.chi2_red == pytest.approx(1.0, abs=0.5)
    # the calibrated model maps the outputs back to the inputs (apply), also from increments
    st = accel_static(21, sigma=0.0)
    x = r.apply(st.means)
    assert np.allclose(x, st.true_inputs(), atol=1e-4)
    dt = 0.01
    assert np.allclose(r.apply(st.means * dt, sample_kind="increment", dt=dt), x)


def test_norm_tri9_recovers_identified_combinations():
    st = accel_static(22)
    r = cal.norm_calibration(st, form="tri9", budget=(60, 400))
    assert r.rank == 9 and r.undetermined == []
    assert np.all(np.abs((r.x - tri9_truth(ACC)) / r.se) < 4.0)
    g = r.derived["gram"]
    Gt = ACC.KE @ ACC.KE.T
    zg = np.array([g["value"][i, j] - Gt[i, j] for i, j in g["entries"]]) / np.sqrt(np.diag(g["cov"]))
    assert np.all(np.abs(zg) < 4.0)
    # mapped back to the paper's form with the truth as reference, K E is the truth up to the noise
    vec, R = r.paper_form(ACC.KE)
    assert np.allclose(R @ R.T, np.eye(3))
    assert np.allclose(vec[3:9], ACC.to_vector()[3:9], atol=2e-4)
    assert "triad frame" in r.frame


def test_norm_paper12_rank_9_of_12_and_same_optimum_as_tri9():
    st = accel_static(23)
    r12 = cal.norm_calibration(st, form="paper12", budget=(60, 400))
    r9 = cal.norm_calibration(st, form="tri9", budget=(60, 400))
    assert r12.rank == 9 and len(r12.names) == 12
    assert r12.L == pytest.approx(r9.L, rel=1e-8)  # a rotation of the triad does not change eq. 7
    assert np.allclose(r12.derived["gram"]["value"], r9.derived["gram"]["value"], rtol=1e-9)
    assert set(r12.undetermined) == {"Exy", "Exz", "Eyx", "Eyz", "Ezx", "Ezy"}
    assert np.all(np.isnan(r12.se[3:9])) and np.all(np.isfinite(r12.se[[0, 1, 2, 9, 10, 11]]))
    gens = r12.identifiability.generators_in_null
    assert all(v > 0.999 for v in gens.values()) and len(gens) == 3


def test_bounds_excluding_the_optimum_are_reported():
    st = accel_static(24)
    lo, hi = np.array([13000.0] * 3 + [-0.01] * 3 + [-400.0] * 3), np.array([14000.0] * 3 + [0.01] * 3 + [400.0] * 3)
    lo[6] = -150.0  # bx truth -206.6 lies outside
    r = cal.norm_calibration(st, form="tri9", bounds=(lo, hi), budget=(40, 200))
    assert r.on_bound == ["bx"]
    assert r.x[6] == pytest.approx(-150.0, abs=1e-3)
    assert any("widen" in n for n in r.notes)


def test_weighted_fit_and_json_export():
    st = accel_static(25)
    st.sigma[:, 2] *= 3.0  # unequal sigmas: the weighted fit is the efficient one
    st.means[:, 2] += np.random.default_rng(26).normal(size=24) * SIG_A * math.sqrt(8.0)
    rw = cal.norm_calibration(st, weighted=True, budget=(40, 200))
    ru = cal.norm_calibration(st, weighted=False, budget=(40, 200))
    assert np.all(np.abs((rw.x - tri9_truth(ACC)) / rw.se) < 4.0)
    assert np.all(rw.se <= ru.se * 1.001)  # the weighted estimator is at least as precise
    d = json.loads(json.dumps(rw.to_dict()))
    assert d["frame"].startswith("triad frame") and d["rank"] == 9 and len(d["covariance"]) == 9
    assert "(K E)^-1 (N - b)" in d["how_to_apply"]


def test_too_few_positions_message():
    st = synth.synthetic_static(ACC, ATT[:6], SIG_A, np.random.default_rng(0), sensor="accel")
    with pytest.raises(sg.SegmentError, match=r"at least 10 .* found 6"):
        cal.norm_calibration(st)
    st4 = synth.synthetic_static(ACC, ATT[:4], SIG_A, np.random.default_rng(0), sensor="accel")
    with pytest.raises(sg.SegmentError, match=r"at least 5 .* found 4"):
        cal.separate_accel(st4)


# ---------------------------------------------------------------------------------------------------------
# gyro
# ---------------------------------------------------------------------------------------------------------
def test_eq25_components_exact_on_noise_free_means():
    st = synth.synthetic_static(GYR, ATT, SIG_G, None, sensor="gyro")
    pr = synth.synthetic_pairs(GYR, AXES, RATES, SIG_G, None)
    d, _ = pr.difference()
    w = pr.delta_input()
    # literally eq. 25: (N+ - N-) / (2 omega) is column k of K E for a rotation about body axis k
    for j in range(pr.n):
        k = int(np.argmax(np.abs(pr.axis[j])))
        assert np.allclose(d[j] / w[j, k], GYR.KE[:, k], rtol=1e-12)
    for bias_from in ("pairs", "static", "both"):
        r = cal.gyro_components(pr, st, bias_from=bias_from)
        assert np.allclose(r.KE, GYR.KE, rtol=1e-12, atol=0)
        assert np.allclose(r.b, GYR.b, rtol=0, atol=1e-5)
        assert np.allclose(r.x, GYR.to_vector(), rtol=1e-10, atol=1e-5)


def test_gyro_components_recover_truth_with_noise():
    st, pr = gyro_data(31)
    r = cal.gyro_components(pr, st)
    assert r.rank == 12
    assert np.all(np.abs((r.x - GYR.to_vector()) / r.se) < 4.0)
    assert "both" in r.notes[0]
    # the bias from the static norm with K E held (Liu 2021 §3.3) agrees within its standard error
    rn = cal.gyro_components(pr, st, bias_from="norm", budget=(20, 60))
    assert np.all(np.abs((rn.b - GYR.b) / rn.se[9:]) < 4.0)


def test_separate_gyro_joint_least_squares():
    st, _ = gyro_data(32)
    rng = np.random.default_rng(33)
    # rotation means of single segments (not pairs) with their known inputs
    rot_axes = np.repeat(np.eye(3), 2, axis=0)
    rates = np.tile([20.0, -20.0], 3)
    att = np.array([synth.vertical_axis_attitude(a) for a in rot_axes])
    rm = sg.RotationMeans(sensor="gyro", means=np.zeros((6, 3)), sigma=np.full((6, 3), SIG_G), axis=rot_axes,
                          rate_deg_s=rates, revolutions=np.ones(6), duration_s=np.full(6, 18.0),
                          input_unit="deg h-1", output_unit="count s-1", latitude_deg=39.98, attitude=att)
    rm.means = GYR.forward(rm.mean_inputs()) + rng.normal(size=(6, 3)) * SIG_G
    r = cal.separate_gyro(st, rm)
    assert np.all(np.abs((r.x - GYR.to_vector()) / r.se) < 4.0)


def test_lgm_rank_3_of_9_and_dynamic_path():
    st, pr = gyro_data(34)
    rep = idf.check_plan("gyro", "lgm")
    assert (rep.rank, rep.n_params) == (3, 9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the biases may end on a bound: they absorb the wrong installation errors
        r = cal.gyro_dynamic(pr, st, budget=(40, 300))
    assert r.derived["lgm_rank"] == (3, 9)
    assert set(r.undetermined) == {"Exy", "Exz", "Eyx", "Eyz", "Ezx", "Ezy"}
    assert any("rank 3 of 9" in n for n in r.notes)
    # what L_gm does determine: the column norms of K E
    assert np.allclose(np.linalg.norm(r.KE, axis=0), np.linalg.norm(GYR.KE, axis=0), rtol=1e-6)
    # and the component form (eq. 25) gets the full matrix from the same pairs
    assert idf.check_plan("gyro", "eq25").rank == 9


def test_gyro_static_norm_is_the_rank_9_problem():
    st, _ = gyro_data(35)
    r = cal.norm_calibration(st, form="paper12", budget=(40, 200))
    assert r.rank == 9 and r.objective.startswith("L_g")


# ---------------------------------------------------------------------------------------------------------
# identifiability of planned paths
# ---------------------------------------------------------------------------------------------------------
def test_identifiability_of_planned_paths():
    r = idf.check_plan("accel", "paper12")
    assert (r.rank, r.n_params) == (9, 12)
    text = " ".join(r.descriptions)
    assert "rotation of the triad about body z" in text and "Exy" in text and "Eyx" in text
    assert idf.check_plan("accel", "tri9").rank == 9
    assert idf.check_plan("accel", "vector").rank == 12
    # one phase only (x always horizontal): the x accelerometer's scale factor cannot be found
    one = idf.check_plan("accel", "tri9", attitudes=ATT[:8])
    assert one.rank < 9 and "Kx" in one.undetermined and one.suggestions
    # diagonal rotation axes raise L_gm to rank 6 (never 9)
    diag = np.array([[1, 1, 0], [1, 0, 1], [0, 1, 1]]) / math.sqrt(2)
    r6 = idf.check_plan("gyro", "lgm", rotation_axes=np.vstack([AXES, diag]), rotation_rates=np.r_[RATES, 3 * [10.]])
    assert r6.rank == 6


# ---------------------------------------------------------------------------------------------------------
# z-scores over noise seeds
# ---------------------------------------------------------------------------------------------------------
def _zscores(n_seeds, offset):
    za, zn, zg = [], [], []
    t9 = tri9_truth(ACC)
    for s in range(offset, offset + n_seeds):
        st = accel_static(s)
        r = cal.separate_accel(st)
        za.append((r.x - ACC.to_vector()) / r.se)
        rn = cal.norm_calibration(st, form="tri9", method="lsq", rng=np.random.default_rng(s))
        zn.append((rn.x - t9) / rn.se)
        gs, pr = gyro_data(10_000 + s)
        rg = cal.gyro_components(pr, gs)
        zg.append((rg.x - GYR.to_vector()) / rg.se)
    return np.array(za), np.array(zn), np.array(zg)


def _check_z(z, mean_tol, std_lo, std_hi):
    m, s = z.mean(axis=0), z.std(axis=0, ddof=1)
    assert np.all(np.abs(m) < mean_tol), m
    assert np.all((s > std_lo) & (s < std_hi)), s


def test_zscores_are_standard_normal():
    for z in _zscores(40, 1000):
        _check_z(z, 0.5, 0.7, 1.3)


def test_zscores_are_standard_normal_tight():
    for z in _zscores(300, 5000):
        _check_z(z, 0.3, 0.85, 1.15)


# ---------------------------------------------------------------------------------------------------------
# segment means from a calib-recording-1 dataset
# ---------------------------------------------------------------------------------------------------------
FS = 20.0
LAT = 39.98


def _quantise(rate, fs):
    """Integer count increments of a rate signal (count s-1), with carry (counts of the integral)."""
    total = np.floor(np.cumsum(rate / fs, axis=0))
    return np.diff(np.vstack([np.zeros((1, 3)), total]), axis=0)


def make_recording(n_static=24, static_s=30.0, rot_rate=30.0, revs=1.5, seed=0, zero_rate=False, flat=False):
    rng = np.random.default_rng(seed)
    g = float(earth.normal_gravity(math.radians(LAT))) / 9.80665
    w_ie = earth.earth_rate_enu(math.radians(LAT)) / earth.DEG_PER_H
    acc, gyr, seg, ang = [], [], [], []
    kinds, labels, axes, rates, atts = [], [], [], [], []
    gap = int(FS)

    def add(C_of_k, omega_b_tab, n, s):
        """``C_of_k``: the attitude at mid-sample k, or one fixed attitude (every sample the same row)."""
        if callable(C_of_k):
            f = np.empty((n, 3))
            w = np.empty((n, 3))
            for i, kk in enumerate(np.arange(n) + 0.5):  # mid-sample
                C = C_of_k(kk)
                f[i] = C.T @ np.array([0.0, 0.0, g])
                w[i] = C.T @ w_ie + omega_b_tab
        else:
            f = np.tile(C_of_k.T @ np.array([0.0, 0.0, g]), (n, 1))
            w = np.tile(C_of_k.T @ w_ie + omega_b_tab, (n, 1))
        acc.append(ACC.forward(f) + rng.normal(0.0, 30.0, (n, 3)))
        gyr.append(GYR.forward(w) + rng.normal(0.0, 2000.0, (n, 3)))
        seg.append(np.full(n, s))
        ang.append(np.zeros(n))

    for m in range(n_static):
        add(ATT[m], np.zeros(3), int(static_s * FS), len(kinds))
        kinds.append("static"), labels.append(f"POS{m + 1}"), axes.append(np.zeros(3)), rates.append(np.nan)
        atts.append(ATT[m])
        add(ATT[m], np.zeros(3), gap, -1)
    for a in np.eye(3):
        C0 = synth.vertical_axis_attitude(a)
        for sgn in (1.0, -1.0):
            r = sgn * rot_rate
            n = int(round(revs * 360.0 / abs(r) * FS))
            add(lambda kk, C0=C0, a=a, r=r: C0 @ axis_angle(a, math.radians(r * kk / FS)), r * 3600.0 * a, n,
                len(kinds))
            ang[-1] = r * np.arange(n) / FS
            kinds.append("rotation"), labels.append(f"ROT {'xyz'[int(np.argmax(a))]}{'+' if sgn > 0 else '-'}")
            axes.append(a), rates.append(0.0 if zero_rate else r), atts.append(C0)
            add(C0, np.zeros(3), gap, -1)
    acc = np.concatenate(acc)
    gyr = np.concatenate(gyr)
    counts_a = np.zeros_like(acc) if flat else _quantise(acc, FS)
    counts_g = _quantise(gyr, FS)
    return make_dataset(counts_a, counts_g, sample_rate_hz=FS, latitude_deg=LAT, accel_units="count",
                        gyro_units="count", accel_kind="increment", gyro_kind="increment",
                        segment_index=np.concatenate(seg), table_angle=np.concatenate(ang),
                        segments={"segment_kind": kinds, "segment_label": labels, "rotation_axis": np.array(axes),
                                  "rotation_rate": np.array(rates), "nominal_attitude": np.array(atts)})


@pytest.fixture(scope="module")
def recording():
    return make_recording()


def test_static_means_and_sigma_from_recording(recording):
    st = sg.static_means(recording, "accel")
    assert st.n == 24 and st.output_unit == "count s-1" and st.input_unit == "g"
    assert st.reference == pytest.approx(float(earth.normal_gravity(math.radians(LAT))) / 9.80665)
    truth = ACC.forward(st.true_inputs())
    z = (st.means - truth) / st.sigma
    assert np.all(np.abs(z) < 5.0)
    # white noise 30 count s-1 per sample: sigma of a 30 s mean = 30 / sqrt(600) (+ quantisation, small)
    assert np.allclose(st.sigma, 30.0 / math.sqrt(600), rtol=0.25)
    assert st.noise is not None and st.noise.n_records == 24


def test_rotation_means_whole_revolutions_and_pairs(recording):
    rot = sg.rotation_means(recording, "gyro")
    assert rot.n == 6
    assert np.all(rot.revolutions == 1)
    assert np.allclose(rot.duration_s, 360.0 / 30.0)  # one whole turn at 30 deg/s
    truth = GYR.forward(rot.mean_inputs())
    assert np.all(np.abs((rot.means - truth) / rot.sigma) < 5.0)
    pr = sg.pair_rotations(rot)
    assert pr.n == 3 and pr.unpaired == []
    assert np.allclose(pr.rate_plus, 30.0) and np.allclose(pr.rate_minus, -30.0)
    assert np.allclose(np.abs(pr.axis), np.eye(3))


def test_full_chain_from_recording(recording):
    inp = sg.extract(recording)
    ra = cal.separate_accel(inp.accel_static)
    assert np.all(np.abs((ra.x - ACC.to_vector()) / ra.se) < 5.0)
    rg = cal.gyro_components(inp.gyro_pairs, inp.gyro_static)
    assert np.all(np.abs((rg.x - GYR.to_vector()) / rg.se) < 5.0)


def test_static_detector_hook(recording, monkeypatch):
    """Without a segment table the static segments come from calib.signal.detect.detect_static(accel, gyro, fs)
    (``.intervals`` [start, stop)); replaced here by the known segments to test the hook itself."""
    bare = recording.drop_vars(["segment_index", "segment_kind", "segment_label", "rotation_axis", "rotation_rate",
                                "nominal_attitude", "table_angle"])
    si = recording["segment_index"].values
    kinds = recording["segment_kind"].values
    ranges = [(int(np.flatnonzero(si == s)[0]), int(np.flatnonzero(si == s)[-1]) + 1)
              for s in range(len(kinds)) if kinds[s] == "static"]
    monkeypatch.setattr(sg.detect, "detect_static",
                        lambda accel, gyro, fs: types.SimpleNamespace(intervals=np.array(ranges)))
    st = sg.static_means(bare, "accel")
    assert st.n == 24 and st.attitude is None
    assert np.allclose(st.means, sg.static_means(recording, "accel").means)

    def failing(accel, gyro, fs):
        raise ValueError("no static interval found")

    monkeypatch.setattr(sg.detect, "detect_static", failing)
    with pytest.raises(sg.SegmentError, match="segment table.*static detector failed"):
        sg.static_means(bare, "accel")


def test_recording_errors():
    with pytest.raises(sg.SegmentError, match="rotation_rate.*segment 24"):
        sg.rotation_means(make_recording(n_static=24, zero_rate=True), "gyro")
    with pytest.raises(sg.SegmentError, match="flat"):
        sg.static_means(make_recording(n_static=10, flat=True), "accel")
    with pytest.raises(sg.SegmentError, match="less than one whole revolution"):
        sg.rotation_means(make_recording(n_static=10, revs=0.8), "gyro")


def test_zscores_with_sigma_from_allan_on_recordings():
    """Whole chain: quantised increments -> segment means -> sigma from the pooled Allan deviation -> fits."""
    za, zg = [], []
    for s in range(40):
        inp = sg.extract(make_recording(seed=500 + s))
        ra = cal.separate_accel(inp.accel_static)
        za.append((ra.x - ACC.to_vector()) / ra.se)
        rg = cal.gyro_components(inp.gyro_pairs, inp.gyro_static)
        zg.append((rg.x - GYR.to_vector()) / rg.se)
    for z in (np.array(za), np.array(zg)):
        _check_z(z, 0.5, 0.7, 1.3)


# ---------------------------------------------------------------------------------------------------------
# slow noise (bias instability) from a long static record: closed forms and correlated segment means
# ---------------------------------------------------------------------------------------------------------


def _gm_record(sigma, tc, fs, n, rng):
    """Exact discretisation of a stationary Gauss-Markov process: beta_k = a beta_k-1 + sigma sqrt(1-a^2) z_k."""
    a = math.exp(-1.0 / (fs * tc))
    z = rng.normal(size=n) * sigma * math.sqrt(1.0 - a * a)
    z[0] = rng.normal() * sigma
    return lfilter([1.0], [1.0, -a], z)


def test_allan_deviation_of_gauss_markov_matches_closed_form_and_fit_recovers_it():
    """AVAR of a simulated GM process against eq. (1) of calib.signal.noisecov, inside allan.py's 95 % intervals, and
    the white + GM fit recovers N, sigma, Tc."""
    rng = np.random.default_rng(31)
    fs, sigma, tc, N = 10.0, 2.0, 30.0, 1.5  # Hz, unit, s, unit s^1/2
    n = 2**20  # 29 h: ~3500 correlation times
    gm = _gm_record(sigma, tc, fs, n, rng)
    r = allan.adev(gm[:, None], fs)
    sel = (r.tau >= 1.0) & (r.tau <= 2000.0)
    exact = np.sqrt(nc.gm_avar(r.tau[sel], sigma, tc))
    ratio = r.adev[sel, 0] / exact
    short = r.tau[sel] <= tc  # thousands of independent terms: tight
    assert np.all(np.abs(ratio[short] - 1.0) < 0.03), ratio
    inside = (exact >= r.lo[sel, 0]) & (exact <= r.hi[sel, 0])
    assert inside.mean() >= 0.8, inside
    assert np.all((exact >= 0.8 * r.lo[sel, 0]) & (exact <= 1.25 * r.hi[sel, 0]))
    # small-tau limit: a random walk with K^2 = 2 sigma^2 / tc
    assert nc.gm_avar(1e-4, sigma, tc) == pytest.approx(2 * sigma**2 / tc * 1e-4 / 3, rel=1e-3)
    # fit white + GM on the sum (as on a long static record)
    y = gm + rng.normal(size=n) * N * math.sqrt(fs)
    m = nc.fit_mean_noise([allan.adev(np.column_stack([y, y, y]), fs)], tau_min_s=0.5, unit="u")
    assert m.slow[0] == "gm"
    assert m.N[0] == pytest.approx(N, rel=0.05)
    assert m.sigma[0] == pytest.approx(sigma, rel=0.15)
    assert m.tc[0] == pytest.approx(tc, rel=0.4)
    lo, hi = m.fit[0]["sigma_ci95"]
    assert lo < m.sigma[0] < hi


def _quad_cov(kernel, t0, T, n=1500):
    """Double integral of kernel(s, t) over windows j, k divided by T_j T_k, midpoint rule."""
    pts = [a + (np.arange(n) + 0.5) / n * d for a, d in zip(t0, T)]
    return np.array([[kernel(p[:, None], q[None, :]).mean() for q in pts] for p in pts])


def test_window_mean_covariances_equal_their_double_integrals():
    t0, T, tc = np.array([0.0, 65.0, 300.0, 130.0]), np.array([60.0, 60.0, 24.0, 36.0]), 300.0
    C = nc.gm_mean_cov(t0, T, tc)
    Cq = _quad_cov(lambda s, t: np.exp(-np.abs(s - t) / tc), t0, T)
    assert np.allclose(C, Cq, rtol=1e-4, atol=1e-6)
    R = nc.rw_mean_cov(t0, T)
    Rq = _quad_cov(np.minimum, t0, T)
    assert np.allclose(R, Rq, rtol=1e-4)
    # M touching windows of length T average to one window of length M T: 1^T C 1 / M^2 = var(M T mean)
    M, Tw = 8, 50.0
    Ct = nc.gm_mean_cov(np.arange(M) * Tw, np.full(M, Tw), tc)
    x = M * Tw / tc
    assert Ct.sum() / M**2 == pytest.approx(2 * tc**2 / (M * Tw) ** 2 * (x - 1 + math.exp(-x)), rel=1e-12)
    # white rate + quantisation on the diagonal: N^2/T + 2 Q^2/T^2
    mdl = nc.MeanNoiseModel("u", Q=np.full(3, 0.3), N=np.full(3, 2.0), slow=["none"] * 3, sigma=np.zeros(3),
                            tc=np.full(3, np.nan), K=np.zeros(3))
    assert np.allclose(mdl.mean_cov(t0, T, 0), np.diag(4.0 / T + 2 * 0.09 / T**2))


def _static_with_times(sigma_w):
    st = synth.synthetic_static(ACC, ATT, sigma_w, None, sensor="accel")
    st.t_start_s = 65.0 * np.arange(st.n)
    return st


def test_common_mode_noise_goes_exactly_into_the_biases():
    """A shift common to every segment mean of an axis (variance s^2, Tc -> inf) is absorbed by that axis' bias
    alone: the sandwich covariance of the norm fit (accel) and of eq. 25 (gyro) gains exactly s^2 on b_i."""
    st = _static_with_times(SIG_A)
    M = st.n
    s2 = np.array([0.04, 0.09, 0.16])
    white = np.stack([np.eye(M) * SIG_A**2] * 3)
    common = white + s2[:, None, None] * np.ones((M, M))
    x9 = tri9_truth(ACC)
    obj = ob.NormObjective(st.means, st.reference, form="tri9", sigma=st.sigma)
    J = obj.jacobian(x9)
    scale = np.ones(9)
    C0 = cv.sandwich_full(J, cv.norm_residual_cov(obj, x9, white), scale)
    C1 = cv.sandwich_full(J, cv.norm_residual_cov(obj, x9, common), scale)
    D = np.zeros((9, 9))
    D[6:, 6:] = np.diag(s2)
    assert np.allclose(C1 - C0, D, atol=1e-9 * np.abs(C0).max())
    gs, pr = gyro_data(5)
    n = 2 * pr.n + gs.n
    gw = np.stack([np.diag(np.concatenate([pr.sigma_plus[:, i], pr.sigma_minus[:, i], gs.sigma[:, i]]) ** 2)
                   for i in range(3)])
    g0 = cal.gyro_components(pr, gs, cov_obs=gw)
    g1 = cal.gyro_components(pr, gs, cov_obs=gw + 100.0 * s2[:, None, None] * np.ones((n, n)))
    assert np.allclose(g0.cov, cal.gyro_components(pr, gs).cov)  # diagonal cov_obs = the independent case
    D = np.zeros((12, 12))
    D[9:, 9:] = np.diag(100.0 * s2)
    assert np.allclose(g1.cov - g0.cov, D, atol=1e-9 * np.abs(g0.cov).max())


def test_zscores_with_correlated_segment_means_need_the_full_covariance():
    """Static means with white noise plus a Gauss-Markov bias (Tc = 300 s, 65 s apart) drawn from their exact
    covariance: with cov_means the bias z-scores are standard normal, with the diagonal sigma alone they are not."""
    st0 = _static_with_times(0.02)
    mdl = nc.MeanNoiseModel("count s-1", Q=np.zeros(3), N=np.full(3, 0.14), slow=["gm"] * 3,
                            sigma=np.full(3, 0.07), tc=np.full(3, 300.0), K=np.zeros(3))
    C = mdl.mean_cov_axes(st0.t_start_s, st0.duration_s)
    L = np.linalg.cholesky(C)
    sd = np.sqrt(np.stack([np.diag(c) for c in C], axis=1))
    t9 = tri9_truth(ACC)
    zf, zd = [], []
    for s in range(120):
        rng = np.random.default_rng(7000 + s)
        st = _static_with_times(sd)
        st.means = st.means + np.einsum("imn,ni->mi", L, rng.normal(size=(st.n, 3)))
        rf = cal.norm_calibration(st, form="tri9", method="lsq", rng=rng, cov_means=C)
        rd = cal.norm_calibration(st, form="tri9", method="lsq", rng=rng)
        assert np.allclose(rf.x, rd.x)  # the estimate does not change, only its covariance
        zf.append((rf.x - t9) / rf.se)
        zd.append((rd.x - t9) / rd.se)
    zf, zd = np.array(zf), np.array(zd)
    _check_z(zf, 0.35, 0.75, 1.25)
    assert np.all(zd[:, 6:].std(axis=0, ddof=1) > 1.5)  # independent-means SEs of the biases: far too small


def test_default_calibration_with_and_without_a_long_static_record(tmp_path):
    """Recording chain: without a long record the result says the bias instability is not in the sigma (and what
    record would fix it); with one, the same estimates get the slow part, and the window times are the plan's."""
    cfg = yaml.safe_load((Path(__file__).parents[2] / "config" / "config.yaml").read_text())
    s = dict(cfg["calibration_session"], dwell_s=20.0, rotation_rates_deg_s=[30.0], revolutions=1)
    stages.simulate_calibration(s, cfg["site"], 3, tmp_path / "s.nc", tmp_path / "s.json")
    stages.simulate_static_check(dict(cfg["static_check"], duration_h=0.3), s, cfg["site"], 4, tmp_path / "l.nc",
                                 tmp_path / "l.json")
    inp = sg.extract(recording_io.load(tmp_path / "s.nc"))
    st = inp.accel_static
    assert np.all(np.diff(st.t_start_s) > st.duration_s[:-1])  # windows in time order, disjoint
    cc = dict(cfg["calibration"], NP=20, EG=60)
    d0 = cs.default_calibration(inp, cc, 1)
    assert "does NOT include bias instability" in d0["noise_note"] and "noise_record" in d0["noise_note"]
    assert any("does NOT include" in n for n in d0["accel"].notes)
    noise = cs.noise_models(inp, tmp_path / "l.nc", cc)
    assert noise["accel"].slow[2] in ("gm", "rw")
    d1 = cs.default_calibration(inp, cc, 1, noise=noise)
    assert np.allclose(d1["accel"].x, d0["accel"].x) and np.allclose(d1["gyro"].x, d0["gyro"].x)
    assert "long static record" in d1["noise_note"]
    assert any("full covariance" in n for n in d1["accel"].notes + d1["gyro"].notes)
    assert np.all(np.isfinite(d1["accel"].se) & (d1["accel"].se > 0)) and np.all(d1["gyro"].se > 0)
