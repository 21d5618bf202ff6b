"""What the diagnosis's own observations can know about an effect: the Fisher bound of its window reductions beside
the bound of the whole sample stream, and the reason where its estimates spread more than twice the stream's bound.

The stream bound is the Gaussian Fisher information of every sample under the simulator's noise with its exact
covariance (:func:`calib.sim.fisher.information_exact`; Whittle's periodic approximation overstates the information
of effects as slow as the session -- a warm-up, a temperature coefficient -- about twofold). The diagnosis
(:mod:`calib.diagnosis.geometry`) first reduces the stream to window reductions: the means of the static segments
(trimmed at both ends) and, over the whole revolutions of each constant-rate rotation, the accelerometer means and
the gyro means and table-angle harmonics. The 45 deg moves between static positions, the spin-up and spin-down ramps
and the partial revolutions are in no window. This module computes the Gaussian Fisher information of exactly those
reductions under the same generative model (the derivatives of the physical path, the simulator's noise, the 24
base parameters as nuisances):

    J_r = D_r^T Sigma_r^-1 D_r,    D_r = W^T D,    Sigma_r = W^T Sigma W   (per channel)

``W`` the reduction weights of every window, ``D`` the per-sample derivatives, ``Sigma`` the exact stationary
covariance of the noise (:func:`calib.diagnosis.bound.reduction_covariance`). Then

* ``reduced bound / stream bound`` is the information the reduction leaves out (the moves, ramps and partial
  revolutions, and the averaging inside a window): a property of the path and of the reduction, not of the fit;
* ``spread of the estimates / reduced bound`` is the estimator's own inefficiency on the observations it has.

The warm-up time constant of a bias drift is profiled by the diagnosis; its derivative is then a column of both
informations (free), so the bounds of the warm-up amplitudes include what not knowing it costs.
"""
from __future__ import annotations

import copy
import math
from types import SimpleNamespace

import numpy as np
from scipy import stats

from calib.diagnosis.bound import reduction_covariance as _reduction_covariance
from calib.diagnosis.geometry import SENSORS, Window, build_geometry, rows_of
from calib.sim import effects as sim_effects
from calib.sim import fisher as sim_fisher
from calib.sim import physical as sim_physical
from calib.sim.counts_engine import noise_terms

#: the shape parameters the diagnosis estimates (profiles on a grid) rather than assumes, per effect
PROFILED_SHAPES = {"bias_drift": ("accel_tau_s", "gyro_tau_s")}
#: relative step of the central differences of a profiled shape parameter
_SHAPE_STEP = 1e-3
#: the length [s] of the means of the samples outside every window in the extended reduction
#: (:func:`extended_windows`): short against a spin-up, a spin-down or a 45 deg move (a few seconds each)
OUTSIDE_MEAN_S = 0.5
#: the spread of the estimates over the stream's bound above which the proof says why
RATIO_LIMIT = 2.0
#: the detection power of the Fisher-limited detection scale (as the proof's empirical one)
POWER = 0.8


def _columns(cfg: dict, sim, clean, effect_id: str, params: dict, temperature):
    """(effect parameter names, their derivative columns by channel, the nuisance columns' names and columns by
    channel; :class:`calib.sim.fisher.ChannelColumns`): the columns of :func:`calib.sim.fisher.information_for`,
    plus a column per shape parameter of :data:`PROFILED_SHAPES` (central differences of the physical path) whose
    effect is not zero."""
    cfg = copy.deepcopy(cfg)
    cfg["effects"] = {k: v for k, v in (cfg.get("effects") or {}).items() if k != effect_id}
    full = sim_effects.resolve({effect_id: params or {}})[effect_id]
    full = {k: v for k, v in full.items() if k != "enabled"}
    enames, ecols = sim_fisher._effect_columns(cfg, sim, clean, effect_id, full, temperature)
    for key in PROFILED_SHAPES.get(effect_id, ()):
        v0 = float(full[key])
        h = _SHAPE_STEP * v0
        d = (sim_physical.inject(sim, clean, {effect_id: {**full, key: v0 + h}}, temperature)
             - sim_physical.inject(sim, clean, {effect_id: {**full, key: v0 - h}}, temperature)) / (2.0 * h)
        if np.any(d != 0.0):     # a warm-up of zero size: its time constant is not a parameter of the data
            ecols.append(d)
            enames.append(key)
    return enames, sim_fisher.ChannelColumns.from_columns(ecols, copy=True), sim_fisher._nuisance_channels(sim, clean)


def reduced_information(cols, sim, geom, n_effect: int | None = None) -> np.ndarray | None:
    """Fisher information of the window reductions of geometry ``geom`` (:func:`calib.diagnosis.geometry.
    build_geometry`: static means, rotation means and gyro harmonics) about the parameters of the per-sample
    derivative columns ``cols`` (list of (n, 6), or :class:`calib.sim.fisher.ChannelColumns`) under the noise of
    simulator ``sim``: per channel ``Dr^T Sr^-1 Dr``, ``Dr = W^T D``, ``Sr = W^T Sigma W`` with Sigma the exact stationary covariance
    (:func:`calib.diagnosis.bound.reduction_covariance`; no circulant approximation: for effects as slow as the
    session, the circulant form wraps the end of the bias instability onto its start and overstates the
    information severalfold).
    ``n_effect``: the first columns are the effect's (default all); a channel none of them touches is left out
    (its rows and columns of the result stay zero). None for a random-walk bias (not stationary)."""
    nz = sim.noise
    if nz["bias_model"] != "gauss_markov":
        return None
    dt = 1.0 / float(sim.sample_rate_hz)
    sig_w, sig_b, tau = noise_terms(nz, dt)
    K = np.concatenate([sim.accel.K, sim.gyro.K])
    cols = sim_fisher.as_channel_columns(cols)
    p = cols.p
    n_effect = p if n_effect is None else int(n_effect)
    J = np.zeros((p, p))
    for c in range(6):
        sensor = SENSORS[c // 3]
        use = [k for k, _ in cols.by_channel[c]]
        if not use or use[0] >= n_effect:
            # a channel the effect does not touch informs only its own base parameters (each channel has its
            # own scale, misalignments and bias): it leaves the effect's bounds as they are and is skipped
            continue
        D = cols.block(c)[1]                  # (n, p_c): the columns that touch channel c
        rows = [(w.i0, w.i1, np.ascontiguousarray(w.W[:, q])) for w in geom.windows
                for q in range(rows_of(sensor, w))]
        every = np.arange(D.shape[1])
        Dr, Dw, at = [], None, None
        for i0, i1, wq in rows:               # a window's samples copied once for all its rows
            if at != (i0, i1):
                # by an index array: the column-major copy whose products keep the summation order they have
                Dw, at = D[i0:i1, every], (i0, i1)
            Dr.append(wq @ Dw)
        Dr = np.array(Dr)                     # (m, p_c)
        del D, Dw
        Sr = _reduction_covariance(rows, float((K[c] * sig_w[c]) ** 2), float((K[c] * dt * sig_b[c]) ** 2),
                                   math.exp(-dt / float(tau[c])), bool(nz["quantize"]))
        A = np.linalg.solve(np.linalg.cholesky(Sr), Dr)
        J[np.ix_(use, use)] += A.T @ A
    return J


def extended_windows(geom, mean_s: float = OUTSIDE_MEAN_S):
    """The diagnosis's windows and, for every run of samples outside them (the moves between static positions, the
    spin-up and spin-down ramps, partial revolutions, the trimmed ends), consecutive means of ``mean_s`` seconds:
    the reduction an estimator that also used those samples would fit (an object with ``windows`` in time order,
    for :func:`reduced_information`)."""
    L = max(2, int(round(mean_s / geom.dt)))
    inside = np.zeros(geom.n_samples, bool)
    for w in geom.windows:
        inside[w.i0:w.i1] = True
    out = list(geom.windows)
    idx = np.flatnonzero(~inside)
    for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if idx.size else []:
        for a in range(0, run.size, L):
            part = run[a:a + L]
            w = Window("outside", "", -1, int(part[0]), int(part[-1]) + 1)
            w.W = np.full((part.size, 1), 1.0 / part.size)
            out.append(w)
    return SimpleNamespace(windows=sorted(out, key=lambda w: w.i0))


def information_pair(cfg: dict, effect_id: str, params: dict | None, sim, clean, temperature, template) -> dict:
    """The stream's (Whittle's approximation, :func:`calib.sim.fisher.information`, and the exact covariance,
    :func:`calib.sim.fisher.information_exact`) and the window reductions' Fisher information about effect ``effect_id`` of session ``cfg``
    (its simulator ``sim``, noise-free increments ``clean`` without the effect, recorded ``temperature``; the
    diagnosis's windows from the session's recording ``template``). Returns ``{"names", "stream", "exact",
    "reduced", "extended", "n_obs", "shapes"}``: the effect's parameter names (a profiled shape parameter last) and
    the informations with the 24 base parameters after them (``extended``: the windows and the samples outside them
    as :data:`OUTSIDE_MEAN_S` means, :func:`extended_windows`; all but ``stream`` None for a random-walk bias), the number of the diagnosis's observations, the shape parameters
    among the names."""
    enames, ecols, nuisance = _columns(cfg, sim, clean, effect_id, params or {}, temperature)
    geom = build_geometry(template)
    # Whittle's, as calib.sim.fisher.information_for computes it (its base columns' spectra kept per session)
    stream = sim_fisher.information(ecols, sim_fisher.noise_spectrum(sim, len(clean)),
                                    fixed=sim_fisher._nuisance_spectra(sim, clean, nuisance))
    cols = ecols + nuisance[1]
    del nuisance
    return {"names": enames, "stream": stream,
            "exact": sim_fisher.information_exact(cols, sim),
            "reduced": reduced_information(cols, sim, geom, ecols.p),
            "extended": reduced_information(cols, sim, extended_windows(geom), ecols.p),
            "n_obs": int(geom.obs["n"]),
            "shapes": [nm for nm in enames if nm in PROFILED_SHAPES.get(effect_id, ())]}


def bounds_pair(info: dict, free=None) -> dict:
    """``{"stream": bounds, "exact": bounds, "reduced": bounds}`` (:func:`calib.sim.fisher.bounds_from`) of
    :func:`information_pair`'s result (``exact``, ``reduced`` empty when there is no such information); ``free``: the size
    parameters estimated (the profiled shape parameters are always free: the diagnosis estimates them)."""
    fr = None if free is None else set(free) | set(info["shapes"])
    return {k: {} if info[k] is None else
            {nm: b for nm, b in sim_fisher.bounds_from(info[k], info["names"], free=fr).items()
             if nm not in info["shapes"]} for k in ("stream", "exact", "reduced", "extended")}


def fisher_detection_scale(J: np.ndarray, names: list, truth: dict, n_obs: int, alpha: float, min_delta_bic: float,
                           free=None, power: float = POWER):
    """The smallest fraction s of the effect ``truth`` (``{name: value}``) that a likelihood-ratio test of its
    parameters with the diagnosis's acceptance rule (chi-square gain above ``k ln(n_obs) + min_delta_bic`` and
    p < ``alpha``, k the parameters tested) detects with probability ``power`` when the chi-square gain is
    noncentral chi-square with k degrees of freedom and noncentrality ``s^2 theta^T C^-1 theta`` (C the
    Fisher covariance of the effect's parameters ``free`` with the others and the base parameters free). None
    when the information does not determine them or the effect is zero."""
    keep = [k for k, nm in enumerate(names) if free is None or nm in free]
    idx = keep + list(range(len(names), J.shape[0]))
    Jk = J[np.ix_(idx, idx)]
    sel = [r for r, k in enumerate(keep) if names[k] in truth]
    if not sel:
        return None
    sc = np.sqrt(np.diag(Jk))
    sc[~(sc > 0)] = 1.0                     # the rows of channels left out (zero) stay zero
    try:
        C = (np.linalg.pinv(Jk / np.outer(sc, sc), rcond=1e-9, hermitian=True) / np.outer(sc, sc))[np.ix_(sel, sel)]
        Ci = np.linalg.inv(C)
    except np.linalg.LinAlgError:
        return None
    th = np.array([truth[names[keep[r]]] for r in sel], float)
    lam1 = float(th @ Ci @ th)
    if not lam1 > 0:
        return None
    k = len(sel)
    thr = max(k * math.log(n_obs) + min_delta_bic, float(stats.chi2.isf(alpha, k)))
    lo, hi = 0.0, 1.0
    while stats.ncx2.sf(thr, k, hi * hi * lam1) < power:   # bracket, then bisect on s
        lo, hi = hi, 2.0 * hi
        if hi > 1e6:
            return None
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if stats.ncx2.sf(thr, k, mid * mid * lam1) >= power:
            hi = mid
        else:
            lo = mid
    return hi


#: the information each effect's parameters have outside the diagnosis's windows, in plain words (the moves, ramps
#: and partial revolutions the windows leave out), by effect and parameter-name prefix; used where the reduction
#: loses more than half of the stream's precision
_LEFT_OUT = {
    "time_offset": ("a clock offset changes the gyro readings by angular acceleration x offset wherever the table "
                    "speeds up or slows down (spin-up and spin-down ramps, the 45 deg moves); at constant rate it only "
                    "shifts the phase of the Earth-rate and gravity harmonics, all the windows keep. Observations of "
                    "the ramps' gyro samples would add it"),
    "accel_lever_arm": ("an off-diagonal lever arm acts through the tangential acceleration d(omega)/dt x r, zero at "
                        "constant rate: only the ramps and the moves carry it; a diagonal one through omega^2 r, which "
                        "the moves carry as much as the windows. Observations of the ramps' and moves' accelerometer "
                        "samples would add it"),
    "temperature_sensitivity/gyro_scale": ("a gyro scale temperature coefficient shows as rate x temperature: the "
                                           "whole-revolution windows come in one block late in the warm-up, the "
                                           "45 deg moves between the static positions span it but are in no window; "
                                           "rotations spread over the warm-up, or the moves as observations, would "
                                           "add it"),
}


def why_above_2(effect_id: str, name: str, std_over_stream: float | None, stream, exact, reduced,
                std_over_reduced: float | None, extended=None) -> str | None:
    """Why the spread of the estimates of parameter ``name`` exceeds :data:`RATIO_LIMIT` times the stream's Fisher
    bound ``stream`` (Whittle's approximation), in numbers: how far the exact covariance raises the stream's bound
    (``exact / stream``), the part lost by the reduction to windows (``reduced / exact``, with what the windows
    leave out, and where ``extended`` -- the bound with the samples outside the windows as short means -- would
    bring it) and the estimator's own part (``std / reduced``). None when it does not exceed the limit."""
    if std_over_stream is None or not std_over_stream > RATIO_LIMIT:
        return None
    parts = []
    if stream and exact and exact / stream > 1.2:
        parts.append(f"the exact covariance puts the stream's bound at {exact / stream:.3g} x Whittle's (an effect as "
                     "slow as the session: the periodic approximation joins the end of the bias instability to its "
                     "start)")
    ref = exact or stream
    if reduced is None:
        parts.append("the diagnosis's window reductions do not determine it")
    elif ref:
        loss = reduced / ref
        key = (f"{effect_id}/gyro_scale" if effect_id == "temperature_sensitivity" and name.startswith("gyro_scale")
               else effect_id)
        txt = f"the window reductions' bound is {loss:.3g} x the stream's"
        if loss > 1.5 and key in _LEFT_OUT:
            txt += f" ({_LEFT_OUT[key]})"
        if loss > 1.5 and extended:
            txt += (f"; the samples outside the windows as {OUTSIDE_MEAN_S:g}-s means would bring it to "
                    f"{extended / ref:.3g} x")
        parts.append(txt)
    if std_over_reduced is not None:
        parts.append(f"the estimates spread {std_over_reduced:.3g} x the reductions' bound"
                     + (" (efficient on the observations it has)" if std_over_reduced <= 1.5 else
                        " (information the fit leaves unused on its own observations)"))
    return "; ".join(parts)


def _truth_values(effect_id: str, params: dict | None) -> dict:
    """``{parameter name: injected value}`` of the size parameters of an effect (the names of
    :func:`calib.sim.fisher.bounds_from`)."""
    full = sim_effects.resolve({effect_id: params or {}})[effect_id]
    return {nm: float(np.asarray(full[key], dtype=float)[idx]) for nm, key, idx in sim_fisher._names(effect_id, full)}


def proof_bounds(infos: list, fitted: set, effects: dict, settings: dict, rename=lambda b: b) -> dict:
    """The proof's Fisher bounds of a single-effect session from its :func:`information_pair` results ``infos``
    (one per effect of ``effects``, in its order): ``all_free`` (the stream by Whittle's approximation, every size
    parameter free), ``as_fitted`` (the same, the parameters ``fitted`` free, the others at their truth),
    ``exact`` (the stream with its exact covariance, as fitted), ``reduced`` (the diagnosis's window reductions,
    as fitted) -- each renamed by ``rename`` to the names the diagnosis reports -- and ``detection``: the
    Fisher-limited detection scale (:func:`fisher_detection_scale`, with ``settings``' ``alpha`` and
    ``min_delta_bic``) of the stream (exact covariance) and of the reductions, as fitted."""
    out = {"all_free": {}, "as_fitted": {}, "exact": {}, "reduced": {}, "extended": {},
           "detection": {"stream": None, "reduced": None}}
    for info, (eid, params) in zip(infos, effects.items()):
        allf, asf = bounds_pair(info), bounds_pair(info, free=fitted)
        out["all_free"].update(rename(allf["stream"]))
        out["as_fitted"].update(rename(asf["stream"]))
        out["exact"].update(rename(asf["exact"]))
        out["reduced"].update(rename(asf["reduced"]))
        out["extended"].update(rename(asf["extended"]))
        if len(infos) == 1:
            truth = {nm: v for nm, v in _truth_values(eid, params).items() if nm in fitted}
            for k in ("exact", "reduced"):
                if info[k] is None:
                    continue
                out["detection"]["stream" if k == "exact" else k] = fisher_detection_scale(info[k], info["names"], truth, info["n_obs"],
                                                             float(settings["alpha"]),
                                                             float(settings["min_delta_bic"]),
                                                             free=set(fitted) | set(info["shapes"]))
    return out


def reduced_columns(effect_id: str, name: str, pp: dict, exact, reduced, extended=None) -> dict:
    """The proof's per-parameter entries of the exact stream bound ``exact``, the window reductions' bound
    ``reduced`` and the extended reduction's ``extended`` (:func:`extended_windows`) of parameter ``name`` whose summary ``pp`` holds ``fisher_bound`` (Whittle's), ``empirical_std``,
    ``mean_se`` and ``rms_error``: the bounds, the spread, the standard error and the rms error over them, and
    :func:`why_above_2`."""
    b, sd, rms, se = pp.get("fisher_bound"), pp.get("empirical_std"), pp.get("rms_error"), pp.get("mean_se")
    over = lambda x, y: None if x is None or not y else x / y
    std_red = over(sd, reduced)
    return {"fisher_bound_exact": exact, "se_over_exact_bound": over(se, exact),
            "std_over_exact_bound": over(sd, exact), "fisher_bound_reduced": reduced,
            "std_over_reduced_bound": std_red, "rms_error_over_reduced_bound": over(rms, reduced),
            "fisher_bound_extended": extended,
            "why_above_2": why_above_2(effect_id, name, pp.get("std_over_bound"), b, exact, reduced, std_red,
                                       extended)}
