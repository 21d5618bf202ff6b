"""The vector model set-up (synthetic sessions and any recording with nominal attitudes).

``N = M x + b`` per triad (M = K E, Liu 2021 eqs. 1-4) with inputs x known from the nominal attitudes and
the table rate/angle: linear, 24 parameters, all identified. :func:`setup_problem` reduces the recording,
fits the noise shape, calibrates the base model, builds the effect library at its solution and estimates
the slow noise by restricted ML (:mod:`calib.diagnosis.noise`).
"""
from __future__ import annotations

import numpy as np

from calib.diagnosis.fitting import fit
from calib.diagnosis.geometry import (SENSORS, DiagnosisInputError, base_design, build_geometry,
                                      pulse_counter_channels, reduce_data, reduced_inputs)
from calib.diagnosis.term_identifiability import prepare_library
from calib.diagnosis.library import build_library
from calib.diagnosis.noise import covariance_blocks, covariance_parts, fit_noise, reml_slow, with_measured_slow
from calib.diagnosis.problem import DEFAULT_SETTINGS, Problem, base_estimates

def setup_problem(ds, settings=None, *, library_from=None, geometry_from=None) -> Problem:
    """Observations, noise model, covariance, base design and effect library of a recording dataset.

    ``library_from``: a previous :class:`Problem` on the same geometry whose library (signatures at its base
    solution) is reused (the proof: every noise seed of a session shares the geometry). ``geometry_from``: a
    previous :class:`Problem` on the same geometry (the same segments, attitudes, table angle and temperature;
    other sensor data) whose geometry, covariance parts and base design are reused, the library being built anew
    at this recording's base solution: the same numbers as a set-up from scratch (the proof's power scan).
    """
    st = {**DEFAULT_SETTINGS, **(settings or {})}
    if library_from is not None:
        geometry_from = None
    shared = library_from if library_from is not None else geometry_from
    if shared is not None:
        geom = shared.geom
    else:
        geom = build_geometry(ds, max_offset_s=st["max_offset_s"], min_static=st["min_static"])
    if geom.n_samples / geom.fs < st["min_duration_s"]:
        raise DiagnosisInputError(f"{geom.source}: recording lasts {geom.n_samples / geom.fs:.1f} s, less than "
                                  f"{st['min_duration_s']:.0f} s", "record a longer session")
    if geom.model != "vector":
        raise DiagnosisInputError("no nominal attitudes: the vector model needs them", "use the norm problem")
    y, readings = reduce_data(geom, ds)
    noise = fit_noise(geom, readings, pulse_counter_channels(ds))
    if shared is not None:
        parts = shared.parts
        xr, ones = reduced_inputs(geom) if library_from is None else (None, None)
        X0 = shared.X0
    else:
        parts = {s: covariance_parts(geom, s) for s in SENSORS}
        xr, ones = reduced_inputs(geom)
        X0 = base_design(geom, xr, ones)
    cache = shared.cache if shared is not None else {}
    _, L = covariance_blocks(geom, noise, parts, cache)        # first guess (Allan random walk)
    prob = Problem(geom, y, noise, parts, L, X0, [], readings, settings=st, cache=cache)
    # the measured noise of the adequacy tests: the session's Allan deviation, and the slow part of a long static
    # record of the same unit when there is one -- never a level estimated from the window means
    if st.get("noise_record"):
        _, prob.L_measured = covariance_blocks(geom, with_measured_slow(noise, geom, st["noise_record"]), parts,
                                               cache)
        prob.noise_basis = f"measured: the session's static segments and the long static record {st['noise_record']}"
    else:
        prob.L_measured = dict(L)
        prob.noise_basis = ("measured within the session's static segments only (no long static record: the slow "
                            "noise between windows is not measured)")
    if library_from is not None:
        prob.lib = library_from.lib
    else:
        base = fit(prob, [])
        M, b = base_estimates(base.theta)
        prob.lib = build_library(geom, M, b, xr0=xr, ones0=ones)
        prepare_library(prob)
    # slow noise by REML on the contrasts orthogonal to the base model and every candidate term
    reml_slow(geom, noise, y, reml_design(prob), parts, cache)
    _, prob.L = covariance_blocks(geom, noise, parts, cache)
    prob.forget_whitened()
    prepare_library(prob)
    return prob


def reml_design(prob: Problem):
    """The fixed effects REML integrates out: the base design plus every candidate's columns that vary with
    attitude, rate or table angle (the clock offset to second order). Terms that are smooth in *time* --
    bias drift and the bias part of the temperature sensitivity -- are left out on purpose: a slow bias
    wander of the noise and a slow deterministic drift cannot be told apart from the data alone, so the
    noise model takes it (a drift is then found only where it exceeds what a bias instability of correlation
    time <= 600 s explains)."""
    cols = [prob.X0]
    for c in prob.lib:
        if c.untestable:
            continue
        if c.kind == "drift":
            continue
        if c.effect == "temperature_sensitivity":
            cols.append(c.S[:, [j for j, nm in enumerate(c.names) if "scale" in nm]])
        elif c.kind == "offset":
            M, _ = base_estimates(fit(prob, []).theta)
            cols += [c.offset.design_delta(0.0, M, deriv=1)[:, None], c.offset.design_delta(0.0, M, deriv=2)[:, None]]
        else:
            cols.append(c.S)
    return np.hstack(cols)
