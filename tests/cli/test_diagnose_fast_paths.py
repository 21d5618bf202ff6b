"""The faster paths ``calib diagnose`` takes give the numbers of the plain ones, to the last bit.

* The reduced inputs of the rotation windows under a clock offset (the time-offset candidate's grid, the base
  design, the latitude and gravity differences) come from compiled sample loops
  (:func:`calib.diagnosis.geometry.rotation_reduced`); the reference is ``W^T`` :func:`window_inputs`, offset by
  offset, as the library computed them before -- for both sample-time conventions.
* The library evaluates a registry effect once for a group of parameters on distinct sensor axes
  (:func:`calib.diagnosis.library.build_library`); the reference is one evaluation per parameter.
"""
from __future__ import annotations

import numpy as np
import pytest

from calib.diagnosis import geometry, library
from calib.io import recording
from calib.sim import effects, simulator

SHORT = {"site": {"latitude_deg": 30.58, "height_m": 0.0}, "dwell_s": 20.0, "revolutions": 1}


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = simulator.simulate_calibration_session(SHORT, 3, tmp_path_factory.mktemp("fast") / "s.nc")
    return recording.load(path)


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def _reference(geom, w, delta, latitude_deg=None, gravity_m_s2=None):
    f, om, _, _ = geometry.window_inputs(geom, w, delta, latitude_deg, gravity_m_s2, need_accel=False)
    return (w.W[:, :geometry.rows_of("accel", w)].T @ f, w.W[:, :geometry.rows_of("gyro", w)].T @ om)


@pytest.mark.parametrize("convention", ["interval_start", "interval_centre"])
def test_rotation_inputs_are_those_of_window_inputs(session, convention):
    ds = session.copy()
    ds.attrs["sample_time_convention"] = convention
    geom = geometry.build_geometry(ds)
    assert geom.rotation and all(w.spline is not None for w in geom.rotation)
    grid = np.arange(-geom.max_offset_s, geom.max_offset_s + 0.5 * 0.0125, 0.0125)
    vals = geometry.offset_grid_inputs(geom, grid)
    for d in (0, 7, len(grid) // 2, len(grid) - 1):
        ref = np.concatenate([np.concatenate([_reference(geom, w, float(grid[d]))[i].ravel() for w in geom.rotation])
                              for i in range(2)])
        assert _same(vals[d], ref)
    lat = geom.latitude_deg + 0.01
    xr, ones = geometry.reduced_inputs(geom, latitude_deg=lat)
    for j, w in enumerate(geom.windows):
        assert _same(ones["gyro"][j], w.W[:, :geometry.rows_of("gyro", w)].sum(axis=0))
        if w.kind == "rotation":
            ra, rg = _reference(geom, w, 0.0, latitude_deg=lat)
            assert _same(xr["accel"][j], ra) and _same(xr["gyro"][j], rg)


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
    mine = [ln for ln in logs[1].splitlines() if "geometry._angles_loop" in ln or "geometry._inputs_loop" in ln]
    assert any("data loaded" in ln and "_angles_loop" in ln for ln in mine), logs[1][-2000:]
    assert any("data loaded" in ln and "_inputs_loop" in ln for ln in mine), logs[1][-2000:]
    assert not [ln for ln in mine if "saved" in ln], mine
