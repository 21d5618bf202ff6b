"""Gathering a parameter sweep: all points into one labelled netCDF, a CSV of the scalar results per point,
and the summary figure (heat maps over the budget axes, :func:`calib.figures.sweep_plots.summary`). The points
themselves: :mod:`calib.studies.sweeps`.
"""
from __future__ import annotations

import json

import numpy as np
import xarray as xr

from calib.figures import sweep_plots
from calib.io.atomic import write_text
from calib.io.netcdf import write_netcdf
from calib.studies.sweeps import SweepError

SUMMARY = {"calibration": ("success_pct", "mean_L_over_L_star", "mean_L", "L_star"),
           "drift_pso": ("rms_optimizer_error_in_bounds", "rms_error_in_bounds", "mean_J_excess")}


def gather(kind: str, name: str, paths, values: list[dict], columns: list[str], out_nc, out_csv, fig,
           metrics_path=None, attrs=None, prov=None):
    """All points into one netCDF with the swept parameters as dimensions (grid order), a CSV of the
    scalar results per point, and the summary figure."""
    if len(paths) != len(values):
        raise SweepError(f"sweep {name}: {len(paths)} point files for {len(values)} points")
    dss = []
    for p, v in zip(paths, values):
        with xr.open_dataset(p, engine="netcdf4") as d:
            ds = d.load()
        ds.attrs = {}
        dss.append(ds)
    ds = xr.concat(dss, dim="point", join="outer", fill_value=np.nan, coords="minimal", compat="override",
                   combine_attrs="drop")
    ds = ds.assign_coords({c: ("point", [v[c] for v in values]) for c in columns})
    if len(columns) == 1:  # a single swept parameter: it becomes the dimension itself
        ds = ds.swap_dims({"point": columns[0]})
    else:
        ds = ds.set_index(point=columns).unstack("point")
    ds = ds.transpose(*columns, ...)
    for c in columns:
        ds[c].attrs["long_name"] = f"swept: {c}"
    ds.attrs.update({"sweep": name, "kind": kind, "swept": json.dumps(columns), **(attrs or {})})

    write_netcdf(ds, out_nc, prov)
    rows = [",".join(columns + list(SUMMARY[kind]))]
    for p, v in zip(dss, values):
        rows.append(",".join([str(v[c]) for c in columns] + [f"{float(p[k]):.6g}" for k in SUMMARY[kind]]))
    write_text(out_csv, "\n".join(rows) + "\n")
    sweep_plots.summary(ds, kind, name, columns, fig)
    if metrics_path:
        m = {k: {"min": float(np.nanmin(ds[k].values)), "max": float(np.nanmax(ds[k].values))} for k in SUMMARY[kind]}
        m["points"] = len(values)
        write_text(metrics_path, json.dumps(m, indent=2))
    return ds
