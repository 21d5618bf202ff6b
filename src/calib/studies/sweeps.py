"""Parameter sweeps: one small synthetic study per point of a grid, gathered into one labelled netCDF
(:mod:`calib.studies.sweep_summary`).

A sweep file (``config/sweeps/*.yaml``, schema ``workflow/schemas/sweep.schema.yaml``) names a ``kind``, the
``grid`` of swept parameters (full factorial), optional ``fixed`` values of other sweep parameters and
``base`` overrides merged into the study config (same keys and ranges as ``config/config.yaml``)::

    name: calibration_budget
    kind: calibration              # calibration | drift_pso
    base: {calibration_session: {dwell_s: 10.0, rotation_rates_deg_s: []}, calibration: {runs: 4}}
    fixed: {method: ide, problem: accel}
    grid: {NP: [10, 20, 40], EG: [30, 60], noise_scale: [1, 10], seed: [1, 2]}

The points become a :class:`snakemake.utils.Paramspace` (one path component per point,
``noise_scale~1_seed~1_NP~10_EG~30``). Parameters that change the synthetic session (``data`` parameters:
``seed``, ``noise_scale``, ``dwell_s`` / ``window_h``) come first, so the points that share a session share
one simulated recording (a second Paramspace over those columns).

Kinds and what one point computes:

* ``calibration`` (Liu 2021): ``runs`` identifications of one problem (``accel``: L_a of eq. 7 in the
  paper's 12-parameter form; ``gyro_static``: L_g of eq. 7; ``gyro_dynamic``: L_gm of eq. 26, then the biases)
  with one optimiser (population NP, EG generations; optimiser run r draws from the stream ``("run", r)`` of ``seeds.calibration``);
  L* = the best of 10 multi-start least-squares fits and of the runs; success: L <= (1 + tol) L*
  (``calibration.success_rel_tol``, the rule of Table 5). Error of the identified (K E)(K E)^T (what the
  norm determines) and of the biases against the simulated truth.
* ``drift_pso`` (He 2019): ``tests`` PSOBE runs (test k draws from the stream ``("psobe_test", k)`` of ``seeds.drift``) on the first
  ``window_h`` hours; the Cramer-Rao bound of the drift for that window and noise; the minimiser of J (eq. 18)
  over the PSO search box (a linear programme on the linearised navigation errors, :func:`argmin_J`), so the
  error of a PSO estimate splits into the optimiser's part (estimate - argmin J) and the estimator's
  (argmin J - truth), both in Cramer-Rao bounds.

Reading and validating sweep files, the grid and each point's config: :mod:`calib.studies.sweep_spec` (light, for the
workflow's parse), re-exported here.
"""
from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import xarray as xr

from calib.studies import stages
from calib.io.netcdf import write_netcdf
from calib.calibration import fit as cal
from calib.calibration import objectives as ob
from calib.io import recording
from calib.signal import segments
from calib.studies.calibration import truth_vector, method_options
from calib.core.triad import PARAM_NAMES
from calib.drift import psobe as drift
from calib.drift import pso
from calib.studies.drift import attitude_rad, drift_crb
from calib.core import seeds

from calib.studies.sweep_spec import (  # noqa: F401 - the sweep files, re-exported
    KINDS, PARAMETERS, PROBLEMS, SECTIONS, SWEEP_DEFAULTS, Parameter, Sweep, SweepError, deep_merge, load, load_all,
    parameter_names)


# ---------------------------------------------------------------------------------------------------------
# stage functions (called by workflow/scripts/sweep_*.py)
# ---------------------------------------------------------------------------------------------------------
def simulate_session(scfg: dict, out, truth, rule="sweep_session"):
    """The synthetic session of one group of points (``scfg`` from :meth:`Sweep.session_config`)."""

    if scfg["kind"] == "calibration":
        stages.simulate_calibration(scfg["session"], scfg["site"], scfg["seed"], out, truth, rule=rule)
    else:
        stages.simulate_navigation(scfg["session"], scfg["site"], scfg["seed"], out, truth, rule=rule)


def run_point(kind: str, recording_path, truth_path, cfg: dict, values: dict, out_nc, prov=None, log=print):
    """One sweep point; writes a small netCDF (scalars and per-run/test arrays, no wall times)."""
    if kind == "calibration":
        ds = calibration_point(recording_path, truth_path, cfg, log=log)
    elif kind == "drift_pso":
        ds = drift_point(recording_path, cfg, log=log)
    else:
        raise SweepError(f"unknown sweep kind {kind!r}; one of {', '.join(KINDS)}")
    ds.attrs["point"] = json.dumps(values, sort_keys=True)

    write_netcdf(ds, out_nc, prov)
    return ds


def _problem_fn(inp, problem):

    if problem == "accel":
        return lambda m, rng, budget, opts: cal.norm_calibration(inp.accel_static, form="paper12", method=m, rng=rng,
                                                                  budget=budget, **opts)
    if problem == "gyro_static":
        return lambda m, rng, budget, opts: cal.norm_calibration(inp.gyro_static, form="paper12", method=m, rng=rng,
                                                                  budget=budget, **opts)
    if inp.gyro_pairs is None:
        raise SweepError("problem gyro_dynamic needs rotation segments -- fix: give "
                         "calibration_session.rotation_rates_deg_s in the sweep's base")
    return lambda m, rng, budget, opts: cal.gyro_dynamic(inp.gyro_pairs, inp.gyro_static, method=m, rng=rng,
                                                         budget=budget, **opts)


def calibration_point(recording_path, truth_path, cfg: dict, log=print):
    """``runs`` identifications of one Liu 2021 problem with one optimiser; see the module docstring."""
    ccfg, sw = cfg["calibration"], cfg["sweep"]
    method, problem = sw["method"], sw["problem"]
    if problem not in PROBLEMS:
        raise SweepError(f"sweep problem {problem!r}: one of {', '.join(PROBLEMS)}")
    R, NP, EG = int(ccfg["runs"]), int(ccfg["NP"]), int(ccfg["EG"])
    seed = int(cfg["seeds"]["calibration"])
    tol = float(ccfg.get("success_rel_tol", 0.01))
    inp = segments.extract(recording.load(recording_path))
    fn = _problem_fn(inp, problem)
    opts = method_options(method, ccfg)
    L = np.empty(R)
    x = np.empty((R, 12))
    hist = np.full((R, EG + 1), np.nan)
    on_bound = np.zeros(R, np.int8)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # bound hits are counted below
        for r in range(R):
            res = fn(method, seeds.stream(seed, "run", r), (NP, EG), opts)
            L[r], x[r] = res.L, res.paper_vector()
            on_bound[r] = bool(res.on_bound)
            h = getattr(res.optimizer, "history", None)
            if h is not None and len(h):
                k = min(len(h), EG + 1)
                hist[r, :k] = np.asarray(h)[:k]
        lsq = [fn("lsq", seeds.stream(seed, "lsq_multistart", r), (NP, EG), {}).L for r in range(10)]
    L_star = float(min(min(lsq), L.min()))
    success = L <= L_star * (1.0 + tol)
    sensor = "accel" if problem == "accel" else "gyro"
    truth = json.loads(Path(truth_path).read_text()) if truth_path else None
    tv = truth_vector(truth, sensor) if truth else None
    gram_err = np.full(R, np.nan)
    bias_err = np.full((R, 3), np.nan)
    if tv is not None:
        form = ob.Form("paper12")
        Mt, bt = form.KE_b(tv)
        Gt = Mt @ Mt.T
        for r in range(R):
            M, b = form.KE_b(x[r])
            gram_err[r] = np.abs(M @ M.T - Gt).max() / np.abs(Gt).max()
            bias_err[r] = b - bt
    log(f"{problem} {method} NP={NP} EG={EG}: success {100 * success.mean():.0f} %, mean L {L.mean():.4g}, "
        f"L* {L_star:.4g}")
    unit = "count s-1"
    return xr.Dataset(
        {"L": (("run",), L, {"long_name": res.objective}),
         "success": (("run",), success.astype(np.int8), {"long_name": f"L <= (1 + {tol}) L*"}),
         "success_pct": ((), 100.0 * float(success.mean()), {"units": "%"}),
         "mean_L": ((), float(L.mean())),
         "L_star": ((), L_star, {"long_name": "best of 10 multi-start least squares and the runs"}),
         "mean_L_over_L_star": ((), float(L.mean() / L_star) if L_star > 0 else math.nan),
         "on_bound": (("run",), on_bound, {"long_name": "a parameter ended on a search bound"}),
         "estimate": (("run", "parameter"), x, {"long_name": "K, E, b (Liu 2021 eq. 8) as identified"}),
         "gram_rel_error": (("run",), gram_err, {"long_name": "max |(KE)(KE)^T - truth| / max |truth|"}),
         "bias_error": (("run", "axis"), bias_err, {"units": unit}),
         "history": (("run", "generation"), hist, {"long_name": "best L per generation"})},
        coords={"run": np.arange(R), "parameter": list(PARAM_NAMES), "axis": ["x", "y", "z"],
                "generation": np.arange(EG + 1)},
        attrs={"problem": problem, "method": method, "NP": NP, "EG": EG, "runs": R,
               "objective": res.objective, "success_rel_tol": tol})


def drift_point(recording_path, cfg: dict, log=print):
    """``tests`` PSOBE runs against the noise limit and the minimiser of J; see the module docstring."""
    session, site, dcfg = cfg["navigation_session"], cfg["site"], cfg["drift"]
    att = attitude_rad(session["attitude_deg"])
    win = drift.load_window(recording_path, dcfg["window_h"], dcfg["nav_rate_hz"], att, site.get("longitude_deg", 0.0))
    cost = drift.NavigationCost(win, dcfg["output_interval_s"], dcfg["weights"], dcfg["position_unit"])
    settings = pso.PSOSettings.from_config(dcfg["pso"])
    truth = np.asarray(session["gyro_drift_deg_h"], float)
    T, G = int(dcfg["tests"]), settings.generations
    seed = int(cfg["seeds"]["drift"])
    est = np.empty((T, 3))
    J = np.empty(T)
    hist = np.empty((T, G + 1))
    pinned = np.zeros((T, 3), np.int8)
    for k in range(T):
        r = pso.minimize(cost, seeds.stream(seed, "psobe_test", k), settings)
        est[k], J[k], hist[k] = r.best, r.best_cost, r.history
        pinned[k, r.pinned] = 1
    eps_min, J_min = argmin_J(cost, settings.lower, settings.upper)
    J_min = float(cost(eps_min[None, :])[0])  # J of the linearised minimiser, by navigation
    if J.min() < J_min:  # a test did better (the errors are not exactly linear in the drift): use it
        eps_min, J_min = est[int(np.argmin(J))].copy(), float(J.min())
    crb = drift_crb(session, win, cost.out_every * win.dt_nav, dcfg["initial_condition"]).sigma_deg_h()
    z_total = (est - truth) / crb
    z_opt = (est - eps_min) / crb
    log(f"particles={settings.particles} generations={G}: rms error {np.sqrt(np.mean(z_total ** 2)):.3g} bounds, "
        f"optimiser part {np.sqrt(np.mean(z_opt ** 2)):.3g} bounds, J excess {np.mean(J / J_min - 1):.3g}")
    d = {"units": "deg h-1"}
    return xr.Dataset(
        {"estimate": (("test", "axis"), est, {**d, "long_name": "PSOBE gyro-drift estimate"}),
         "J": (("test",), J, {"long_name": "J (He 2019 eq. 18) at the estimate"}),
         "J_history": (("test", "generation"), hist, {"long_name": "J of the global best per generation"}),
         "pinned": (("test", "axis"), pinned, {"long_name": "best particle on a range bound"}),
         "truth": (("axis",), truth, d),
         "crb": (("axis",), crb, {**d, "long_name": "Cramer-Rao bound, 1 sigma"}),
         "argmin_J": (("axis",), eps_min, {**d, "long_name": "minimiser of J in the search range (linear programme)"}),
         "J_min": ((), J_min),
         "error_in_bounds": (("test", "axis"), z_total, {"long_name": "(estimate - truth) / CRB"}),
         "optimizer_error_in_bounds": (("test", "axis"), z_opt, {"long_name": "(estimate - argmin J) / CRB"}),
         "rms_error_in_bounds": ((), float(np.sqrt(np.mean(z_total ** 2)))),
         "rms_optimizer_error_in_bounds": ((), float(np.sqrt(np.mean(z_opt ** 2)))),
         "mean_J_excess": ((), float(np.mean(J / J_min - 1.0)), {"long_name": "mean of J / min J - 1"})},
        coords={"test": np.arange(1, T + 1), "axis": ["x", "y", "z"], "generation": np.arange(G + 1)},
        attrs={"particles": settings.particles, "generations": G, "variant": settings.variant,
               "window_h": dcfg["window_h"], "initial_condition": dcfg["initial_condition"],
               "frame": "body axes (default: along east-north-up)"})


def argmin_J(cost, lower: float, upper: float, step_deg_h: float = 0.01):
    """Minimiser of J (He 2019 eq. 18) over the search box [lower, upper]^3 deg/h.

    The navigation errors of a stationary window are linear in the drift compensation c (the premise of
    :func:`calib.drift.psobe.linear_lsq`): e(c) = e0 + H c, with H from one navigation run per axis (step
    ``step_deg_h``). J = sum of rho-weighted |e| is then convex and piecewise linear in c, and its minimum
    over the box is a linear programme: min sum(t) s.t. -t <= e0 + H c <= t, lower <= c <= upper.
    Returns (c [deg/h] (3,), J of the linear model).
    """
    from scipy.optimize import linprog

    kl, kn = drift.position_scale(cost.unit, cost.win.lat0, cost.win.h0)
    X = np.vstack([np.zeros(3), step_deg_h * np.eye(3)])
    err = cost.errors(X)
    Y = np.concatenate([err["vE"], err["vN"], kl * err["lat"], kn * err["lon"]], axis=-1)
    w = np.repeat(np.asarray(cost.weights, float), err["vE"].shape[-1])
    Y = Y * w
    y0, H = Y[0], (Y[1:] - Y[0]).T / step_deg_h  # (N,), (N, 3)
    n = y0.size
    eye = np.eye(n)
    A = np.block([[H, -eye], [-H, -eye]])
    b = np.concatenate([-y0, y0])
    res = linprog(np.concatenate([np.zeros(3), np.ones(n)]), A_ub=A, b_ub=b,
                  bounds=[(lower, upper)] * 3 + [(0, None)] * n, method="highs")
    if not res.success:  # pragma: no cover - a bounded feasible LP always solves
        raise RuntimeError(f"argmin_J: linear programme failed: {res.message}")
    return res.x[:3], float(res.fun)
