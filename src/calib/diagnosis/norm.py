"""The norm model set-up (recordings without nominal attitudes: real data).

Without attitudes the accelerometer *norm* model is used (Liu 2021 eq. 7, in the identified lower-triangular
form of :mod:`calib.calibration.objectives`), linearised at its solution: the observations are the norm
residuals of the static means, the base design their Jacobian, and only what the gravity norm sees can be
tested; every gyro term is listed as untestable with the experiment that would make it testable.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from calib.calibration import objectives as ob
from calib.calibration.ellipsoid import fit_ellipsoid
from calib.core.triad import MIN_POSES_TO_TEST
from calib.core.distributions import chi2_sf
from calib.core.earth import STANDARD_GRAVITY
from calib.diagnosis.geometry import AXES, TO_MODEL, DiagnosisInputError, build_geometry, rate_readings
from calib.diagnosis.term_identifiability import prepare_library
from calib.diagnosis.library import DRIFT_TAUS, EXPERIMENTS, Candidate, window_nodes, zero_params
from calib.diagnosis.problem import DEFAULT_SETTINGS, Problem, lstsq
from calib.signal import allan
from calib.sim import effects

NORM_EFFECTS = [("accel_quadratic_nonlinearity", [("k2_ug_per_g2", "vec")]),
                ("accel_cubic_nonlinearity", [("k3_ug_per_g3", "vec")]),
                ("accel_scale_asymmetry", [("asym_ppm", "vec")]),
                ("accel_cross_coupling", [("k_cross_ug_per_g2", "offdiag")]),
                ("temperature_sensitivity", [("accel_bias_ug_per_degC", "vec"), ("accel_scale_ppm_per_degC", "vec")])]


#: the parameter dicts of the library's unit columns, built once per process (the registry's ``apply`` only reads them;
#: a repeated diagnosis, e.g. the real proof's repetitions, asked for thousands of fresh copies)
_UNIT_PARAMS: dict = {}


def _unit_params(eid, key, e, tau=None) -> dict:
    """The zeroed registry defaults of ``eid`` (:func:`zero_params`) with element ``e`` of ``key`` set to 1 (every
    element for ``e = "all"``; and, for the bias drift's warm-up, ``accel_tau_s = tau``). One dict per argument tuple,
    shared: do not modify."""
    k = (eid, key, e, tau)
    p = _UNIT_PARAMS.get(k)
    if p is None:
        p = zero_params(eid)
        arr = np.zeros(np.shape(effects.REGISTRY[eid].defaults[key]))
        if e == "all":
            arr[...] = 1.0
        else:
            arr[e] = 1.0
        p[key] = arr.tolist()
        if tau is not None:
            p["accel_tau_s"] = tau
        _UNIT_PARAMS[k] = p
    return p


def _norm_initial(N, ref):
    """Lower-triangular M and b from an algebraic ellipsoid fit of the static means: (N - b)^T (M M^T)^-1 (N - b)
    = ref^2."""
    fit = fit_ellipsoid(N)
    if fit is None:
        raise DiagnosisInputError("the static means do not lie on an ellipsoid: the norm calibration failed",
                                  "record static positions spread over all orientations")
    Qn, s0 = fit.Qn, fit.s0
    MMt = np.linalg.inv(Qn / s0**2 * ref**2)
    return np.linalg.cholesky(MMt), fit.bias


def _window_nodes(geom):
    """The evaluation nodes of the norm model's (static) windows, concatenated: their mid-times [s], the window each
    node belongs to, the node count per window and the temperature at the nodes (None without a temperature
    channel). Geometry only: computed once per geometry (:meth:`calib.diagnosis.geometry.Geometry.derived`)."""
    ts, temps, owner = [], [], []
    for j, w in enumerate(geom.windows):
        idx = window_nodes(geom, w)
        ts.append(geom.time_s[w.i0 + idx] + 0.5 * geom.dt)
        if geom.temperature is not None:
            temps.append(geom.temperature[w.i0 + idx])
        owner.append(np.full(idx.size, j))
    owner = np.concatenate(owner)
    return np.concatenate(ts), owner, np.bincount(owner), (np.concatenate(temps) if temps else None)


#: the library terms whose per-sample value does not depend on the sensor-axis input: the bias drift (a function of
#: time) and the temperature bias (of the temperature; the input enters its formula only through the scale term,
#: zero in a bias column: a signed zero, which the window sums do not see). Their window means are the same for
#: every recording on one geometry.
_INPUT_FREE = {("bias_drift", "accel_warmup_ug"), ("bias_drift", "accel_trend_ug_per_h"),
               ("temperature_sensitivity", "accel_bias_ug_per_degC")}
#: the library terms whose axis i is the size of element i times a function of that axis alone, evaluated element by
#: element (the registry's formulas): one evaluation with every element 1 holds the three unit terms in its columns,
#: the same numbers as three evaluations with one element 1
_SEPARABLE = {("accel_quadratic_nonlinearity", "k2_ug_per_g2"), ("accel_cubic_nonlinearity", "k3_ug_per_g3"),
              ("accel_scale_asymmetry", "asym_ppm"), ("temperature_sensitivity", "accel_bias_ug_per_degC"),
              ("temperature_sensitivity", "accel_scale_ppm_per_degC")}


def setup_norm_problem(ds, settings=None, *, geometry_from=None) -> Problem:
    """The accelerometer norm model (Liu 2021 eq. 7, lower-triangular form tri9) linearised at its solution:
    observations are the norm residuals r_m = ref^2 - |M^-1 (N_m - b)|^2 of the static means, the base design
    their Jacobian, the effect signatures -2 x^T M^-1 K dd/dphi (x = M^-1 (N - b), sensor-axis input
    y = (N - b)/K, K_i = |row i of M|). Noise: white + quantisation of each mean from the Allan deviation,
    propagated to r; if the base model's reduced chi-square exceeds 2, the sigmas are scaled by its square root
    (the unexplained scatter is treated as noise) and the report says so.

    ``geometry_from``: a previous norm :class:`Problem` of a recording with the same geometry (segment table,
    time axis, temperature and site; other accelerometer samples, e.g. a resampled repetition of it) whose
    geometry and what is derived from it alone are reused: the same numbers as a set-up from scratch."""
    st = {**DEFAULT_SETTINGS, **(settings or {})}
    if geometry_from is not None and geometry_from.kind == "norm":
        geom = geometry_from.geom
    else:
        geom = build_geometry(ds, max_offset_s=0.0, min_static=max(st["min_static"], MIN_POSES_TO_TEST))
    if geom.n_samples / geom.fs < st["min_duration_s"]:
        raise DiagnosisInputError(f"{geom.source}: recording lasts {geom.n_samples / geom.fs:.1f} s, less than "
                                  f"{st['min_duration_s']:.0f} s", "record a longer session")
    ya, _ = rate_readings(ds, "accel")
    if not np.all(np.isfinite(ya)):
        raise DiagnosisInputError(f"{geom.source}: variable 'accel' holds NaN or Inf")
    wins = geom.static
    geom.windows = wins
    Nm = np.array([ya[w.i0:w.i1].mean(axis=0) for w in wins])
    T = np.array([w.n * geom.dt for w in wins])
    recs = [ya[w.i0:w.i1] for w in wins]
    try:
        A = allan.adev_pooled(recs, geom.fs, unit=geom.units_out["accel"])
    except allan.AllanError as exc:
        raise DiagnosisInputError(f"{geom.source}: no noise estimate for 'accel' ({exc})",
                                  "the static segments must hold varying samples (not flat data)") from exc
    nm = A.noise_model(("Q", "N"))
    if np.any(~(nm.N > 0)) and np.any(~(nm.Q > 0)):
        raise DiagnosisInputError(f"{geom.source}: the accelerometer shows no noise in its static segments (flat "
                                  "data?): sigma of the means cannot be estimated")
    sigN = np.sqrt(nm.N[None, :] ** 2 / T[:, None] + 2.0 * nm.Q[None, :] ** 2 / T[:, None] ** 2)
    iu = geom.units_in["accel"]
    conv = TO_MODEL[iu]
    ref = geom.gravity_m_s2 / STANDARD_GRAVITY * conv
    M0, b0 = _norm_initial(Nm, ref)
    form = ob.Form("tri9")
    th0 = form.from_KE_b(M0, b0)
    obj = ob.NormObjective(Nm, ref, form="tri9", sigma=sigN)
    obj.weighted = True
    obj.set_weights(th0)
    sol = least_squares(obj.residuals, th0, jac=obj.jacobian, method="lm", xtol=1e-14, ftol=1e-14)
    th = sol.x
    obj.set_weights(th)
    sol = least_squares(obj.residuals, th, jac=obj.jacobian, method="lm", xtol=1e-14, ftol=1e-14)
    th = sol.x
    obj.weighted = False
    r0 = obj.residuals(th)
    J = obj.jacobian(th)
    sr = obj.residual_sigma(th)
    M, b = form.KE_b(th)
    Kd = np.linalg.norm(M, axis=1)
    xh = np.linalg.solve(M, (Nm - b).T).T
    yin = (Nm - b) / Kd                       # sensor-axis input [model input unit]
    G = -2.0 * np.linalg.solve(M.T, xh.T).T * (Kd * conv)[None, :]   # dr/dd per segment (m, 3), d in g
    # per-window nodes for time-dependent terms
    t, owner, cnt, temp = geom.derived(("norm", "nodes"), lambda: _window_nodes(geom))
    yreg = yin[owner] / conv
    temp = temp if temp is not None else np.full(t.shape, 25.0)
    finite_input = bool(np.all(np.isfinite(yreg)))
    E_id = np.eye(3)
    ctx = effects.SensorContext(t, yreg, np.zeros_like(yreg), yreg, np.zeros_like(yreg), np.zeros_like(yreg),
                                np.zeros_like(yreg), temp, E_id, E_id)

    m = len(wins)

    def window_means(da, only=None):
        # per-window means of the node terms ``da`` (the columns but ``only`` zero): np.add.at's sums (each in node
        # order from 0), by bincount (the same order); a column of zeros sums to +0 whatever the signs of its zeros
        dm = np.empty((m, 3))
        for c in range(3):
            if (only is None or c == only) and da[:, c].any():
                dm[:, c] = np.bincount(owner, weights=da[:, c], minlength=m)
            else:
                dm[:, c] = 0.0
        dm /= cnt[:, None]
        return dm

    separable = {}

    def unit_means(eid, key, e, tau):
        if (eid, key) in _SEPARABLE:
            if (eid, key) not in separable:
                separable[(eid, key)] = effects.REGISTRY[eid].apply(ctx, _unit_params(eid, key, "all"))[0]
            return window_means(separable[(eid, key)], e[0])
        return window_means(effects.REGISTRY[eid].apply(ctx, _unit_params(eid, key, e, tau))[0])

    def col(eid, key, e, tau=None):
        """Column of the unit term ``(key, e)`` (bias drift: warm-up time constant ``tau``); window means of a term
        that does not depend on the input (:data:`_INPUT_FREE`) are kept with the geometry."""
        if (eid, key) in _INPUT_FREE and finite_input:
            dm = geom.derived(("norm", "window_means", eid, key, e, tau), lambda: unit_means(eid, key, e, tau))
        else:
            dm = unit_means(eid, key, e, tau)
        return np.sum(G * dm, axis=1)

    geom.obs = {"sensor": np.zeros(m, int), "axis": np.zeros(m, int), "window": np.arange(m), "row": np.zeros(m, int),
                "n": m, "blocks": {(0, 0): np.arange(m)}}
    lib = []
    temp_ok = geom.temperature is not None and float(np.ptp(temp)) > 0.05
    for eid, layout in NORM_EFFECTS:
        names, units, axes_, cols, keys = [], [], [], [], []
        for key, kind in layout:
            entries = ([(i,) for i in range(3)] if kind == "vec" else
                       [(i, j) for i in range(3) for j in range(3) if i != j])
            for e in entries:
                cols.append(col(eid, key, e))
                names.append(key + "[" + ",".join(AXES[i] for i in e) + "]")
                units.append(effects.REGISTRY[eid].units.get(key, ""))
                axes_.append(AXES[e[0]])
                keys.append((key, e))
        c = Candidate(eid, "accel", names, units, axes_, np.column_stack(cols), keys=keys)
        if eid == "temperature_sensitivity" and not temp_ok:
            c.untestable, c.experiment = EXPERIMENTS["temperature_sensitivity"]
        lib.append(c)
    # bias drift of the accelerometer
    unit_of = effects.REGISTRY["bias_drift"].units
    names = [f"accel_warmup_ug[{a}]" for a in AXES] + [f"accel_trend_ug_per_h[{a}]" for a in AXES]
    c = Candidate("bias_drift", "accel", names,
                     [unit_of["accel_warmup_ug"]] * 3 + [unit_of["accel_trend_ug_per_h"]] * 3, list(AXES) * 2,
                     kind="drift", keys=[("accel_warmup_ug", (i,)) for i in range(3)]
                     + [("accel_trend_ug_per_h", (i,)) for i in range(3)])
    trend = []
    for i in range(3):
        trend.append(col("bias_drift", "accel_trend_ug_per_h", (i,)))
    for tau in DRIFT_TAUS:
        cols = []
        for i in range(3):
            cols.append(col("bias_drift", "accel_warmup_ug", (i,), tau))
        c.S_by_tau[tau] = np.column_stack(cols + trend)
    c.S = c.S_by_tau[900.0]
    lib.append(c)
    g_col = np.full(m, 2.0 * ref * (ref / geom.gravity_m_s2))           # dr/d(delta g)
    lib.append(Candidate("gravity_error", "site", ["delta_g_m_s2"], ["m s-2"], [""], g_col[:, None],
                            keys=[("delta_g_m_s2", ())]))
    for eid, sensor, reason in (("latitude_error", "site", "latitude_error_norm"),
                                ("time_offset", "clock", "time_offset"),
                                ("accel_lever_arm", "accel", "accel_lever_arm"),
                                ("gyro_g_sensitivity", "gyro", "gyro_norm"),
                                ("gyro_scale_asymmetry", "gyro", "gyro_norm"),
                                ("gyro_scale_nonlinearity", "gyro", "gyro_norm"),
                                ("bias_drift", "gyro", "gyro_norm"),
                                ("temperature_sensitivity", "gyro", "gyro_norm")):
        cc = Candidate(eid, sensor, [], [], [], np.zeros((m, 0)))
        cc.untestable, cc.experiment = EXPERIMENTS[reason]
        lib.append(cc)
    chi0 = float(np.sum((r0 / sr) ** 2))
    dof0 = m - 9
    # scatter beyond the sensor noise: estimated against the base model *plus* every attitude-dependent
    # candidate (so that a term of the library is not charged to the noise), like the REML of the vector model
    cand_cols = [c.S for c in lib if c.S is not None and c.S.shape[1] and not c.untestable and c.kind != "drift"
                 and c.effect not in ("gravity_error", "temperature_sensitivity")]
    yv = r0 / sr

    def scatter(cols):
        A_ = np.hstack([J] + cols) / sr[:, None]
        th_, _, rk_ = lstsq(A_, yv)
        rr = yv - A_ @ th_
        return float(rr @ rr), m - rk_

    chi_f, doff = scatter(cand_cols)
    note_few = ""
    if doff < 5:
        # too few segments to hold every candidate: add them greedily (largest chi-square drop first) while
        # at least max(5, m/4) degrees of freedom remain
        chosen, rest = [], list(cand_cols)
        chi_f, doff = scatter([])
        while rest:
            trials = [scatter(chosen + [c]) for c in rest]
            j = int(np.argmin([t[0] for t in trials]))
            if trials[j][1] < max(5, m // 4):
                break
            chosen.append(rest.pop(j))
            chi_f, doff = trials[j]
        note_few = (f" ({m} segments cannot hold every candidate: the scatter is estimated with {len(chosen)} of "
                    f"{len(cand_cols)} candidate terms, the strongest first)")
    over = chi_f / doff if doff > 0 else float("inf")
    if dof0 < 3:
        raise DiagnosisInputError(f"{geom.source}: {m} static segments leave {dof0} degrees of freedom after the "
                                  "9-parameter norm calibration", "record more static positions")
    scale = math.sqrt(over) if over > 1.0 else 1.0
    Ls = {(0, 0): np.diag(sr * scale)}
    noise_method = ("white noise and quantisation of each static mean from the Allan deviation pooled over the "
                    "static segments (N^2/T + 2Q^2/T^2), propagated to the norm residuals")
    if scale > 1.0:
        noise_method += (f"; the segment means scatter {scale:.3g} times more than that (reduced chi-square {over:.3g} "
                         "of the base model plus every attitude-dependent candidate), so every sigma is scaled by "
                         f"{scale:.3g}: the excess (hand placement, vibration, unmodelled physics) is treated as noise "
                         "and findings are hypotheses") + note_few
    prob = Problem(geom, r0, None, None, Ls, J, lib, {"accel": ya}, n_noise_params=1 if scale > 1 else 0,
                   settings=st, kind="norm", base_names=tuple(f"accel:{n}" for n in form.names))
    prob.base_theta = th
    prob.noise_method = noise_method
    prob.overdispersion = over
    prob.L_measured = {(0, 0): np.diag(sr)}   # the Allan-measured noise, before any scaling to the scatter
    prob.noise_basis = ("measured within the static segments (white noise and quantisation of each mean); the slow "
                        "noise between segments is not in the norm model's noise")
    prob.raw_chi2 = (chi0, dof0, chi2_sf(chi0, max(dof0, 1)))
    prob.norm_allan = A
    # for the generic bases of calib.diagnosis.generic: dr/dd per segment and axis, and the segments' mid times
    prob.norm_generic = {"G": G, "t": np.array([geom.time_s[w.i0] + 0.5 * w.n * geom.dt for w in wins])}
    prepare_library(prob)
    return prob
