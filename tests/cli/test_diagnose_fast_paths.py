"""The faster paths ``calib diagnose`` takes give the numbers of the plain ones: to the last bit, or where the
faster path sums in another order, within the rounding-error bound of the sums.

* The reduced inputs of the rotation windows under a clock offset (the time-offset candidate's grid, the base
  design, the latitude and gravity differences) come from a compiled loop over the samples and four matrix
  products (:func:`calib.diagnosis.geometry.rotation_reduced`); the reference is ``W^T`` :func:`window_inputs`,
  offset by offset, as the library computed them before -- for both sample-time conventions -- and the bound is
  that of a sum of n products, 2 (n + 4) eps times the sum of the terms' magnitudes.
* The library evaluates a registry effect once for a group of parameters on distinct sensor axes
  (:func:`calib.diagnosis.library.build_library`); the reference is one evaluation per parameter (to the bit).
* The generic bases reduce all terms of a family in one product (:func:`calib.diagnosis.library.reduce_axis_terms`);
  the reference is :func:`calib.diagnosis.library._reduce_term` term by term.
"""
from __future__ import annotations

import numpy as np
import pytest

from calib.diagnosis import geometry, library
from calib.io import recording
from calib.sim import effects
from calib.sim.calibration_session import simulate_calibration_session

SHORT = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = simulate_calibration_session(SHORT, 3, tmp_path_factory.mktemp("fast") / "s.nc")
    return recording.load(path)


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def _reference(geom, w, delta, latitude_deg=None, gravity_m_s2=None):
    """``W^T f`` and ``W^T omega`` of :func:`window_inputs`, and the rounding scale of each: ``|W|^T`` times the
    largest magnitude each sample's input can take from its three angle terms (|cos|, |sin| <= 1, |1 - cos| <= 2)
    and, for the gyros, the table rate."""
    f, om, w_nb, _ = geometry.window_inputs(geom, w, delta, latitude_deg, gravity_m_s2, need_accel=False)
    ga, wg = geometry.site_vectors(geom, latitude_deg, gravity_m_s2)
    u = np.asarray(w.axis, float)
    out = []
    for x, v, sensor in ((f, w.attitude.T @ ga, "accel"), (om, w.attitude.T @ wg, "gyro")):
        W = w.W[:, :geometry.rows_of(sensor, w)]
        mag = np.abs(v) + np.abs(np.cross(u, v)) + 2.0 * np.abs((u @ v) * u)
        scale = np.abs(W).T @ np.broadcast_to(mag, x.shape)
        if sensor == "gyro":
            scale = scale + np.abs(W).T @ np.abs(w_nb) / geometry.earth.DEG_PER_H * geometry.TO_MODEL[geom.units_in["gyro"]]
        out.append((W.T @ x, 2.0 * (w.n + 4) * np.finfo(float).eps * scale))
    return out


def _within(got, ref_bound):
    ref, bound = ref_bound
    got = np.asarray(got).reshape(ref.shape)
    return bool(np.all(np.abs(got - ref) <= bound)) and bool(np.all(bound < 1e-9 * np.max(np.abs(ref))))


def _tilt(geom):
    """Every rotation window's attitude turned 30 deg about a horizontal axis: the session's axes are all vertical,
    where the accelerometers' sin and (1 - cos) terms vanish or cancel; tilted, every term of the sum is seen."""
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    for w in geom.rotation:
        w.attitude = R @ w.attitude
    return geom


@pytest.mark.parametrize("convention,tilted", [("interval_start", False), ("interval_centre", False),
                                               ("interval_start", True)])
def test_rotation_inputs_are_those_of_window_inputs(session, convention, tilted):
    ds = session.copy()
    ds.attrs["sample_time_convention"] = convention
    geom = geometry.build_geometry(ds)
    if tilted:
        geom = _tilt(geom)
        ga, _ = geometry.site_vectors(geom)
        assert all(np.linalg.norm(np.cross(w.axis, w.attitude.T @ ga)) > 0.4 * np.linalg.norm(ga)
                   for w in geom.rotation)
    assert geom.rotation and all(w.spline is not None for w in geom.rotation)
    grid = np.arange(-geom.max_offset_s, geom.max_offset_s + 0.5 * 0.0125, 0.0125)
    vals = geometry.offset_grid_inputs(geom, grid)
    for d in (0, 7, len(grid) // 2, len(grid) - 1):
        pos = 0
        for i in range(2):
            for w in geom.rotation:
                ref = _reference(geom, w, float(grid[d]))[i]
                assert _within(vals[d, pos:pos + ref[0].size], ref), (d, i)
                pos += ref[0].size
        assert pos == vals.shape[1]
    lat = geom.latitude_deg + 0.01
    xr, ones = geometry.reduced_inputs(geom, latitude_deg=lat)
    for j, w in enumerate(geom.windows):
        assert _same(ones["gyro"][j], w.W[:, :geometry.rows_of("gyro", w)].sum(axis=0))
        if w.kind == "rotation":
            ra, rg = _reference(geom, w, 0.0, latitude_deg=lat)
            assert _within(xr["accel"][j], ra) and _within(xr["gyro"][j], rg)


def test_generic_terms_reduced_together_are_each_reduced_alone(session):
    geom = geometry.build_geometry(session)
    ctx = library.sample_context(geom)
    n = ctx.t.size
    rng = np.random.default_rng(11)
    terms = [rng.normal(size=n), 1.0, ctx.t - ctx.t.mean()]
    K = np.array([1.0e5, 1.1e5, 0.9e5])
    for sensor in geometry.SENSORS:
        views, _ = library._reduce_plan(geom, ctx, sensor)
        nodes = max(sl.stop - sl.start for _, sl in views)
        conv = geometry.TO_MODEL[geom.units_in[sensor]]
        for axis in range(3):
            got = library.reduce_axis_terms(geom, ctx, terms, sensor, axis, K[axis] * conv)
            assert got.shape == (geom.obs["n"], len(terms))
            rows = geom.obs["blocks"][(geometry.SENSORS.index(sensor), axis)]
            for j, term in enumerate(terms):
                d = np.zeros((n, 3))
                d[:, axis] = term
                ref = library._reduce_term(geom, ctx, d, sensor, K, conv)
                # each entry a sum over one window's nodes: within 2 (nodes + 2) eps sum |W| |K conv term|
                mag = np.abs(np.broadcast_to(term, (n,))) * abs(K[axis] * conv)
                scale = np.zeros(geom.obs["n"])
                scale[rows] = np.concatenate([np.abs(Wt) @ mag[sl] for Wt, sl in views])
                assert np.all(np.abs(got[:, j] - ref) <= 2.0 * (nodes + 2) * np.finfo(float).eps * scale)
                others = np.setdiff1d(np.arange(geom.obs["n"]), rows)
                assert np.all(got[others, j] == 0.0) and np.all(ref[others] == 0.0)
                assert np.max(np.abs(ref[rows])) > 1e3 * np.max(2.0 * (nodes + 2) * np.finfo(float).eps * scale)


def test_grouped_library_columns_are_one_evaluation_per_parameter(session):
    geom = geometry.build_geometry(session)
    xr, ones = geometry.reduced_inputs(geom)
    rng = np.random.default_rng(5)
    M = {s: np.diag([1e5, 1.1e5, 0.9e5]) + rng.normal(0, 50.0, (3, 3)) for s in geometry.SENSORS}
    b = {s: np.zeros(3) for s in geometry.SENSORS}
    lib = {c.key: c for c in library.build_library(geom, M, b, xr0=xr, ones0=ones)}
    ctx = library.sample_context(geom)
    conv = {s: geometry.TO_MODEL[geom.units_in[s]] for s in geometry.SENSORS}
    Kd = {s: np.diag(M[s]).copy() for s in geometry.SENSORS}
    E = {s: M[s] / Kd[s][:, None] for s in geometry.SENSORS}
    temp = ctx.temperature if ctx.temperature is not None else np.full(ctx.t.shape, 25.0)
    sctx = effects.SensorContext(ctx.t, ctx.f, ctx.w, effects.rows_times(ctx.f, E["accel"]),
                                 effects.rows_times(ctx.w, E["gyro"]), ctx.w_nb, ctx.dw_nb, temp, E["accel"],
                                 E["gyro"])

    def column(eid, sensor, p):
        da, dg = effects.REGISTRY[eid].apply(sctx, p)
        return library._reduce_term(geom, ctx, da if sensor == "accel" else dg, sensor, Kd[sensor], conv[sensor])

    checked = 0
    for key in ("accel_lever_arm/accel", "gyro_g_sensitivity/gyro", "accel_cross_coupling/accel",
                "temperature_sensitivity/gyro", "accel_quadratic_nonlinearity/accel"):
        c = lib[key]
        for j, (pkey, e) in enumerate(c.keys):
            p = library.zero_params(c.effect)
            arr = np.zeros(np.shape(effects.REGISTRY[c.effect].defaults[pkey]))
            arr[e] = 1.0
            p[pkey] = arr.tolist()
            assert _same(c.S[:, j], column(c.effect, c.sensor, p)), (key, pkey, e)
            checked += 1
    for sensor, pre, wkey, skey in (("accel", "accel", "accel_warmup_ug", "accel_trend_ug_per_h"),
                                    ("gyro", "gyro", "gyro_warmup_deg_h", "gyro_trend_deg_h_per_h")):
        c = lib[f"bias_drift/{sensor}"]
        for tau in (120.0, 900.0):
            for i in range(3):
                for k, extra in ((wkey, {f"{pre}_tau_s": tau}), (skey, {})):
                    p = library.zero_params("bias_drift")
                    v = [0.0, 0.0, 0.0]
                    v[i] = 1.0
                    p[k] = v
                    p.update(extra)
                    col = i if k == wkey else 3 + i
                    assert _same(c.S_by_tau[tau][:, col], column("bias_drift", sensor, p))
                    checked += 1
    assert checked == 9 + 9 + 6 + 6 + 3 + 24


def test_compiled_loops_come_from_the_disk_cache_in_a_fresh_process(session, tmp_path):
    """The loops are compiled once (numba, cache beside the module) and loaded, not compiled, by every later
    process: a second fresh process reads them from the cache and writes nothing."""
    import os
    import subprocess
    import sys

    path = tmp_path / "s.nc"
    session.to_netcdf(path)
    code = ("import numpy as np\nfrom calib.io import recording\nfrom calib.diagnosis import geometry\n"
            f"ds = recording.load(r'{path}', validate_all=False)\ng = geometry.build_geometry(ds)\n"
            "geometry.offset_grid_inputs(g, np.linspace(-0.25, 0.25, 41))\n")
    env = dict(os.environ, NUMBA_DEBUG_CACHE="1")
    logs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300,
                           check=True).stdout for _ in range(2)]
    mine = [ln for ln in logs[1].splitlines() if "geometry._angles_loop" in ln]
    assert any("data loaded" in ln and "_angles_loop" in ln for ln in mine), logs[1][-2000:]
    assert not [ln for ln in mine if "saved" in ln], mine
