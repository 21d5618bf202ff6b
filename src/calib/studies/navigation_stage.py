"""Liu et al. (2021) §4 static-navigation check (Figure 10): navigate a static recording of the calibrated unit with
the parameters identified by each method, and the project's ``calib navigate`` stage.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import xarray as xr

from calib.signal import plausibility
from calib.nav import navigation
from calib.io.netcdf import write_netcdf
from calib.core.triad import TriadModel
from calib.io.recording import read_header, require_sensors
from calib.core.progress import Progress
from calib.io.atomic import write_text


def _median_run(path):
    """Parameter vector of the run with the median L (a representative run, not the best) of a runs file."""
    with xr.open_dataset(path, engine="netcdf4") as ds:
        L = ds["L"].values
        k = int(np.argsort(L)[len(L) // 2])
        return ds["estimate"].values[k], int(ds["run"].values[k])


def method_calibrations(cal_dir, methods):
    """TriadCalibration per method: accelerometers from the paper's 12-parameter norm fit, gyros from the
    dynamic path (L_gm then biases), each the median-L run; and the project's default calibration."""
    cal_dir = Path(cal_dir)
    out, notes = {}, {}
    for m in methods:
        if m == "default":
            with xr.open_dataset(cal_dir / "default_calibration.nc", engine="netcdf4") as d:
                a, g = d["accel"].values, d["gyro"].values
            notes[m] = "default: 9-parameter norm accelerometers rotated to the body frame + eq. 25 gyros"
        else:
            a, ra = _median_run(cal_dir / "runs" / f"accel_{m}.nc")
            g, rg = _median_run(cal_dir / "runs" / f"gyro_dynamic_{m}.nc")
            notes[m] = f"{m}: accel run {ra}, gyro run {rg} (median L of each)"
        out[m] = navigation.TriadCalibration(TriadModel.from_vector(a, "g", "count s-1"),
                                             TriadModel.from_vector(g, "deg h-1", "count s-1"))
    return out, notes


def run_static_check(recording_path, cal_dir, out_nc, fig, metrics_path, check: dict, nav: dict, prov=None, log=print):
    """Liu et al. (2021) Figure 10: east/north velocity and latitude/longitude errors of the static navigation with each
    method's parameters, initial position and attitude known (the paper's 'download' of initial values)."""
    methods = list(check["methods"])
    if "default" not in methods:
        methods.append("default")
    cals, notes = method_calibrations(cal_dir, methods)
    parts = []
    for m in methods:
        ds = navigation.navigate_recording(recording_path, calibration=cals[m], init="attrs",
                                           nav_rate_hz=nav["nav_rate_hz"], output_interval_s=nav["output_interval_s"],
                                           progress=lambda d, n, m=m: None)
        keep = ["vE_err", "vN_err", "lat_err_arcmin", "lon_err_arcmin", "north_err_m", "east_err_m",
                "pitch_err_arcmin", "roll_err_arcmin", "yaw_err_arcmin"]
        parts.append(ds[keep].expand_dims(calibration=[m]))
        log(f"{notes[m]}: max |vE| {float(np.abs(ds['vE_err']).max()):.3f} m/s, "
            f"max |vN| {float(np.abs(ds['vN_err']).max()):.3f} m/s")
    res = xr.concat(parts, dim="calibration")
    res.attrs.update({"initial_condition": "true position and attitude (Liu 2021 §4.2)",
                      "vertical_channel": "held", "methods": json.dumps(notes)})
    write_netcdf(res, out_nc, prov)
    # matplotlib with the project's rc settings, imported here: the navigate rule draws nothing and starts sooner
    from calib.figures import navigation_plots

    navigation_plots.static_check(res, fig)
    metrics = {m: {"max_abs_vE_m_s": float(np.abs(res["vE_err"].sel(calibration=m)).max()),
                   "max_abs_vN_m_s": float(np.abs(res["vN_err"].sel(calibration=m)).max()),
                   "final_position_error_m": float(np.hypot(res["north_err_m"].sel(calibration=m)[-1],
                                                            res["east_err_m"].sel(calibration=m)[-1]))}
               for m in methods}
    write_text(metrics_path, json.dumps(metrics, indent=2))
    return res


def load_calibration(nc_path):
    """TriadCalibration from a ``default_calibration.nc`` of the calibrate stage (body frame, counts); any other file
    is refused (:func:`calib.signal.plausibility.check_calibration_file`, whose read gives the vectors)."""
    vecs = plausibility.check_calibration_file(nc_path)
    return navigation.TriadCalibration(TriadModel.from_vector(vecs["accel"], "g", "count s-1"),
                                       TriadModel.from_vector(vecs["gyro"], "deg h-1", "count s-1"))


def check_navigation_inputs(recording_path, calibration_nc):
    """What can be refused before a sample is read: the calibration file's kind, and the recording's units against
    the calibration given (raw counts need one, physical units take none; :func:`calib.nav.navigation.check_units`).
    ``calib navigate`` asks this first: a wrong pairing is named at once, not after the full check of a long
    recording's samples. Returns ``(header, calibration or None)``, for :func:`navigate_file` (``inputs=``)."""
    cal = load_calibration(calibration_nc) if calibration_nc else None
    h = read_header(recording_path)
    require_sensors(h)   # a partial record (one triad): the navigation needs both, the missing one named
    navigation.check_units(h, cal)
    return h, cal


def navigate_file(recording_path, calibration_nc, out_nc, nav: dict, prov=None, init="attrs", log=print,
                  inputs=None):
    """Navigate one recording (streamed, progress in the log) and write the labelled error dataset.
    ``inputs``: :func:`check_navigation_inputs` of these two files when the caller has it (the header and the
    calibration are then not read again)."""

    h, cal = inputs if inputs is not None else check_navigation_inputs(recording_path, calibration_nc)
    bar = Progress(h.n_samples, f"navigating {Path(recording_path).name}")
    ds = navigation.navigate_recording(recording_path, calibration=cal, init=init, nav_rate_hz=nav["nav_rate_hz"],
                                       output_interval_s=nav["output_interval_s"], progress=lambda d, n: bar(d),
                                       header=h)
    # a non-finite solution is refused (exit 3) before it could replace an earlier output
    plausibility.check_finite_result(ds, out_nc, "check the calibration and the recording's units; the navigation "
                                     "rate is navigation.nav_rate_hz (calib navigate --nav-rate)")
    write_netcdf(ds, out_nc, prov)
    log(f"final errors: vE {float(ds['vE_err'][-1]):.4f} m/s, vN {float(ds['vN_err'][-1]):.4f} m/s, "
        f"lat {float(ds['lat_err_arcmin'][-1]):.3f}', lon {float(ds['lon_err_arcmin'][-1]):.3f}'")
    return ds
