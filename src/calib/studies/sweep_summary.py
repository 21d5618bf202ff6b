"""Gathering a parameter sweep: all points into one labelled netCDF, a CSV of the scalar results per point,
and the summary figure (heat maps over the budget axes). The points themselves: :mod:`calib.studies.sweeps`.
"""
from __future__ import annotations

import json

import numpy as np
import xarray as xr

from calib.figures import style as figures
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
    summary_figure(ds, kind, name, columns, fig)
    if metrics_path:
        m = {k: {"min": float(np.nanmin(ds[k].values)), "max": float(np.nanmax(ds[k].values))} for k in SUMMARY[kind]}
        m["points"] = len(values)
        write_text(metrics_path, json.dumps(m, indent=2))
    return ds


def _reduce(da, keep):
    """Mean over every dimension not in ``keep``; returns the array and the names averaged over."""
    over = [d for d in da.dims if d not in keep]
    return (da.mean(over) if over else da), over


def summary_figure(ds, kind, name, columns, path):
    """Heat maps of the summary metrics over the two budget axes (NP x EG, particles x generations), one
    column per value of the first other swept parameter (noise level, window, ...), averaged over the rest
    (seeds); a line plot when fewer than two budget axes are swept."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm, Normalize

    if kind == "calibration":
        y, x = "NP", "EG"
        metrics = [("success_pct", "success [%]", "viridis", None),
                   ("mean_L_over_L_star", "mean L / L*", "magma_r", "log")]
    else:
        y, x = "particles", "generations"
        metrics = [("rms_optimizer_error_in_bounds", "rms (estimate − argmin J) / CRB", "magma_r", "log"),
                   ("rms_error_in_bounds", "rms (estimate − truth) / CRB", "magma_r", "log")]
    axes2 = [c for c in (y, x) if c in columns]
    others = [c for c in columns if c not in axes2 and c != "seed"]
    facet = others[0] if others else None
    fvals = list(ds[facet].values) if facet else [None]
    nrow, ncol = len(metrics), len(fvals)
    fig, axs = plt.subplots(nrow, ncol, figsize=(3.4 * ncol + 1.0, 2.9 * nrow), squeeze=False, layout="constrained")
    averaged = set()
    for i, (var, label, cmap, scale) in enumerate(metrics):
        if len(axes2) == 2:  # one colour scale per metric, shared by the columns
            red_all = [_reduce(ds[var] if fv is None else ds[var].sel({facet: fv}), axes2)[0].values for fv in fvals]
            zs = np.concatenate([r.ravel() for r in red_all])
            zs = zs[np.isfinite(zs)]
            pos = zs[zs > 0]
            if scale == "log" and pos.size and pos.min() < pos.max():
                norm = LogNorm(vmin=pos.min(), vmax=pos.max())
            elif zs.size and zs.min() < zs.max():
                norm = Normalize(vmin=zs.min(), vmax=zs.max())
            else:
                norm = None
        for j, fv in enumerate(fvals):
            ax = axs[i, j]
            da = ds[var] if fv is None else ds[var].sel({facet: fv})
            if len(axes2) == 2:
                red, over = _reduce(da, axes2)
                averaged.update(over)
                z = red.transpose(y, x).values
                im = ax.imshow(z, origin="lower", aspect="auto", cmap=cmap, norm=norm)
                ax.set_xticks(range(ds.sizes[x]), [str(v) for v in ds[x].values])
                ax.set_yticks(range(ds.sizes[y]), [str(v) for v in ds[y].values])
                for (r, c), val in np.ndenumerate(z):
                    ax.text(c, r, f"{val:.3g}", ha="center", va="center", fontsize=7, color="w",
                            bbox={"facecolor": "k", "alpha": 0.25, "pad": 0.5, "lw": 0})
                ax.set_xlabel(x)
                ax.set_ylabel(y)
                if j == ncol - 1:
                    fig.colorbar(im, ax=axs[i, :].tolist(), label=label, shrink=0.85)
                ax.grid(False)
            else:
                lead = axes2[0] if axes2 else columns[0]
                red, over = _reduce(da, [lead])
                averaged.update(over)
                ax.plot([str(v) for v in red[lead].values], red.values, "o-")
                ax.set_xlabel(lead)
                ax.set_ylabel(label)
                if scale == "log":
                    ax.set_yscale("log")
            if fv is not None:
                ax.set_title(f"{facet} = {fv}", fontsize=8)
    note = f" (mean over {', '.join(sorted(averaged))})" if averaged else ""
    fig.suptitle(f"sweep {name}{note}", fontsize=9)
    figures.save(fig, path)
