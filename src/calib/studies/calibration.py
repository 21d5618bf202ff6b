"""Liu et al. (2021) study on one calibration session: noise, repeated identifications per method, Tables 2, 4, 5,
Figures 2-6 and 8, identifiability, and the project's default calibration for navigation.

Called by the workflow rules of ``workflow/rules/calibration.smk`` and by ``calib calibrate``.
Scientific products (netCDF, CSV, figures) never hold wall times; those go to ``timings.csv``.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import time
import warnings
from pathlib import Path

import numpy as np
import xarray as xr

from calib.calibration import fit as cal
from calib.calibration import bound as calbound
from calib.calibration import identifiability as idf
from calib.calibration import objectives as ob
from calib.signal import noisecov
from calib.io import recording
from calib.signal import segments
from calib.io.netcdf import CF_VERSION, write_netcdf
from calib.core.progress import Progress
from calib.core.triad import PARAM_NAMES, TriadModel
from calib.studies import stages
from calib.core import seeds
from calib.io.atomic import json_default, make_folder, scratch_folder, strict_json, write_json, write_text
from calib.sim.calibration_session import (build_calibration_simulator, calibration_session_channels,
                                           calibration_session_dataset)
from calib.sim.fisher import mean_noise_models
from calib.sim.static_session import static_counts_dataset
from calib.sim.truth import calibration_truth

#: how the DE variants of Liu 2021 map to the figures
FIGURE_OF = {"de_rand1": 2, "de_current_to_best1": 3, "de_integration": 4, "ide": 5}
PAPER_TABLE2 = {"de_rand1": (0.045558, 0.015841), "de_integration": (0.008171, 6.1852e-04), "ide": (0.004854, 8.5377e-04)}
PAPER_TABLE4 = {"static": (0.4935, 4.0192e-06), "dynamic": (0.003075, 7.8156e-04)}
PAPER_TABLE5 = {"accel": {"ga": (73.33, 0.1513, 0.1096), "pso": (86.67, 0.03387, 0.04783), "ide": (96.67, 0.004854, 8.5377e-04)},
                "gyro": {"ga": (60.0, 0.08360, 0.09456), "pso": (83.33, 0.05049, 0.03806), "ide": (100.0, 0.003075, 7.8156e-04)}}


def method_options(method: str, ccfg: dict) -> dict:
    """Optimiser settings from the config (fixed before anything is measured)."""
    if method in ("de_rand1", "de_current_to_best1", "de_integration"):
        return dict(ccfg.get("de", {}))
    if method in ("ide", "ide_lsq"):
        return {k: v for k, v in ccfg.get("ide", {}).items()} | {"CR": ccfg.get("de", {}).get("CR", 0.6)}
    if method == "ga":
        g = ccfg.get("ga", {})
        return {"p_crossover": g.get("crossover_prob", 0.9), "p_mutation": g.get("mutation_prob", 0.1),
                "tournament": g.get("tournament", 2), "n_elite": g.get("elite", 2), "eta_c": g.get("eta_c", 15.0),
                "eta_m": g.get("eta_m", 20.0)}
    if method == "pso":
        p = ccfg.get("pso", {})
        return {"w_start": p.get("w_start", 0.9), "w_end": p.get("w_end", 0.4), "c1": p.get("c1", 2.0),
                "c2": p.get("c2", 2.0), "v_max": p.get("v_max_frac", 0.2)}
    return {}


def _history(res, EG):
    h = np.full(EG + 1, np.nan)
    if res.history is not None and len(res.history):
        k = min(len(res.history), EG + 1)
        h[:k] = np.asarray(res.history)[:k]
    return h


def _runs(problem, method, ccfg, seed0, progress=None):
    """``runs`` independent identifications of ``problem(method, rng, budget, opts)``."""
    R, NP, EG = ccfg["runs"], ccfg["NP"], ccfg["EG"]
    opts = method_options(method, ccfg)
    out = []
    for r in range(R):
        rng = seeds.stream(seed0, "run", r)
        out.append(problem(method, rng, (NP, EG), opts))
        if progress:
            progress()
    return out


def _run_dataset(results, L, hist, x, names, sensor, method, objective, truth=None):
    ds = xr.Dataset(
        {"estimate": (("run", "parameter"), x, {"long_name": f"{sensor} K, E, b estimated by {method} (Liu 2021 "
                                                            "eq. 25 order)"}),
         "L": (("run",), L, {"long_name": objective}),
         "history": (("run", "generation"), hist, {"long_name": f"best {objective} per generation"})},
        coords={"run": ("run", np.arange(len(L)), {"long_name": "independent run"}), "parameter": list(names),
                "generation": ("generation", np.arange(hist.shape[1]), {"long_name": "optimizer generation"})},
        attrs={"sensor": sensor, "method": method, "objective": objective,
               "on_bound": json.dumps(sorted({p for r in results for p in (r.on_bound or [])}))})
    if truth is not None:
        ds["truth"] = (("parameter",), truth, {"long_name": f"{sensor} K, E, b of the simulated unit"})
    return ds


def _problem(inp, key, method, rng, budget, opts):
    """One identification: 'accel' (paper's 12-parameter norm, eq. 7), 'gyro_static' (L_g, eq. 7) or
    'gyro_dynamic' (L_gm of eq. 26, then the biases by eq. 7 with K, E held; Liu 2021 §3.3)."""
    if key == "accel":
        return cal.norm_calibration(inp.accel_static, form="paper12", method=method, rng=rng, budget=budget, **opts)
    if key == "gyro_static":
        return cal.norm_calibration(inp.gyro_static, form="paper12", method=method, rng=rng, budget=budget, **opts)
    return cal.gyro_dynamic(inp.gyro_pairs, inp.gyro_static, method=method, rng=rng, budget=budget, **opts)


_WORKER = {}


def _task(args):
    key, m, seed0 = args
    inp, ccfg = _WORKER["inp"], _WORKER["ccfg"]
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # bound hits are reported in the runs files and tables
        res = _runs(lambda method, rng, budget, opts: _problem(inp, key, method, rng, budget, opts), m, ccfg, seed0)
    for r in res:  # keep what the products need; optimiser populations stay in the worker
        if r.optimizer is not None:
            r.optimizer.population = None
            r.optimizer.population_fun = None
    return res, time.perf_counter() - t


def _map_tasks(inp, ccfg, tasks, workers, progress):
    """Run the (problem, method) blocks, in ``workers`` processes (fork) when > 1. Each block is seeded by
    itself, so the result does not depend on the number of workers."""
    _WORKER.update(inp=inp, ccfg=ccfg)
    if workers <= 1:
        out = []
        for t in tasks:
            out.append(_task(t))
            progress()
        return out
    with mp.get_context("fork").Pool(workers) as pool:
        out = []
        for r in pool.imap(_task, tasks):
            out.append(r)
            progress()
    return out


def run_study(recording_path, truth_path, out_dir, ccfg: dict, seed: int, prov=None, log=print, workers: int = 1,
              noise_record=None):
    """The whole Liu 2021 calibration study on one session. ``noise_record``: path of a long static recording
    of the same unit (the slow noise of the default calibration's segment means, :func:`noise_models`), or
    None. Writes into ``out_dir``:

    ``noise.nc`` + ``allan.png``; ``runs/{sensor}_{method}.nc``; ``tables/table2_de_variants.csv``,
    ``table4_gyro_paths.csv``, ``table5_methods.csv``; ``figures/figure{2,3,4,5,6,8}_*.png``;
    ``identifiability.json``; ``default_calibration.json`` + ``.nc``; ``timings.csv``;
    ``calibration.metrics.json``.
    """
    from calib.figures import calibration_plots   # matplotlib: imported only when drawing

    out = Path(out_dir)
    for sub in ("runs", "tables", "figures"):
        make_folder(out / sub)   # (inside an output set: removed again should the study end without its products)
    timing = {}
    t0 = time.perf_counter()
    ds = recording.load(recording_path)
    inp = segments.extract(ds)
    timing["extract_s"] = time.perf_counter() - t0
    log(f"{inp.accel_static.n} static positions, {0 if inp.gyro_pairs is None else inp.gyro_pairs.n} rotation pairs")
    truth = json.loads(Path(truth_path).read_text()) if truth_path else None
    true_vec = {s: truth_vector(truth, s) for s in ("accel", "gyro")} if truth else {"accel": None, "gyro": None}
    _noise_products(inp, out, prov)

    methods = list(ccfg["methods"])
    EG = ccfg["EG"]
    runs = {}
    bar = Progress(len(methods) * 3, "method x problem blocks")

    keys = ["accel", "gyro_static"] + (["gyro_dynamic"] if inp.gyro_pairs is not None else [])
    tasks = [(key, m, seeds.child_seed(seed, "method", m)) for key in keys for m in methods]
    # scipy's differential evolution blocks first (each several times any other block): handed out last, one of them
    # kept a worker busy long after the other had run out of blocks. Every block is seeded by itself, and the results
    # are put back in task order, so nothing but the wall time depends on the order
    order = sorted(range(len(tasks)), key=lambda i: tasks[i][1] != "scipy_de")
    done = _map_tasks(inp, ccfg, [tasks[i] for i in order], workers, bar)
    results = [None] * len(tasks)
    for j, i in enumerate(order):
        results[i] = done[j]
    for (key, m, _), (res, dt) in zip(tasks, results):
        timing[f"{key}_{m}_s"] = dt
        L = np.array([r.L for r in res])
        hist = np.array([_history(r.optimizer, EG) for r in res])
        x = np.array([r.paper_vector() for r in res])
        sensor = "accel" if key == "accel" else "gyro"
        rds = _run_dataset(res, L, hist, x, PARAM_NAMES, sensor, m, res[0].objective, true_vec[sensor])
        write_netcdf(rds, out / "runs" / f"{key}_{m}.nc", prov)
        runs[(key, m)] = (res, L, hist)
    problems = {k: (lambda method, rng, budget, opts, k=k: _problem(inp, k, method, rng, budget, opts)) for k in keys}

    # ---- the best-known optimum: multi-start least squares ----
    best = {}
    for key, problem in problems.items():
        ls = [problem("lsq", seeds.stream(seed, "lsq_multistart", r), (ccfg["NP"], EG), {}) for r in range(10)]
        best[key] = min(min(r.L for r in ls), min(float(np.min(v[1])) for k, v in runs.items() if k[0] == key))
    tol = float(ccfg.get("success_rel_tol", 0.01))
    success = {k: float(np.mean(v[1] <= best[k[0]] * (1.0 + tol)) * 100.0) for k, v in runs.items()}

    _table2(out / "tables" / "table2_de_variants.csv", runs, methods)
    _table4(out / "tables" / "table4_gyro_paths.csv", runs, problems, ccfg["default_method"] if
            ccfg["default_method"] in methods else "ide")
    _table5(out / "tables" / "table5_methods.csv", runs, methods, success, best, tol)
    for m, fig_no in FIGURE_OF.items():
        if ("accel", m) in runs:
            calibration_plots.convergence(runs[("accel", m)][2], f"Liu et al. (2021) Fig. {fig_no}: accelerometer, {m}",
                                          "L_a (eq. 7) [g²]", out / "figures" / f"figure{fig_no}_accel_{m}.png")
    if ("gyro_static", "ide") in runs:
        calibration_plots.convergence(runs[("gyro_static", "ide")][2], "Liu et al. (2021) Fig. 6: gyro, static path, "
                                      "IDE", "L_g (eq. 7) [(°/h)²]", out / "figures" / "figure6_gyro_static_ide.png")
    if ("gyro_dynamic", "ide") in runs:
        calibration_plots.convergence(runs[("gyro_dynamic", "ide")][2], "Liu et al. (2021) Fig. 8: gyro, dynamic "
                                      "path (eq. 26), IDE", "L_gm (eq. 26), relative",
                                      out / "figures" / "figure8_gyro_dynamic_ide.png")

    # ---- identifiability and the default calibration ----
    t = time.perf_counter()
    noise = noise_models(inp, noise_record, ccfg) if noise_record else None
    default = default_calibration(inp, ccfg, seed, noise=noise)
    log(default["noise_note"])
    timing["default_calibration_s"] = time.perf_counter() - t
    ident = _identifiability(inp, runs, default)
    write_text(out / "identifiability.json", json.dumps(ident, indent=2))
    write_default(default, out / "default_calibration.json", out / "default_calibration.nc", prov, true_vec,
                  bound=default_bound(inp, default, noise))
    write_text(out / "timings.csv", "quantity,seconds\n" + "".join(f"{k},{v:.4f}\n" for k, v in timing.items()))
    metrics = {"success_pct": {f"{k[0]}.{k[1]}": v for k, v in success.items()},
               "mean_L": {f"{k[0]}.{k[1]}": float(np.mean(v[1])) for k, v in runs.items()},
               "best_L": best, "rank": {k: v["rank"] for k, v in ident.items() if isinstance(v, dict) and "rank" in v}}
    write_text(out / "calibration.metrics.json", json.dumps(metrics, indent=2))
    log(json.dumps(metrics, indent=2))
    return metrics


def truth_vector(truth, sensor):
    try:
        t = truth["sensor"][sensor]
    except (KeyError, TypeError):
        try:
            t = truth[sensor]
        except (KeyError, TypeError):
            return None
    if isinstance(t, dict) and "vector" in t:
        return np.asarray(t["vector"], float)
    if isinstance(t, dict) and {"K", "E", "b"} <= set(t):
        E = np.asarray(t["E"], float)
        return TriadModel(np.asarray(t["K"], float), E, np.asarray(t["b"], float)).to_vector()
    return None


def _noise_products(inp, out, prov):
    """``noise.nc`` and ``figures/allan.png``: the Allan deviation of each sensor pooled over the static positions,
    with its 95 % interval."""
    from calib.figures import calibration_plots   # matplotlib: imported only when drawing

    data, coords, panels = {}, {}, []
    for sensor, res in (("accel", inp.accel_noise), ("gyro", inp.gyro_noise)):
        tau = np.asarray(res.tau)
        unit = res.unit or "count s-1"
        coords[f"tau_{sensor}"] = (f"tau_{sensor}", tau, {"units": "s", "long_name": f"{sensor} averaging time"})
        ad = np.asarray(res.adev).reshape(len(tau), -1)[:, :3]
        lo = np.asarray(res.lo).reshape(len(tau), -1)[:, :3]
        hi = np.asarray(res.hi).reshape(len(tau), -1)[:, :3]
        data[f"adev_{sensor}"] = ((f"tau_{sensor}", "axis"), ad, {"units": unit,
                                  "long_name": f"{sensor} Allan deviation"})
        data[f"adev_{sensor}_lo"] = ((f"tau_{sensor}", "axis"), lo, {"units": unit,
                                     "long_name": f"{sensor} Allan deviation, lower end of the 95 % interval"})
        data[f"adev_{sensor}_hi"] = ((f"tau_{sensor}", "axis"), hi, {"units": unit,
                                     "long_name": f"{sensor} Allan deviation, upper end of the 95 % interval"})
        panels.append((sensor, tau, ad, lo, hi, unit))
    calibration_plots.noise_allan(panels, out / "figures" / "allan.png")
    ds = xr.Dataset(data, coords={**coords, "axis": ["x", "y", "z"]},
                    attrs={"method": "overlapping Allan deviation pooled over static segments, 95 % chi-square "
                                     "intervals; sigma of a segment mean = ADEV at tau = segment duration"})
    write_netcdf(ds, out / "noise.nc", prov)


def _stats(L):
    return float(np.mean(L)), float(np.std(L, ddof=1)) if len(L) > 1 else 0.0


def _table2(path, runs, methods):
    rows = ["method,mean_L_a,std_L_a,runs,paper_mean_L_a,paper_std_L_a"]
    for m in ("de_rand1", "de_current_to_best1", "de_integration", "ide"):
        if ("accel", m) in runs:
            mu, sd = _stats(runs[("accel", m)][1])
            pm, ps = PAPER_TABLE2.get(m, ("", ""))
            rows.append(f"{m},{mu:.6g},{sd:.6g},{len(runs[('accel', m)][1])},{pm},{ps}")
    rows.append("# L_a of eq. 7 in g^2 (accelerometer input in standard g); the paper's units and noise are not "
                "stated, so only the ordering is comparable")
    write_text(path, "\n".join(rows) + "\n")


def _table4(path, runs, problems, method):
    rows = ["path,objective,mean_L,std_L,runs,method,paper_mean,paper_std"]
    if ("gyro_static", method) in runs:
        mu, sd = _stats(runs[("gyro_static", method)][1])
        rows.append(f"static,L_g (eq. 7) [(deg/h)^2],{mu:.6g},{sd:.6g},{len(runs[('gyro_static', method)][1])},"
                    f"{method},{PAPER_TABLE4['static'][0]},{PAPER_TABLE4['static'][1]}")
    if ("gyro_dynamic", method) in runs:
        mu, sd = _stats(runs[("gyro_dynamic", method)][1])
        rows.append(f"dynamic,L_gm (eq. 26) relative,{mu:.6g},{sd:.6g},{len(runs[('gyro_dynamic', method)][1])},"
                    f"{method},{PAPER_TABLE4['dynamic'][0]},{PAPER_TABLE4['dynamic'][1]}")
    rows.append("# L_gm constrains only the three column norms of K_g E_g (Jacobian rank 3 of 9): its installation "
                "errors are not determined; the static L_g path sees only Earth rate")
    write_text(path, "\n".join(rows) + "\n")


def _table5(path, runs, methods, success, best, tol):
    rows = ["sensor,objective,method,success_pct,mean_L,std_L,runs,paper_success_pct,paper_mean_L,paper_std_L"]
    for key, sensor, objective in (("accel", "accel", "L_a"), ("gyro_dynamic", "gyro", "L_gm"),
                                   ("gyro_static", "gyro", "L_g (static)")):
        for m in methods:
            if (key, m) not in runs:
                continue
            mu, sd = _stats(runs[(key, m)][1])
            p = PAPER_TABLE5.get(sensor, {}).get(m) if key != "gyro_static" else None
            pp = ",".join(str(v) for v in p) if p else ",,"
            rows.append(f"{sensor},{objective},{m},{success[(key, m)]:.2f},{mu:.6g},{sd:.6g},{len(runs[(key, m)][1])},{pp}")
    rows.append(f"# success: final L <= (1 + {tol}) L*, with L* the best optimum found by 10 multi-start least-squares "
                f"runs and all runs of all methods (L*: " + "; ".join(f"{k} {v:.6g}" for k, v in best.items()) + ")")
    write_text(path, "\n".join(rows) + "\n")


NO_SLOW_NOISE_NOTE = ("the sigma of the segment means comes from the Allan deviation of the session's own static "
                      "segments only (tau <= half a segment): it does NOT include bias instability slower than a "
                      "segment, and the means are treated as independent; the covariance is scaled by the reduced "
                      "chi-square where the fit scatters more. Give a long static record of the same unit (config "
                      "calibration.noise_record: static_check, the 2 h static_check recording) to include it")


def noise_models(inp, noise_record, ccfg) -> dict:
    """Noise models (``noisecov.MeanNoiseModel``) of both triads from the session's static segments and the
    long static record ``noise_record`` (path or loaded recording of the same unit at rest); the shortest
    tau used is ``ccfg['noise_tau_min_s']`` (default 5 s)."""
    ds = noise_record if isinstance(noise_record, xr.Dataset) else recording.load(noise_record)
    tau_min = float(ccfg.get("noise_tau_min_s", 5.0))
    return {s: noisecov.triad_noise(getattr(inp, f"{s}_noise"), ds, s, tau_min_s=tau_min) for s in ("accel", "gyro")}


def default_calibration(inp, ccfg, seed, noise: dict | None = None):
    """The project's default: accelerometers by the identified 9-parameter norm form (IDE + polish), rotated
    into the body frame of the gyros with the nominal attitudes (the separate calibration's K E as reference;
    without attitudes the rotation stays unidentified and is reported), gyros by eq. 25.

    Standard errors. With ``noise`` (:func:`noise_models`, from a long static record of the same unit) the
    covariance of the segment means is the full one of ``calib.signal.noisecov`` (white + quantisation + the slow
    Gauss-Markov / random-walk bias, correlated between segments), propagated through both estimators
    (accelerometers: sandwich J^+ C_r J^+T of the unweighted eq. 7; gyros: A C A^T of the linear eq. 25
    estimator); the estimates themselves do not change. The covariance is scaled by the reduced chi-square only
    if the chi-square rejects the noise model (p < 0.001, noted). Without ``noise``: independent means with the
    in-segment Allan sigma, scaled by the reduced chi-square (:func:`_inflate_by_scatter`), and
    ``noise_note`` says the bias instability is not included."""
    method = ccfg["default_method"]
    covs = noisecov.observation_covs(inp, noise) if noise is not None else {"accel_static": None, "gyro_eq25": None}
    acc = cal.norm_calibration(inp.accel_static, form="tri9", method=method, rng=seeds.stream(seed, "default_calibration"),
                               budget=(ccfg["NP"], ccfg["EG"]), cov_means=covs["accel_static"],
                               **method_options(method, ccfg))
    if noise is None:
        _inflate_by_scatter(acc)
        noise_note = NO_SLOW_NOISE_NOTE
        acc.notes.append(noise_note)
    else:
        _inflate_if_rejected(acc)
        noise_note = ("sigma and correlation of the segment means from a noise model fitted to the Allan deviation "
                      "of the session's static segments and of a long static record of the same unit (includes "
                      "the bias instability): accel " + "; ".join(noise["accel"].describe(a) for a in range(3))
                      + " | gyro " + "; ".join(noise["gyro"].describe(a) for a in range(3)))
    ref = None
    frame_note = "accelerometer triad frame (rotation to the gyro frame unidentified: no nominal attitudes)"
    if inp.accel_static.attitude is not None:
        sep = cal.separate_accel(inp.accel_static)
        ref = sep.KE
        frame_note = "body frame realised by the nominal table attitudes (triad rotation fixed by the separate calibration)"
    gyro = (cal.gyro_components(inp.gyro_pairs, inp.gyro_static, cov_obs=covs["gyro_eq25"])
            if inp.gyro_pairs is not None else None)
    if gyro is not None and noise is None:
        gyro.notes.append(NO_SLOW_NOISE_NOTE)
    return {"accel": acc, "accel_reference": ref, "gyro": gyro, "frame_note": frame_note, "noise_note": noise_note,
            "noise_model": None if noise is None else {s: m.to_dict() for s, m in noise.items()}}


def _inflate_if_rejected(res, p_reject: float = 1e-3):
    """With a full noise model the chi-square r^T C_r^-1 r should follow chi-square(dof); only when it rejects
    the model (upper tail p < ``p_reject``) is the covariance scaled by the reduced chi-square (noted)."""
    from calib.core.distributions import chi2_sf

    if res.dof > 0 and np.isfinite(res.chi2):
        p = chi2_sf(res.chi2, res.dof)
        res.derived["chi2_p"] = p
        if p < p_reject:
            f = res.chi2 / res.dof
            res.cov = res.cov * f
            res.notes.append(f"chi-square {res.chi2:.3g} on {res.dof} dof rejects the noise model (p = {p:.2g}): "
                             f"covariance scaled by the reduced chi-square {f:.3g}")
    return res


def _inflate_by_scatter(res):
    """Scale the covariance by the reduced chi-square when the fit scatters more than the noise model says.

    The sigma of a 60 s segment mean comes from the Allan deviation, which a 60 s segment measures only up to
    tau = 30 s: a bias instability that decorrelates over minutes (the accelerometers' 5 ug, 300 s) is not
    visible there but moves every segment mean. The fit's own scatter reveals it; without this the standard
    errors of the accelerometer norm fit were 2-6x too small over repeated noise seeds."""
    if res.dof > 0 and np.isfinite(res.chi2) and res.chi2 / res.dof > 1.0:
        f = res.chi2 / res.dof
        res.cov = res.cov * f
        res.notes.append(f"covariance scaled by the reduced chi-square {f:.3g} (scatter beyond the Allan sigma of "
                         "the segment means: bias instability slower than a segment)")
    return res


def default_bound(inp, default, noise: dict | None) -> dict:
    """The Cramér–Rao bound at the default calibration's estimates (:func:`calib.calibration.bound.default_bounds`)
    for the session's windows ``inp`` and the noise the calibration used: ``noise`` (:func:`noise_models`, the
    measured model with the slow bias) or, without a long static record, the windows' own independent sigmas.
    Returns ``{sensor: {"block": what the bound is, "sigma_crb", "se_over_crb", "null_reason"}}`` (None for a
    sensor without an estimate)."""
    acc, gyro = default["accel"], default["gyro"]
    vec_a, _ = acc.paper_form(default["accel_reference"])
    found = calbound.default_bounds(inp, ob.Form("paper12").KE_b(vec_a),
                                    None if gyro is None else (gyro.KE, gyro.b), noise)
    out = {}
    for sensor, res in (("accel", acc), ("gyro", gyro)):
        if res is None:
            out[sensor] = None
            continue
        b, how = found[sensor]
        observe, form, of = calbound.DEFAULT_BOUNDS[sensor]
        noise_key, _, inputs = how.partition("; inputs: ")
        block = {"observe": observe, "form": form, "of": of,
                 "noise": calbound.NOISE_OF_BOUND.get(noise_key, noise_key), "inputs": inputs or None,
                 "windows": None if b is None else b.n_windows,
                 "evaluated_at": "the default calibration's estimate (not the truth)"}
        if b is None:
            block["not_available"] = how
        out[sensor] = {"block": block, **calbound.beside_estimates(res.names, res.se, b, how)}
    return out


def write_default(default, json_path, nc_path, prov, true_vec, bound: dict | None = None):
    """``default_calibration.json`` and ``.nc`` of :func:`default_calibration`; ``bound``
    (:func:`default_bound`): the Cramér–Rao bound beside every estimate (``sigma_crb``, ``se_over_crb`` = the
    reported standard error / the bound, and the ``bound`` block of each sensor; None with its reason where the
    data do not determine a parameter)."""
    acc, gyro, ref = default["accel"], default["gyro"], default["accel_reference"]
    vec_a, R = acc.paper_form(ref)
    out = {"frame": default["frame_note"], "noise": default.get("noise_note"),
           "noise_model": default.get("noise_model"), "accel": acc.to_dict(), "accel_body_vector": dict(zip(PARAM_NAMES, map(float, vec_a))),
           "accel_rotation_to_body": R.tolist(),
           "gyro": None if gyro is None else gyro.to_dict(),
           "how_to_apply": "N = counts/dt (count s-1); x = (K E)^-1 (N - b) in g (accel) and deg/h (gyro), body frame"}
    if true_vec["accel"] is not None:
        # errors only in the directions the data determine: the Gram matrix (K E)(K E)^T and the biases
        M_true = ob.Form("paper12").KE_b(true_vec["accel"])[0]
        out["accel_error_gram_rel"] = float(np.abs(acc.KE @ acc.KE.T - M_true @ M_true.T).max()
                                            / np.abs(M_true @ M_true.T).max())
        out["accel_error_bias"] = (acc.b - true_vec["accel"][9:]).tolist()
    if gyro is not None and true_vec["gyro"] is not None:
        out["gyro_error"] = dict(zip(PARAM_NAMES, map(float, gyro.paper_vector() - true_vec["gyro"])))
        out["gyro_z"] = dict(zip(gyro.names, map(float, (gyro.x - _match(gyro, true_vec["gyro"])) / gyro.se)))
    for sensor, b in (bound or {}).items():
        if b is not None and out.get(sensor) is not None:
            out[sensor].update(sigma_crb=b["sigma_crb"], se_over_crb=b["se_over_crb"],
                               bound={**b["block"], "null_reason": b["null_reason"]})
    write_text(json_path, json.dumps(out, indent=2))
    coords = {"parameter": list(PARAM_NAMES)}
    data = {"accel": (("parameter",), vec_a, {"long_name": "accelerometer K, E, b in the body frame"}),
            "accel_cov_lin": (("p1", "p2"), acc.cov, {"long_name": "covariance of the accelerometer parameters "
                                                                    "(linearised at the optimum)"})}
    if gyro is not None:
        data["gyro"] = (("parameter",), gyro.paper_vector(), {"long_name": "gyro K, E, b (eq. 25), body frame"})
        data["gyro_cov"] = (("q1", "q2"), gyro.cov, {"long_name": "covariance of the gyro parameters"})
    for sensor, res in (("accel", acc), ("gyro", gyro)):
        b = (bound or {}).get(sensor)
        if b is None or res is None:
            continue
        dim = "parameter" if tuple(res.names) == tuple(PARAM_NAMES) else f"{sensor}_{res.form}_parameter"
        if dim != "parameter":
            coords[dim] = list(res.names)
        per = "g" if sensor == "accel" else "deg/h"
        nd = "; ".join(f"{n}: {r}" for n, r in b["null_reason"].items())
        common = {"observe": b["block"]["observe"], "noise": b["block"]["noise"], "null_reason": nd or "none"}
        data[f"{sensor}_sigma_crb"] = ((dim,), [np.nan if b["sigma_crb"][n] is None else b["sigma_crb"][n]
                                                for n in res.names],
                                       {"long_name": f"Cramer-Rao bound of the {sensor} parameters ({res.form}) at "
                                                     "the estimate (NaN: null_reason)",
                                        "parameter_units": f"K: count s-1 per {per}; E: 1; b: count s-1", **common})
        data[f"{sensor}_se_over_crb"] = ((dim,), [np.nan if b["se_over_crb"][n] is None else b["se_over_crb"][n]
                                                  for n in res.names],
                                         {"long_name": f"reported standard error / Cramer-Rao bound of the {sensor} "
                                                       f"parameters ({res.form}) (NaN: null_reason)", "units": "1",
                                          **common})
    write_netcdf(xr.Dataset(data, coords=coords, attrs={"frame": default["frame_note"],
                                                        "accel_units": "count s-1 per g", "gyro_units": "count s-1 per deg/h"}),
                 nc_path, prov)


def _match(res, true12):
    """Truth in the parameterisation of ``res`` (ke9 + b or paper12)."""
    if len(res.names) == 12:
        return true12
    M, b = ob.Form("paper12").KE_b(true12)
    return ob.Form(res.form).from_KE_b(M, b) if hasattr(ob.Form(res.form), "from_KE_b") else true12


def _identifiability(inp, runs, default):
    rep = {}
    if ("accel", "ide") in runs:
        r = runs[("accel", "ide")][0][0]
        rep["accel_paper12"] = {"rank": int(r.rank), "n": 12, "null_space": list(r.identifiability.descriptions)}
    if ("gyro_dynamic", "ide") in runs:
        r = runs[("gyro_dynamic", "ide")][0][0]
        rk = r.derived.get("lgm_rank", (None, 9))
        rep["gyro_Lgm"] = {"rank": int(rk[0]), "n": 9, "null_space": list(r.identifiability.descriptions)}
    a = default["accel"]
    rep["accel_tri9_default"] = {"rank": int(a.rank), "n": 9}
    if default["gyro"] is not None:
        rep["gyro_eq25_default"] = {"rank": int(default["gyro"].rank), "n": len(default["gyro"].names)}
    try:
        plan = idf.check_plan("accel", "paper12")
        rep["plan_accel_paper12"] = {"rank": int(plan.rank), "n": 12, "what_to_add": list(getattr(plan, "suggestions", []))}
    except Exception as exc:  # noqa: BLE001 - a failed plan check is reported, not hidden
        rep["plan_accel_paper12"] = {"error": str(exc)}
    rep["note"] = ("The norm of eq. 7 cannot see a rotation of the whole triad: the paper's 12-parameter accelerometer "
                   "form has rank 9 of 12; L_gm (eq. 26) sees only the three column norms of K_g E_g (rank 3 of 9). "
                   "The default uses the identified 9-parameter form for the accelerometers and the full-rank "
                   "component form of eq. 25 for the gyros.")
    return rep


def z_noise_mode(ccfg: dict) -> str:
    """How the z-score study gets its long static record: 'none' (``calibration.noise_record`` unset), 'per_seed'
    (default: a fresh record of the same unit simulated for every seed, so the noise estimate is resampled
    too) or 'shared' (``calibration.z_noise_record: shared``: the one static_check recording for all seeds)."""
    if ccfg.get("noise_record") in (None, "none", False):
        return "none"
    return str(ccfg.get("z_noise_record", "per_seed"))


#: what the default calibration's estimators leave out of the information the bound uses, by (sensor, first letter
#: of the parameter: K, E, b), written beside a ratio above :data:`EFFICIENCY_FLAG` (:func:`efficiency_note`)
EFFICIENCY_REASONS = {
    **{("accel", c): "eq. 7 is unweighted and treats the static means as independent: it leaves out the "
                     "correlation of the slow bias between the means (and any difference in their noise) that the "
                     "bound weights by" for c in "KEb"},
    **{("gyro", c): "eq. 25 takes K E from the + / - pair differences alone with the windows independent: it leaves "
                    "out the Earth-rate information of the static means and the correlation of the slow bias "
                    "between windows" for c in "KE"},
    ("gyro", "b"): "the biases are a weighted mean of the pair and static means taken as independent: the "
                   "correlation of the Gauss-Markov bias between windows (by which generalised least squares tells "
                   "the constant bias from the slow one) is left out",
}

#: the state of one z-score study, set before the seeds run (and inherited by the forked workers)
_Z: dict = {}


def _as_loaded(ds: xr.Dataset, path) -> xr.Dataset:
    """An in-memory recording as ``recording.load`` returns it once written to ``path``: the ``Conventions``
    attribute, numbers among the global attributes as numpy floats, ``_path``. (Only the provenance attributes
    of the written file are missing; samples, variables and their attributes are the same: tests/studies.)"""
    attrs = {k: np.float64(v) if isinstance(v, float) else v for k, v in ds.attrs.items() if k != "conventions"}
    attrs["Conventions"] = f"{CF_VERSION} {recording.CONVENTIONS}"
    attrs["_path"] = str(path)
    ds.attrs = attrs
    return ds


def _z_setup(session, site, ccfg, seed0, check, mode, shared, workdir, files: bool, bound_seed=None) -> dict:
    """Everything the seeds of the z-score study share. ``files``: every seed writes its recordings to
    ``workdir`` and reads them back (the reference path); otherwise the recordings stay in memory and what does
    not depend on the noise seed (the clean increments of the calibration path, its table angle and segment table,
    the truth) is computed once: the sensor models, effects and site of ``build_calibration_simulator`` do not
    depend on the seed, only the noise does. ``bound_seed``: the seed whose windows give the Cramér–Rao bound
    (the simulator's noise as the noise model of the window means, :func:`calib.sim.fisher.mean_noise_models`)."""
    ctx = {"session": session, "site": site, "ccfg": ccfg, "seed0": seed0, "check": check, "mode": mode,
           "shared": shared, "workdir": Path(workdir), "files": bool(files), "bound_seed": bound_seed}
    cfg = stages.calibration_cfg(session, site)
    sim = build_calibration_simulator(cfg, seeds.child_seed(seed0, "session", 0))
    ctx["noise_models"] = mean_noise_models(sim)
    if not files:
        # the truth sidecar as read back from its JSON file (floats round-trip exactly through JSON)
        truth = json.loads(json.dumps(strict_json(calibration_truth(sim)), default=json_default))
        ctx.update(sim=sim, clean=sim.clean_increments(), channels=calibration_session_channels(sim),
                   truth=truth,
                   static_cfg=stages.static_check_cfg(check, session, site) if mode == "per_seed" else None)
    return ctx


def _z_seed(k: int):
    """Seed ``k`` of the z-score study (state in :data:`_Z`): the z-scores of the default calibration with the
    segment-only sigma and (noise record) with the noise model, the parameter names, the errors of the estimates
    (estimate - truth; the estimates do not depend on the sigma model) and, for the seed ``bound_seed``, the
    Cramér–Rao bounds of the session (:func:`calib.calibration.bound.session_bounds`: its windows, the truth and
    the simulator's noise; no estimator), else None."""
    c = _Z
    seed0, ccfg, workdir, mode = c["seed0"], c["ccfg"], c["workdir"], c["mode"]
    rec, tru = workdir / f"s{k}.nc", workdir / f"s{k}.truth.json"
    seed_k = seeds.child_seed(seed0, "session", k)
    if c["files"]:
        stages.simulate_calibration(c["session"], c["site"], seed_k, rec, tru)
        truth = json.loads(tru.read_text())
        inp = segments.extract(recording.load(rec))
        rec.unlink()
        tru.unlink()
    else:
        truth = c["truth"]
        inp = segments.extract(_as_loaded(calibration_session_dataset(c["sim"], seed_k, c["clean"],
                                                                      c["channels"]), rec))
    noise = None
    if mode == "per_seed":
        lrec, ltru = workdir / f"l{k}.nc", workdir / f"l{k}.truth.json"
        lseed = seeds.child_seed(seed0, "noise_record", k)
        if c["files"]:
            stages.simulate_static_check(c["check"], c["session"], c["site"], lseed, lrec, ltru)
            noise = noise_models(inp, recording.load(lrec), ccfg)
            lrec.unlink()
            ltru.unlink()
        else:
            noise = noise_models(inp, static_counts_dataset(c["static_cfg"], lseed, path=lrec), ccfg)
    elif mode == "shared":
        noise = noise_models(inp, c["shared"], ccfg)
    ta = truth_vector(truth, "accel")
    Mt, bt = ob.Form("paper12").KE_b(ta)
    L, _ = ob.lower_triangular_gauge(Mt)
    t9 = ob.Form("tri9").from_KE_b(L, bt)
    tg = None
    out, names = {}, {}
    for key, nz in (("segment", None), ("with", noise)):
        if key == "with" and noise is None:
            continue
        d = default_calibration(inp, ccfg, seeds.child_seed(seed0, "calibration", k), noise=nz)
        g = d["gyro"]
        tg = _match(g, truth_vector(truth, "gyro")) if tg is None else tg
        err = {"accel": d["accel"].x - t9, "gyro": g.x - tg}
        out[key] = {"accel": err["accel"] / d["accel"].se, "gyro": err["gyro"] / g.se}
        names = {"accel": d["accel"].names, "gyro": g.names}
    crb = None
    if k == c["bound_seed"]:
        crb = calbound.bounds_json(calbound.session_bounds(inp, ta, truth_vector(truth, "gyro"), c["noise_models"]))
    return out, names, err, crb


def run_z_seeds(session: dict, site: dict, ccfg: dict, n_seeds: int, seed0: int, out_csv, fig, metrics_path,
                workdir, log=print, check: dict | None = None, noise_record=None, workers: int = 1,
                files: bool = False):
    """The default calibration over ``n_seeds`` simulated sessions (the data stage's generator, full noise
    model): z = (estimate - truth) / standard error of every identified parameter. Accelerometers: the
    identified 9-parameter norm form against the truth in the same gauge; gyros: eq. 25 components.

    Standard errors (:func:`default_calibration`): with a long static record (:func:`z_noise_mode`: 'per_seed'
    simulates one per seed from the ``check`` config, i.e. the static_check settings, seed ``child_seed(seed0, "noise_record", k)``
    k``; 'shared' uses ``noise_record``) from the noise model with the slow part; the z-scores of the
    segment-only sigma (today's behaviour without a record) are reported next to them for the same seeds
    (columns ``*_segment_sigma``). Without a record only the segment-only z-scores (``mean_z``, ``std_z``).

    ``workers`` > 1: the seeds run in that many forked processes; every seed derives its own seeds
    (``seeds.child_seed``), so the results do not depend on the number of workers. ``files``: every seed's
    recordings go through files in ``workdir`` (written, read back, deleted: the reference path, slower); by
    default they stay in memory (the same datasets, tests/studies/test_calibration_z.py)."""

    results = z_seed_block(session, site, ccfg, seed0, 0, n_seeds, workdir, check=check, noise_record=noise_record,
                           workers=workers, files=files)
    return z_products(results, ccfg, n_seeds, out_csv, fig, metrics_path, log=log)


def z_seed_block(session: dict, site: dict, ccfg: dict, seed0: int, first: int, stop: int, workdir,
                 check: dict | None = None, noise_record=None, workers: int = 1, files: bool = False,
                 progress: bool = True) -> list:
    """Seeds ``first`` .. ``stop - 1`` of the z-score study (:func:`run_z_seeds`; the workflow runs blocks of seeds
    as jobs of their own and gathers them with :func:`z_products`): per seed, in order, its z-scores (``{"with" |
    "segment": {"accel" | "gyro": array}}``), the parameter names, the errors of the estimates (``{"accel" |
    "gyro": array}``) and the Cramér–Rao bounds (the block's first seed; None for the others). Every seed derives
    its own seeds from ``seed0`` and its index, so a block holds the same numbers as the same seeds of one run."""
    mode = z_noise_mode(ccfg)
    if mode == "per_seed" and check is None:
        raise ValueError("calibration.noise_record is set: the z-score study needs the static_check settings (check)")
    if mode == "shared" and not noise_record:
        raise ValueError("calibration.z_noise_record = shared needs the static_check recording (noise_record)")
    if mode not in ("none", "per_seed", "shared"):
        raise ValueError(f"calibration.z_noise_record: {mode!r}; use per_seed or shared")
    ks = range(int(first), int(stop))
    results = []
    # a scratch folder for the file path only (the in-memory path makes none), removed again at the end
    with scratch_folder(workdir, make=files) as workdir:
        shared = recording.load(noise_record) if mode == "shared" else None
        bar = Progress(len(ks), "noise seeds") if progress else None
        _Z.clear()
        _Z.update(_z_setup(session, site, ccfg, seed0, check, mode, shared, workdir, files, bound_seed=int(first)))
        try:
            workers = max(1, min(int(workers), len(ks)))
            if workers > 1:
                from concurrent.futures import ProcessPoolExecutor

                ex = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("fork"))
                it = ex.map(_z_seed, ks)
            else:
                ex, it = None, map(_z_seed, ks)
            try:
                for i, res in enumerate(it):
                    results.append(res)
                    if bar is not None:
                        bar(i + 1)
            finally:
                if ex is not None:
                    ex.shutdown(cancel_futures=True)
        finally:
            _Z.clear()
    return results


def write_z_block(results: list, first: int, path) -> Path:
    """Seeds ``first`` .. of :func:`z_seed_block` as JSON for the gathering job (arrays as lists: floats to the
    last bit, NaN kept)."""
    items = [{"z": {key: {s: np.asarray(v).tolist() for s, v in d.items()} for key, d in out.items()},
              "names": {s: list(v) for s, v in names.items()},
              "error": {s: np.asarray(v).tolist() for s, v in err.items()}, "bound": crb}
             for out, names, err, crb in results]
    return write_json({"first": int(first), "stop": int(first) + len(items), "seeds": items}, path, strict=False)


def read_z_blocks(paths) -> list:
    """The blocks written by :func:`write_z_block`, joined in seed order (a gap or an overlap is refused)."""
    blocks = sorted((json.loads(Path(p).read_text()) for p in paths), key=lambda b: b["first"])
    out, nxt = [], 0
    for b in blocks:
        if b["first"] != nxt:
            raise ValueError(f"z-score seed blocks: seeds {nxt} .. {b['first'] - 1} missing or given twice")
        out += [({key: {s: np.asarray(v, dtype=float) for s, v in d.items()} for key, d in it["z"].items()},
                 it["names"], {s: np.asarray(v, dtype=float) for s, v in it["error"].items()}, it["bound"])
                for it in b["seeds"]]
        nxt = b["stop"]
    return out


#: an efficiency ratio above this on a determined parameter gets the reason beside it
EFFICIENCY_FLAG = 2.0


def efficiency_note(sensor: str, name: str, ratio: float) -> str:
    """Why the default calibration's spread exceeds the bound by more than :data:`EFFICIENCY_FLAG` (empty when it
    does not): the information the estimator leaves out that the bound uses."""
    if not np.isfinite(ratio) or ratio <= EFFICIENCY_FLAG:
        return ""
    return EFFICIENCY_REASONS[(sensor, name[0])].replace(",", ";")   # a field of the CSV table


def _one_bound(bounds: list) -> dict:
    """The session's bound from the blocks (each computes it from its first seed's windows): all the same, or
    refused (the seeds of one study share the segment table and the noise settings)."""
    got = [b for b in bounds if b is not None]
    if not got:
        raise ValueError("z-score seed blocks: no Cramér–Rao bound gathered (every block computes one)")
    for b in got[1:]:
        if json.dumps(b, sort_keys=True) != json.dumps(got[0], sort_keys=True):
            raise ValueError("z-score seed blocks: the blocks' Cramér–Rao bounds differ (different sessions?)")
    return got[0]


def _bound_comment(crb: dict) -> list:
    """Comment lines of the z-score table on the bound: what each is the bound of, and what is not determined."""
    out = ["sigma_crb: Cramer-Rao bound from the session's windows and the simulator's noise (white + "
           "quantisation + Gauss-Markov bias; correlated between windows); no estimator run. std_estimate: "
           "std of (estimate - truth) over the seeds; efficiency_ratio = std_estimate / sigma_crb"]
    for key, b in crb.items():
        und = [n for n, v in b["sigma"].items() if v is None]
        out.append(f"{key} ({b['observe']} model; {b['of']}): "
                   + ("all determined" if not und else "not determined: " + " ".join(und)))
    return [line.replace(",", ";") for line in out]   # comment rows of a CSV: no field separators


def z_products(results: list, ccfg: dict, n_seeds: int, out_csv, fig, metrics_path, log=print) -> dict:
    """The z-score table, metrics and figure from every seed's result (:func:`z_seed_block`, in seed order).

    Beside every parameter: the empirical std of the estimates over the seeds (``std_estimate``), the Cramér–Rao
    bound of the session (``sigma_crb``; 'not determined' where the data do not determine it, never a number)
    and the efficiency ratio std_estimate / sigma_crb, with the information the estimator leaves out where the
    ratio exceeds :data:`EFFICIENCY_FLAG` (``efficiency_note``, :func:`efficiency_note`)."""
    if len(results) != n_seeds:
        raise ValueError(f"calibration.z_seeds: {n_seeds} seeds configured, {len(results)} results gathered")
    mode = z_noise_mode(ccfg)
    z = {"with": {"accel": [], "gyro": []}, "segment": {"accel": [], "gyro": []}}
    errors = {"accel": [], "gyro": []}
    names = {}
    for out, nm, err, _ in results:
        for key, zz in out.items():
            for sensor in ("accel", "gyro"):
                z[key][sensor].append(zz[sensor])
        for sensor in ("accel", "gyro"):
            errors[sensor].append(err[sensor])
        names = nm
    crb = _one_bound([r[3] for r in results])
    main = "with" if mode != "none" else "segment"
    header = ("sensor,parameter,mean_z,std_z,n_seeds" + (",mean_z_segment_sigma,std_z_segment_sigma" if main == "with"
                                                         else "") + ",std_estimate,sigma_crb,efficiency_ratio,efficiency_note")
    rows = [header]
    metrics = {"noise_record": mode, "n_seeds": n_seeds, "z": {}, "crb": crb}
    za = {key: {s: np.array(v) for s, v in d.items()} for key, d in z.items() if d["accel"]}

    def ms(a):
        return float(np.mean(a)), float(np.std(a, ddof=1)) if n_seeds > 1 else 0.0

    for sensor in ("accel", "gyro"):
        for j, nm in enumerate(names[sensor]):
            m, sd = ms(za[main][sensor][:, j])
            row = f"{sensor},{nm},{m:.3f},{sd:.3f},{n_seeds}"
            ent = {"mean_z": m, "std_z": sd}
            if main == "with":
                m0, s0 = ms(za["segment"][sensor][:, j])
                row += f",{m0:.3f},{s0:.3f}"
                ent.update(mean_z_segment_sigma=m0, std_z_segment_sigma=s0)
            sd_e = float(np.std(np.array(errors[sensor])[:, j], ddof=1)) if n_seeds > 1 else float("nan")
            bnd = crb[sensor]["sigma"].get(nm)
            ratio = calbound.efficiency(sd_e, bnd)
            note = efficiency_note(sensor, nm, ratio)
            row += (f",{sd_e:.6g},{'not determined' if bnd is None else format(bnd, '.6g')},"
                    f"{'' if not np.isfinite(ratio) else format(ratio, '.3f')},{note}")
            ent.update(std_estimate=sd_e, sigma_crb=bnd, efficiency_ratio=None if not np.isfinite(ratio) else ratio,
                       efficiency_note=note or None)
            rows.append(row)
            metrics["z"][f"{sensor}.{nm}"] = ent
    rows.append("# z = (estimate - truth) / standard error; sigma of the segment means: "
                + ({"none": "segment-only Allan deviation (no long static record: bias instability not included)",
                    "per_seed": "noise model from the session's segments and a long static record simulated per seed "
                                "(static_check settings); *_segment_sigma: the segment-only sigma on the same seeds",
                    "shared": "noise model from the session's segments and the one static_check recording; "
                              "*_segment_sigma: the segment-only sigma on the same seeds"}[mode]))
    rows += [f"# {line}" for line in _bound_comment(crb)]
    write_text(out_csv, "\n".join(rows) + "\n")
    write_text(metrics_path, json.dumps(metrics, indent=2))
    log("\n".join(rows))
    # the error bars: mean and spread over the seeds of every parameter's z, for each sigma reported
    stats = {key: {s: (za[key][s].mean(0), za[key][s].std(0, ddof=1) if n_seeds > 1 else None)
                   for s in ("accel", "gyro")} for key in (("with", "segment") if main == "with" else (main,))}
    from calib.figures import calibration_plots   # matplotlib: imported only when drawing

    calibration_plots.z_scores(stats, names, main, n_seeds, fig)
    return metrics
