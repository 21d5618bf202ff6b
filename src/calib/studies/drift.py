"""He et al. (2019) study: 50 PSOBE tests, Table 1, Figures 2-4, the baselines and the Cramér–Rao bound.

The bound (:mod:`calib.drift.bound`) comes from the linear error model and the session's noise densities, without
running an estimator; beside it the tables give the Kalman filter's own covariance and each estimator's spread
over its repetitions divided by the bound (the efficiency ratio: 1 for an efficient estimator).

Called by the workflow rules ``drift_pso`` and ``drift_validation`` and by ``calib drift``.
"""
from __future__ import annotations

import contextlib
import json
import math
import time
from pathlib import Path

import numpy as np
import xarray as xr

from calib.drift import bound as crb_bound
from calib.drift import psobe as drift
from calib.core import earth
from calib.drift import pso
from calib.io import recording
from calib.nav import reader as nav_reader
from calib.nav import strapdown
from calib.core.earth import DEG_PER_H
from calib.io.atomic import scratch_folder
from calib.io.netcdf import write_netcdf
from calib.core.progress import Progress
from calib.nav import errormodel
from calib.sim.static_session import simulate_static_session
from calib.signal import allan
from calib.core.rotations import dcm_to_euler
from calib.core import seeds
from calib.io.atomic import write_json, write_text

AXES = ["x", "y", "z"]


def _plots():
    """The study's figures (:mod:`calib.figures.drift_plots`): matplotlib is imported only when a figure is drawn."""
    from calib.figures import drift_plots   # matplotlib: imported only when drawing
    return drift_plots


#: He 2019 Table 1 (PSOBE, 50 tests) and its Ac values (§IV.A), for comparison
PAPER_TABLE1 = {"max": [-0.01032, 0.01077, 0.01079], "min": [-0.01048, 0.01067, 0.009786],
                "mean": [-0.01038, 0.01073, 0.01046], "std": [3.39e-5, 1.735e-5, 1.913e-4],
                "Ac_pct": [96.2, 92.7, 95.4]}


def attitude_rad(att: dict):
    return tuple(math.radians(att[k]) for k in ("pitch", "roll", "yaw"))


def drift_crb(session: dict, win, dt_out: float, condition: str, accel_bias_known: bool = False):
    """The Cramér–Rao bound (:class:`calib.drift.bound.DriftBound`) of the session's drift over the estimators'
    output instants of ``win`` (every ``dt_out`` s), for the simulator's noise densities of ``session``."""
    return crb_pair(session, window_geometry(win, dt_out), condition, (accel_bias_known,))[0]


def window_geometry(win, dt_out: float) -> dict:
    """What the bound needs of a window (:func:`crb_pair`), as plain numbers that JSON carries exactly: the number
    of navigation steps, their interval, the sample rate, the latitude [rad], height [m] and C_b^n of the start,
    and the output interval [s]."""
    return {"n_steps": int(len(win.Dtheta)), "dt_nav": float(win.dt_nav), "sample_rate_hz": float(win.sample_rate_hz),
            "lat0": float(win.lat0), "h0": float(win.h0), "C_bn": np.asarray(win.init.cbn(), float).tolist(),
            "dt_out": float(dt_out)}


def crb_pair(session: dict, geom: dict, condition: str, accel_bias_known=(False, True)) -> tuple:
    """The bounds of :func:`drift_crb` for a window of :func:`window_geometry`, one per entry of
    ``accel_bias_known`` (by default: the accelerometer biases as nuisance, then known), sharing the observation
    noise (:func:`calib.drift.bound.drift_bounds`)."""
    dt_out = geom["dt_out"]
    n_out = geom["n_steps"] // max(1, int(round(dt_out / geom["dt_nav"])))
    q_g, q_a = crb_bound.noise_psd(session, geom["sample_rate_hz"])
    return crb_bound.drift_bounds(n_out * dt_out / 3600.0, dt_out, geom["lat0"], np.asarray(geom["C_bn"], float),
                                  geom["h0"], q_g, q_a, condition, accel_bias_known=tuple(accel_bias_known))


def cost_limits(session: dict, geom: dict, dcfg: dict, crb, crb_known, seed0: int) -> dict:
    """Per estimator of the noise-seed study, what minimising He 2019's J does by itself, from the linear model
    alone (:mod:`calib.drift.bound`, no estimator run), in units of the estimator's own bound: (spread, offset,
    spread of J's minimum). The least squares of J's weighting (every output instant alike) over the columns
    :func:`calib.drift.psobe.linear_lsq` fits: its spread (``lsq_limit_over_crb``, a closed form) and offset.
    J's own minimum over the drift alone, PSOBE's criterion: its offset from the truth on the noise-free data,
    which the accelerometer bias PSOBE does not model causes (``cost_offset_z``, in the bound with the biases as
    nuisance, like ``mean_z``), and its spread over the noise (``cost_min_spread_over_crb``, over the bound with
    the biases known like PSOBE's efficiency; 400 draws of the model, stream (``cost_minimum_draws``) of
    ``seed0``). The Kalman filter does not minimise J: NaN."""
    dt_out = geom["dt_out"]
    n_out = geom["n_steps"] // max(1, int(round(dt_out / geom["dt_nav"])))
    window_h = n_out * dt_out / 3600.0
    C = np.asarray(geom["C_bn"], float)
    lat, h = geom["lat0"], geom["h0"]
    q_g, q_a = crb_bound.noise_psd(session, geom["sample_rate_hz"])
    kl, kn = drift.position_scale(dcfg["position_unit"], lat, h)
    w = np.asarray(dcfg["weights"], float) * np.array([1.0, 1.0, kl, kn])
    theta = np.r_[np.asarray(session["gyro_drift_deg_h"], float) * DEG_PER_H,
                  (C @ np.asarray(session["accel_bias_m_s2"], float))[:2]]
    cond = dcfg["initial_condition"]
    lsq = crb_bound.cost_lsq_limit(window_h, dt_out, lat, C, theta, w, h, q_g, q_a, cond)
    off = crb_bound.cost_offset(window_h, dt_out, lat, C, theta, w, h, cond) / DEG_PER_H
    spread, _ = crb_bound.cost_minimum_spread(window_h, dt_out, lat, C, theta, w,
                                              seeds.stream(seed0, "cost_minimum_draws"), 400, h, q_g, q_a, cond)
    nan = np.full(3, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        def per(v, b=crb):  # none where the bound is inf
            return np.where(np.isfinite(b), v / b, np.nan)
        return {"kalman": (nan, nan, nan),
                "lls_with_accel_bias": (per(lsq.sigma_deg_h()), per(lsq.bias_deg_h()), nan),
                "pso": (nan, per(off), per(spread / DEG_PER_H, crb_known))}


#: why each estimator's spread and offset are what they are, beside the computed numbers (no commas: a CSV field)
NOISE_SEED_REASONS = {
    "kalman": "the filter of the bound's own model",
    "lls_with_accel_bias": "least squares of J: every output instant weighed alike while the errors are correlated "
                           "in time; spread limit lsq_limit_over_crb x the bound (the vertical accelerometer bias it "
                           "also fits takes part of the noise)",
    "pso": "searches the minimum of J (absolute errors) of the drift alone: that minimum spreads "
           "cost_min_spread_over_crb x the bound and the accelerometer bias PSOBE does not model moves it "
           "cost_offset_z bounds from the truth",
}


def _finite(v):
    """JSON-safe float: None where the data do not determine the quantity (inf or nan)."""
    return float(v) if np.isfinite(v) else None


def _csv_num(v) -> str:
    """A number for a CSV field: empty where it does not apply (nan)."""
    return f"{round(float(v), 3) + 0.0:.3f}" if np.isfinite(v) else ""   # + 0.0: no "-0.000"


def noise_psd(session: dict):
    """Process-noise parameters of the session for the linear error model: (ARW [rad/sqrt(s)], white [rad/s])."""
    gn = session["gyro_noise"]
    if gn["model"] == "arw":
        return gn.get("arw_deg_rth", 0.0) * math.pi / 180.0 / 60.0, 0.0
    return 0.0, gn.get("white_deg_h", 0.0) * DEG_PER_H


def run_pso_tests(recording_path, out_nc, out_table, out_baselines, out_timings, fig2, fig3, metrics_path,
                  session: dict, site: dict, nav: dict, dcfg: dict, seed: int, prov=None, log=print):
    """The 50 repeated PSOBE tests on one noise realisation, with the Cramér–Rao bound and the baselines."""
    t_start = time.perf_counter()
    att = attitude_rad(session["attitude_deg"])
    win = drift.load_window(recording_path, dcfg["window_h"], dcfg["nav_rate_hz"], att, site.get("longitude_deg", 0.0))
    log(f"window: {win.n_samples} samples ({dcfg['window_h']} h) pre-integrated to {len(win.Dtheta)} steps "
        f"of {win.dt_nav} s in {time.perf_counter() - t_start:.1f} s")
    cost = drift.NavigationCost(win, dcfg["output_interval_s"], dcfg["weights"], dcfg["position_unit"])
    settings = pso.PSOSettings.from_config(dcfg["pso"])
    truth = np.asarray(session["gyro_drift_deg_h"], float)
    if np.any(truth < settings.lower) or np.any(truth > settings.upper):
        log(f"WARNING: the true drift {truth} deg/h lies outside the PSO search range "
            f"[{settings.lower}, {settings.upper}]: the estimate will be pinned to a bound")
    n_tests = int(dcfg["tests"])
    G = settings.generations
    est = np.empty((n_tests, 3))
    hist = np.empty((n_tests, G + 1))
    pinned = np.zeros((n_tests, 3), bool)
    bar = Progress(n_tests, "PSOBE tests")
    t0 = time.perf_counter()
    for k in range(n_tests):
        rng = seeds.stream(seed, "psobe_test", k)
        r = pso.minimize(cost, rng, settings)
        est[k], hist[k] = r.best, r.history
        pinned[k, r.pinned] = True
        bar(k + 1, f"test {k + 1}: eps = {np.array2string(r.best, precision=5)} deg/h, J = {r.best_cost:.4g}")
    t_pso = time.perf_counter() - t0
    if pinned.any():
        log(f"FLAG: best particle pinned to the search-range bound in {int(pinned.any(1).sum())} of {n_tests} "
            f"tests (axes {[AXES[i] for i in np.where(pinned.any(0))[0]]}): widen drift.pso.lower/upper")

    # ---- Cramér–Rao bound, for the configured noise, window and initial condition (no estimator run) ----
    arw, white = noise_psd(session)
    dt_out = cost.out_every * win.dt_nav
    cond = dcfg["initial_condition"]
    bnd, bnd_known = crb_pair(session, window_geometry(win, dt_out), cond)
    crb_deg_h = bnd.sigma_deg_h()
    crb_known_deg_h = bnd_known.sigma_deg_h()
    log(f"Cramér–Rao bound (1 sigma, nuisance: horizontal accelerometer biases, initial condition {cond}): "
        f"{np.array2string(crb_deg_h, precision=6)} deg/h (accelerometer biases known: "
        f"{np.array2string(crb_known_deg_h, precision=6)}); {bnd.n_observations} observations, condition number "
        f"of their covariance {bnd.cond_sigma:.3g}, of the Fisher matrix {bnd.cond_fisher:.3g}"
        + (f"; {bnd.null.shape[1]} parameter combinations not in the data" if bnd.null.shape[1] else ""))

    # ---- baselines ----
    base = {}
    timing = {"pso_50_tests_s": t_pso, "pso_one_test_s": t_pso / n_tests}
    t = time.perf_counter()
    e, _, n_runs = drift.linear_lsq(cost, with_accel_bias=False)
    timing["lls_drift_only_s"] = time.perf_counter() - t
    base["lls_drift_only"] = e
    t = time.perf_counter()
    e, ab, n_runs = drift.linear_lsq(cost, with_accel_bias=True)
    timing["lls_with_accel_bias_s"] = time.perf_counter() - t
    base["lls_with_accel_bias"] = e
    t = time.perf_counter()
    e, kal_sigma, _ = drift.kalman_baseline(cost, arw, cond, True, white, 1.0 / win.sample_rate_hz)
    timing["kalman_s"] = time.perf_counter() - t
    base["kalman"] = e
    base["pso_mean"] = est.mean(0)
    # where does the PSO error come from? J's own minimum (drift-only model) and, on synthetic data, the minimum
    # with the true accelerometer bias compensated: (PSO - Jmin) is the optimiser, (Jmin - Jmin_comp) the
    # unmodelled accelerometer bias, (Jmin_comp - truth) the noise
    t = time.perf_counter()
    jmin, jmin_val = cost.minimum(est.mean(0))
    base["J_minimum"] = jmin
    ab = np.asarray(session.get("accel_bias_m_s2", [0.0, 0.0, 0.0]), float)
    if np.any(ab):
        base["J_minimum_accel_bias_compensated"] = cost.minimum(truth, accel_bias=ab)[0]
    # the unit of the position terms of J weights them against the velocity terms: show how it moves J's minimum
    for unit in drift.POSITION_UNITS:
        if unit != dcfg["position_unit"]:
            other = drift.NavigationCost(win, dcfg["output_interval_s"], dcfg["weights"], unit)
            base[f"J_minimum_position_in_{unit}"] = other.minimum(jmin)[0]
    timing["J_minimum_search_s"] = time.perf_counter() - t
    log(f"J minimum (drift-only model): {np.array2string(jmin, precision=5)} deg/h, J = {jmin_val:.5g}; "
        f"mean PSO best J = {np.mean([cost(e[None])[0] for e in est[:3]]):.5g}")

    # ---- products ----
    tab = drift.table1(est, truth)
    ds = xr.Dataset(
        {
            "estimate": (("test", "axis"), est, {"units": "deg h-1", "long_name": "PSOBE gyro-drift estimate"}),
            "J_history": (("test", "generation"), hist, {"long_name": "J (He 2019 eq. 18) of the global best per "
                                                                      "generation"}),
            "pinned": (("test", "axis"), pinned.astype(np.int8), {"long_name": "best particle on a range bound"}),
            "truth": (("axis",), truth, {"units": "deg h-1", "long_name": "simulated gyro drift"}),
            "crb": (("axis",), crb_deg_h, {"units": "deg h-1", "long_name": "Cramer-Rao bound, 1 sigma, horizontal "
                                          "accelerometer biases as nuisance (inf: not determined by the data)"}),
            "crb_accel_bias_known": (("axis",), crb_known_deg_h,
                                     {"units": "deg h-1", "long_name": "Cramer-Rao bound, 1 sigma, accelerometer "
                                                                       "biases known (the drift-only model)"}),
            "kalman_sigma": (("axis",), kal_sigma, {"units": "deg h-1", "long_name": "Kalman filter covariance, 1 "
                                                                                    "sigma (the filter's own)"}),
            "pso_spread_over_crb": (("axis",), tab["std"] / crb_deg_h,
                                    {"long_name": "std of the PSOBE tests (one noise realisation) / CRB"}),
            "baseline": (("estimator", "axis"), np.array([base[m] for m in base]),
                         {"units": "deg h-1", "long_name": "gyro drift by the baseline estimators"}),
        },
        coords={"test": ("test", np.arange(1, n_tests + 1), {"long_name": "repeated PSOBE test"}), "axis": AXES,
                "generation": ("generation", np.arange(G + 1), {"long_name": "PSO generation"}),
                "estimator": list(base)},
        attrs={"position_unit": dcfg["position_unit"], "weights": json.dumps(dcfg["weights"]),
               "initial_condition": cond, "window_h": dcfg["window_h"], "pso_variant": settings.variant,
               "frame": "body axes (default: along east-north-up)",
               "crb_method": "calib.drift.bound: linear error model, white gyro and accelerometer noise, Fisher "
                             "information of the navigation errors at the output instants; no estimator run",
               "crb_observations": bnd.n_observations, "crb_condition_observation_covariance": bnd.cond_sigma,
               "crb_condition_fisher": bnd.cond_fisher},
    )
    write_netcdf(ds, out_nc, prov)
    _write_table1(out_table, tab, crb_deg_h, kal_sigma)
    _write_baselines(out_baselines, base, truth, crb_deg_h)
    write_text(out_timings, "quantity,seconds\n" + "".join(f"{k},{v:.4f}\n" for k, v in timing.items()))
    plots = _plots()
    plots.estimates_per_test(fig2, est, truth, crb_deg_h)
    plots.convergence(fig3, hist[0], dcfg["position_unit"])
    z = (est.mean(0) - truth) / crb_deg_h
    axes = lambda v: {a: _finite(x) for a, x in zip(AXES, v)}  # noqa: E731
    metrics = {"Ac_of_mean_pct": dict(zip(AXES, tab["Ac_of_mean_pct"].tolist())),
               "crb_deg_h": axes(crb_deg_h),
               "crb_accel_bias_known_deg_h": axes(crb_known_deg_h),
               "kalman_sigma_deg_h": axes(kal_sigma),
               "crb_condition_observation_covariance": bnd.cond_sigma,
               "pso_mean_error_in_bounds": axes(z),
               "pso_spread_over_bound": axes(tab["std"] / crb_deg_h),
               **{f"{m}_error_in_bounds": axes((base[m] - truth) / crb_deg_h) for m in base}}
    write_text(metrics_path, json.dumps(metrics, indent=2))
    log(json.dumps(metrics, indent=2))
    return ds


def _write_table1(path, tab, crb, kal_sigma):
    """Table 1 with the bound: ``crb_1sigma_deg_h`` (calib.drift.bound; inf where the data do not determine the
    axis), ``std_over_crb`` (the PSOBE tests' spread on this one noise realisation over the bound: the optimiser's
    share of the error; the spread over noise realisations is in noise_seeds.csv) and the Kalman filter's own
    1-sigma ``kalman_sigma_deg_h``."""
    rows = ["axis,max_deg_h,min_deg_h,mean_deg_h,std_deg_h,reference_deg_h,Ac_of_mean_pct,Ac_mean_pct,"
            "crb_1sigma_deg_h,std_over_crb,kalman_sigma_deg_h,Ac_limit_1sigma_pct,paper_mean_deg_h,paper_std_deg_h,"
            "paper_Ac_pct"]
    for i, a in enumerate(AXES):
        lim = 100.0 * (1.0 - crb[i] / abs(tab["reference"][i]))
        rows.append(",".join([f"eps_{a}"] + [f"{tab[k][i]:.6g}" for k in ("max", "min", "mean", "std", "reference",
                                                                            "Ac_of_mean_pct", "Ac_mean_pct")]
                             + [f"{crb[i]:.6g}", f"{tab['std'][i] / crb[i]:.3g}", f"{kal_sigma[i]:.6g}",
                                f"{lim:.2f}", f"{PAPER_TABLE1['mean'][i]}",
                                f"{PAPER_TABLE1['std'][i]}", f"{PAPER_TABLE1['Ac_pct'][i]}"]))
    write_text(path, "\n".join(rows) + "\n")


def _write_baselines(path, base, truth, crb):
    rows = ["method,eps_x_deg_h,eps_y_deg_h,eps_z_deg_h,Ac_x_pct,Ac_y_pct,Ac_z_pct,err_x_over_crb,err_y_over_crb,"
            "err_z_over_crb"]
    for m, e in base.items():
        ac = pso.accuracy(e, truth)
        z = (e - truth) / crb
        rows.append(",".join([m] + [f"{v:.6g}" for v in e] + [f"{v:.2f}" for v in ac] + [f"{v:.2f}" for v in z]))
    write_text(path, "\n".join(rows) + "\n")


def run_validation(recording_path, pso_nc, out_nc, fig4, metrics_path, session: dict, site: dict, nav: dict,
                   dcfg: dict, prov=None, log=print, chunk=None):
    """Navigate the whole recording (240 h) without and with compensation by the mean PSOBE estimate (and by
    the Kalman baseline), in one streamed pass with three streams; He 2019 Figure 4."""
    with xr.open_dataset(pso_nc, engine="netcdf4") as p:
        mean_est = p["estimate"].values.mean(0)
        kal = p["baseline"].sel(estimator="kalman").values
        crb = p["crb"].values
    truth = np.asarray(session["gyro_drift_deg_h"], float)
    h = recording.read_header(recording_path)
    att = attitude_rad(session["attitude_deg"])
    lat0, lon0 = math.radians(h.latitude_deg), math.radians(site.get("longitude_deg", 0.0))
    init = strapdown.NavInit(lat=lat0, lon=lon0, h=h.height_m, pitch=att[0], roll=att[1], yaw=att[2])
    n_sub = int(round(h.sample_rate_hz / nav["nav_rate_hz"]))
    dt_nav = n_sub / h.sample_rate_hz
    out_every = max(1, int(round(nav["output_interval_s"] / dt_nav)))
    streams = np.array([np.zeros(3), mean_est, kal]) * DEG_PER_H
    names = ["uncompensated", "pso_mean", "kalman"]
    st = {"state": None, "carry": None}
    outs = []
    bar = Progress(h.n_samples, "240 h navigation")

    def step(i0, acc, gyr):   # runs in the reader's worker thread while the next slice is read
        dth = recording.to_si(gyr, h.gyro_units, h.gyro_kind, h.dt, "gyro")
        dv = recording.to_si(acc, h.accel_units, h.accel_kind, h.dt, "accel")
        if st["carry"] is None:
            st["carry"] = strapdown.new_carry(dth[0], dv[0])
        D1, D2 = strapdown.preintegrate(dth, dv, n_sub, st["carry"])
        o, st["state"] = strapdown.navigate_multi(D1, D2, dt_nav, st["state"] or init, streams, None, out_every)
        outs.append(o)

    nav_reader.for_each_chunk(recording_path, step, header=h, chunk=chunk, progress=bar)
    out = np.concatenate(outs, axis=1)
    t_s = np.arange(1, out.shape[1] + 1) * out_every * dt_nav
    wrap = lambda a: (a + math.pi) % (2 * math.pi) - math.pi  # noqa: E731
    arcmin = 180.0 / math.pi * 60.0
    r_m, r_n = earth.radii(lat0)
    data = {
        "pitch_err": (("stream", "time"), arcmin * wrap(out[..., 0] - att[0]),
                     {"units": "arcmin", "long_name": "pitch error (navigated - true)"}),
        "roll_err": (("stream", "time"), arcmin * wrap(out[..., 1] - att[1]),
                    {"units": "arcmin", "long_name": "roll error (navigated - true)"}),
        "yaw_err": (("stream", "time"), arcmin * wrap(out[..., 2] - att[2]),
                   {"units": "arcmin", "long_name": "yaw error (navigated - true)"}),
        "vE_err": (("stream", "time"), out[..., 3],
                  {"units": "m s-1", "long_name": "east velocity error"}),
        "vN_err": (("stream", "time"), out[..., 4],
                  {"units": "m s-1", "long_name": "north velocity error"}),
        "lon_err": (("stream", "time"), arcmin * (out[..., 7] - lon0),
                   {"units": "arcmin", "long_name": "longitude error"}),
        "lat_err": (("stream", "time"), arcmin * (out[..., 6] - lat0),
                   {"units": "arcmin", "long_name": "latitude error"}),
        "compensation": (("stream", "axis"), streams / DEG_PER_H, {"units": "deg h-1",
                                                                   "long_name": "gyro drift compensated"}),
    }
    ds = xr.Dataset(data, coords={"stream": names, "axis": AXES,
                                  "time": ("time", t_s, {"units": "s", "long_name": "time from start"})},
                    attrs={"frame": "errors = computed - true; attitude C_b^n = Rz(yaw) Rx(pitch) Ry(roll), ENU",
                           "nav_rate_hz": nav["nav_rate_hz"], "vertical_channel": "held at the initial height"})
    write_netcdf(ds, out_nc, prov)
    _plots().navigation_errors(fig4, ds)
    # residual drift along the Earth axis drives longitude: d(lambda)/dt = eps_N cos L + eps_U sin L (ENU)
    C = init.cbn()
    metrics = {}
    for s, name in enumerate(names):
        resid = C @ ((truth - streams[s] / DEG_PER_H) * DEG_PER_H)
        polar = resid[1] * math.cos(lat0) + resid[2] * math.sin(lat0)
        # the linear error model's longitude response to the residual drift (and the true accelerometer bias)
        # at the end; its secular part grows at the drift component along the Earth's axis

        ab = np.asarray(session.get("accel_bias_m_s2", [0.0, 0.0, 0.0]), float)
        T_end = t_s[-1]
        resp = errormodel.error_response(np.array([0.0, T_end]), lat0, C.T @ resid, ab, C, h.height_m,
                                         drift_coupling=True)
        pred = float(resp["lon_err"].values[-1]) * arcmin
        secular = errormodel.longitude_rate(lat0, C.T @ resid, C) * T_end * arcmin
        metrics[name] = {"lon_err_240h_arcmin": float(ds["lon_err"].values[s, -1]),
                         "lon_err_predicted_arcmin": float(pred),
                         "lon_err_secular_part_arcmin": float(secular),
                         "residual_polar_drift_deg_h": float(polar / DEG_PER_H),
                         "max_abs_vE_m_s": float(np.abs(ds["vE_err"].values[s]).max()),
                         "max_abs_vN_m_s": float(np.abs(ds["vN_err"].values[s]).max())}
    arw, white = noise_psd(session)
    sig = drift.longitude_noise_sigma(t_s[-1], lat0, C, arw, white, h.dt) * arcmin
    for name in names:
        m = metrics[name]
        m["lon_err_noise_sigma_arcmin"] = sig
        m["lon_err_within_2sigma_of_prediction"] = bool(abs(m["lon_err_240h_arcmin"] - m["lon_err_predicted_arcmin"])
                                                        <= 2 * sig)
    # bound on the polar component of the estimate: propagate the per-axis CRB (independent approximation)
    cvec = C.T @ np.array([0.0, math.cos(lat0), math.sin(lat0)])
    metrics["polar_bound_deg_h"] = _finite(math.sqrt(np.sum((cvec * crb) ** 2)))
    write_text(metrics_path, json.dumps(metrics, indent=2))
    log(json.dumps(metrics, indent=2))
    return ds


def binomial_band(n: int, p: float = 0.95, level: float = 0.99):
    """Two-sided ``level`` acceptance band for the count of successes out of ``n`` at rate ``p``."""
    from scipy.stats import binom

    a = (1.0 - level) / 2.0
    return int(binom.ppf(a, n, p)), int(binom.isf(a, n, p))


#: the estimators of the noise-seed study, in the order of its tables
NOISE_SEED_ESTIMATORS = ("kalman", "lls_with_accel_bias", "pso")


def run_noise_seeds(out_nc, out_csv, fig, metrics_path, session: dict, site: dict, dcfg: dict, n_seeds: int,
                    seed0: int, workdir, prov=None, log=print):
    """Repeat the scenario over ``n_seeds`` noise realisations: the Kalman filter, the linear least squares with
    accelerometer biases and one PSOBE test per seed, against the Cramér–Rao bound (:mod:`calib.drift.bound`).

    Each seed's window is simulated to a temporary recording (the same generator as the data stage), then
    estimated; z = (estimate - truth) / bound (the accelerometer biases as nuisance). The efficiency ratio is the
    spread over the seeds divided by the bound of the model the estimator fits (PSOBE fits the drift-only model:
    the bound with the accelerometer biases known). Acceptance (``consistent``): |z| <= 2 in a share of seeds
    inside the binomial 99 % band around 95 %, and std(z) in 0.85-1.15 -- unbiased and efficient.

    One run of every seed (:func:`noise_seed_block`) and the products (:func:`noise_seed_products`); the workflow
    runs blocks of seeds as jobs of their own and gathers them.
    """
    block = noise_seed_block(session, site, dcfg, seed0, 0, n_seeds, workdir)
    return noise_seed_products([block], out_nc, out_csv, fig, metrics_path, session, dcfg, n_seeds, seed0, prov,
                               log=log, workdir=None)


def noise_seed_block(session: dict, site: dict, dcfg: dict, seed0: int, first: int, stop: int, workdir,
                     progress: bool = True) -> dict:
    """Seeds ``first`` .. ``stop - 1`` of the noise-seed study: per seed, in order, the estimates [deg/h] of
    :data:`NOISE_SEED_ESTIMATORS` and the Kalman filter's 1-sigma [deg/h]; with the window's
    :func:`window_geometry` (the bound is computed once, from it, by :func:`noise_seed_products`).

    Seed ``k`` simulates its window from ``seeds.child_seed(seed0, "session", k)`` and runs PSOBE on the stream
    ``("psobe_test", k)``: a block holds the same numbers as the same seeds of one run. Its recording lives in
    the scratch folder ``workdir`` (made for the block, removed again when empty) one seed at a time.
    """
    first, stop = int(first), int(stop)
    if not 0 <= first <= stop:
        raise ValueError(f"noise seeds {first} .. {stop - 1}: expected 0 <= first <= stop")
    att = attitude_rad(session["attitude_deg"])
    arw, white = noise_psd(session)
    cond = dcfg["initial_condition"]
    n = stop - first
    est = {m: np.empty((n, 3)) for m in NOISE_SEED_ESTIMATORS}
    kal = np.empty((n, 3))
    settings = pso.PSOSettings.from_config(dcfg["pso"])
    geom = None
    bar = Progress(n, f"noise seeds {first} .. {stop - 1}") if progress else None
    cfg = dict(session)
    cfg.update(mode="physical", duration_h=dcfg["window_h"], site={"latitude_deg": site["latitude_deg"],
                                                                 "height_m": site.get("height_m", 0.0)})
    with scratch_folder(workdir) as work:   # one seed's recording at a time
        for i, k in enumerate(range(first, stop)):
            path = work / f"seed{k}.nc"
            try:
                simulate_static_session(cfg, seeds.child_seed(seed0, "session", k), path)
                win = drift.load_window(path, dcfg["window_h"], dcfg["nav_rate_hz"], att,
                                        site.get("longitude_deg", 0.0))
            finally:   # also when interrupted: no seed file is left behind
                path.unlink(missing_ok=True)
            cost = drift.NavigationCost(win, dcfg["output_interval_s"], dcfg["weights"], dcfg["position_unit"])
            est["kalman"][i], kal[i], _ = drift.kalman_baseline(cost, arw, cond, True, white, 1.0 / win.sample_rate_hz)
            est["lls_with_accel_bias"][i] = drift.linear_lsq(cost, True)[0]
            est["pso"][i] = pso.minimize(cost, seeds.stream(seed0, "psobe_test", k), settings).best
            if geom is None:   # the same window for every seed
                geom = window_geometry(win, cost.out_every * win.dt_nav)
            if bar is not None:
                bar(i + 1)
    return {"first": first, "stop": stop, "estimates": est, "kalman_sigma": kal, "geometry": geom}


def write_noise_seed_block(block: dict, path):
    """A :func:`noise_seed_block` as JSON for the gathering job (floats to the last bit)."""
    return write_json({"first": block["first"], "stop": block["stop"],
                       "estimates": {m: np.asarray(v).tolist() for m, v in block["estimates"].items()},
                       "kalman_sigma": np.asarray(block["kalman_sigma"]).tolist(), "geometry": block["geometry"]},
                      path, strict=False)


def read_noise_seed_blocks(paths) -> list:
    """The blocks written by :func:`write_noise_seed_block`, in seed order (:func:`noise_seed_products` refuses a
    gap or an overlap)."""
    blocks = sorted((json.loads(Path(p).read_text()) for p in paths), key=lambda b: (b["first"], b["stop"]))
    for b in blocks:
        b["estimates"] = {m: np.asarray(v, dtype=float).reshape(-1, 3) for m, v in b["estimates"].items()}
        b["kalman_sigma"] = np.asarray(b["kalman_sigma"], dtype=float).reshape(-1, 3)
    return blocks


def noise_seed_products(blocks: list, out_nc, out_csv, fig, metrics_path, session: dict, dcfg: dict, n_seeds: int,
                        seed0: int, prov=None, log=print, workdir=None):
    """The noise-seed table, dataset, metrics and figure (:func:`run_noise_seeds`) from the blocks of
    :func:`noise_seed_block` (in seed order, together every seed once). The bound comes from the windows'
    geometry, which every block must share. ``workdir``: the study's scratch folder, whose blocks' folders are
    removed by now: removed too when empty."""
    nxt = 0
    for b in blocks:
        if b["first"] != nxt:
            raise ValueError(f"noise-seed blocks: seeds {min(nxt, b['first'])} .. {max(nxt, b['first']) - 1} "
                             "missing or given twice")
        nxt = b["stop"]
    if nxt != n_seeds:
        raise ValueError(f"drift.noise_seeds: {n_seeds} seeds configured, the blocks hold seeds 0 .. {nxt - 1}")
    geoms = [b["geometry"] for b in blocks if b["stop"] > b["first"]]
    if not geoms:
        raise ValueError("drift.noise_seeds: the study needs at least one seed -- fix: set drift.noise_seeds >= 2")
    if any(g != geoms[0] for g in geoms[1:]):
        raise ValueError("noise-seed blocks: their windows differ (made with different drift settings) -- fix: "
                         "remove the blocks and run them again")
    if workdir is not None:
        with contextlib.suppress(OSError):
            Path(workdir).rmdir()
    truth = np.asarray(session["gyro_drift_deg_h"], float)
    cond = dcfg["initial_condition"]
    est = {m: np.concatenate([b["estimates"][m] for b in blocks]) for m in NOISE_SEED_ESTIMATORS}
    kal_sigma = np.concatenate([b["kalman_sigma"] for b in blocks])[-1]   # the same for every seed
    crb, crb_known = (b.sigma_deg_h() for b in crb_pair(session, geoms[0], cond))
    names = list(est)
    own = {m: crb_known if m == "pso" else crb for m in names}   # the bound of the model each estimator fits
    z = np.array([(est[m] - truth) / crb for m in names])  # (method, seed, axis)
    spread = np.array([est[m].std(0, ddof=1) for m in names])  # (method, axis)
    eff = np.array([spread[i] / own[m] for i, m in enumerate(names)])
    lo, hi = binomial_band(n_seeds)
    ds = xr.Dataset({"estimate": (("estimator", "seed", "axis"), np.array([est[m] for m in names]),
                                  {"units": "deg h-1", "long_name": "gyro drift estimate"}),
                     "z": (("estimator", "seed", "axis"), z, {"long_name": "(estimate - truth) / Cramer-Rao bound"}),
                     "crb": (("axis",), crb, {"units": "deg h-1", "long_name": "Cramer-Rao bound, 1 sigma, horizontal "
                                              "accelerometer biases as nuisance (calib.drift.bound)"}),
                     "crb_accel_bias_known": (("axis",), crb_known,
                                              {"units": "deg h-1", "long_name": "Cramer-Rao bound, 1 sigma, "
                                                                                "accelerometer biases known"}),
                     "kalman_sigma": (("axis",), kal_sigma, {"units": "deg h-1", "long_name": "Kalman filter "
                                                                                  "covariance, 1 sigma"}),
                     "efficiency": (("estimator", "axis"), eff,
                                    {"long_name": "std over the seeds / Cramer-Rao bound of the estimator's model"}),
                     "truth": (("axis",), truth, {"units": "deg h-1", "long_name": "simulated gyro drift"})},
                    coords={"estimator": names, "axis": AXES,
                            "seed": ("seed", np.array([seeds.child_seed(seed0, "session", k) for k in range(n_seeds)],
                                                      dtype=np.int64), {"long_name": "noise seed"})},
                    attrs={"initial_condition": cond, "window_h": dcfg["window_h"]})
    write_netcdf(ds, out_nc, prov)
    rows = ["estimator,axis,mean_z,std_z,within_2_bounds,n_seeds,band99_low,band99_high,consistent,crb_deg_h,"
            "crb_accel_bias_known_deg_h,kalman_sigma_deg_h,std_deg_h,efficiency,lsq_limit_over_crb,cost_offset_z,"
            "cost_min_spread_over_crb,reason"]
    limits = cost_limits(session, geoms[0], dcfg, crb, crb_known, seed0)
    metrics = {"n_seeds": n_seeds, "band99": [lo, hi], "crb_deg_h": {a: _finite(v) for a, v in zip(AXES, crb)},
               "crb_accel_bias_known_deg_h": {a: _finite(v) for a, v in zip(AXES, crb_known)},
               "kalman_sigma_deg_h": dict(zip(AXES, kal_sigma.tolist()))}
    for i, m in enumerate(names):
        for j, a in enumerate(AXES):
            within = int(np.sum(np.abs(z[i, :, j]) <= 2.0))
            ok = lo <= within <= hi and 0.85 <= z[i, :, j].std(ddof=1) <= 1.15
            rows.append(f"{m},{a},{z[i, :, j].mean():.3f},{z[i, :, j].std(ddof=1):.3f},{within},{n_seeds},{lo},{hi},{ok},"
                        f"{crb[j]:.6g},{crb_known[j]:.6g},{kal_sigma[j]:.6g},{spread[i, j]:.6g},{eff[i, j]:.3f},"
                        f"{_csv_num(limits[m][0][j])},{_csv_num(limits[m][1][j])},{_csv_num(limits[m][2][j])},"
                        f"{NOISE_SEED_REASONS[m]}")
            metrics[f"{m}.{a}"] = {"mean_z": _finite(z[i, :, j].mean()), "std_z": _finite(z[i, :, j].std(ddof=1)),
                                   "within_2_bounds": within, "std_deg_h": float(spread[i, j]),
                                   "efficiency": _finite(eff[i, j]),
                                   "lsq_limit_over_crb": _finite(limits[m][0][j]),
                                   "cost_offset_z": _finite(limits[m][1][j]),
                                   "cost_min_spread_over_crb": _finite(limits[m][2][j]),
                                   "reason": NOISE_SEED_REASONS[m]}
    write_text(out_csv, "\n".join(rows) + "\n")
    write_text(metrics_path, json.dumps(metrics, indent=2))
    log("\n".join(rows))
    _plots().noise_seed_z(fig, z, names, n_seeds)
    return ds


def run_real_drift(recording_path, out_json, fig, metrics_path, rcfg: dict, seed: int, log=print):
    """PSOBE on a real static recording without known latitude or heading (issue: ADIS16405 data).

    The initial attitude is levelled by the accelerometers over the first second (heading set to 0: unknown);
    a short window keeps the MEMS navigation errors near-linear. The PSO estimate is compared with the mean
    gyro output over the same window: they may differ by the Earth rate seen by the gyros (|omega_ie^b| <=
    Omega at an unknown heading and latitude) plus 2 Allan-deviation sigma of the window mean.
    """

    h = recording.read_header(recording_path)
    win_s = float(rcfg["window_s"])
    n = int(round(win_s * h.sample_rate_hz))
    if n > h.n_samples:
        raise ValueError(f"{recording_path}: drift window {win_s} s is longer than the recording "
                         f"({h.duration_s:.1f} s) -- fix: shorten recording.drift.window_s")
    acc_all, gyr_all = [], []
    for _, a, g in recording.iter_raw_chunks(recording_path, h, stop=max(n, int(600 * h.sample_rate_hz))):
        acc_all.append(a)
        gyr_all.append(g)
    acc = recording.to_si(np.concatenate(acc_all), h.accel_units, h.accel_kind, h.dt, "accel") / h.dt
    gyr = recording.to_si(np.concatenate(gyr_all), h.gyro_units, h.gyro_kind, h.dt, "gyro") / h.dt
    # stationarity check on the window: the accelerometer norm must stay near g
    an = np.linalg.norm(acc[:n], axis=1)
    if np.std(an) > 0.05 * np.mean(an):
        raise ValueError(f"{recording_path}: the recording is not stationary over the drift window (accel norm "
                         f"scatter {np.std(an):.3g} m/s^2) -- choose a static window")
    f0 = acc[: int(h.sample_rate_hz)].mean(0)
    # levelling: C_b^n such that C_b^n f0 is vertical (heading 0)
    up = f0 / np.linalg.norm(f0)
    east = np.cross([0.0, 1.0, 0.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    C = np.vstack([east, north, up])
    pitch, roll, yaw = (float(v) for v in dcm_to_euler(C))
    win = drift.load_window(recording_path, win_s / 3600.0, rcfg.get("nav_rate_hz", h.sample_rate_hz),
                            (pitch, roll, yaw))
    cost = drift.NavigationCost(win, rcfg.get("output_interval_s", 1.0), rcfg.get("weights", [1, 1, 1, 10]),
                                rcfg.get("position_unit", "m"))
    settings = pso.PSOSettings.from_config(rcfg["pso"])
    ests, Js = [], []
    for k in range(int(rcfg.get("tests", 10))):
        r = pso.minimize(cost, seeds.stream(seed, "psobe_test", k), settings)
        ests.append(r.best)
        Js.append(r.best_cost)
        if r.pinned:
            log(f"FLAG: test {k}: best particle pinned to the search range on axes {r.pinned} -- widen the range")
    ests = np.array(ests)
    mean_gyro = gyr[:n].mean(0) / DEG_PER_H  # deg/h
    ad = allan.adev(gyr[:n] / DEG_PER_H, h.sample_rate_hz, unit="deg h-1")
    sigma = np.asarray(ad.sigma_of_mean(win_s)).reshape(-1)[:3]
    omega = earth.OMEGA_IE / DEG_PER_H
    band = omega + 2.0 * sigma
    diff = ests.mean(0) - mean_gyro
    # a drift about the vertical only turns the heading: within a short window it barely moves velocity or
    # position, so that axis is not determined by J (the spread over the tests shows it)
    vertical = [bool(abs(C[2, i]) > 0.9) for i in range(3)]
    out = {"window_s": win_s, "estimate_mean_deg_h": ests.mean(0).tolist(), "estimate_std_deg_h": ests.std(0).tolist(),
           "mean_gyro_output_deg_h": mean_gyro.tolist(), "difference_deg_h": diff.tolist(),
           "allowed_band_deg_h": band.tolist(), "allan_sigma_of_window_mean_deg_h": sigma.tolist(),
           "within_band": [None if v else bool(abs(d) <= b) for d, b, v in zip(diff, band, vertical)],
           "undetermined_axes": [a for a, v in zip(AXES, vertical) if v],
           "undetermined_reason": "body axis along gravity: its drift only turns the heading, which a short window "
                                  "does not see in velocity or position; a longer window, a heading reference or "
                                  "a rotation of the unit would determine it",
           "initial_attitude_deg": [math.degrees(pitch), math.degrees(roll), 0.0],
           "note": "latitude and heading unknown: the difference may hold any Earth-rate component up to "
                   f"{omega:.3f} deg/h; the band adds 2 Allan sigma of the window mean"}
    write_text(out_json, json.dumps(out, indent=2))
    write_text(metrics_path, json.dumps({"within_band_all_level_axes": float(all(w for w in out["within_band"] if w is not None)),
                                              **{f"difference_{a}_deg_h": float(d) for a, d in zip(AXES, diff)}},
                                             indent=2))
    _plots().real_drift(fig, ests, mean_gyro, band, win_s)
    log(json.dumps(out, indent=2))
    return out
