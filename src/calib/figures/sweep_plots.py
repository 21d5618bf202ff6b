"""The summary figure of a parameter sweep: heat maps of its metrics over the two budget axes, drawn from the
gathered sweep (:func:`calib.studies.sweep_summary.gather`)."""
from __future__ import annotations

import numpy as np
from matplotlib.colors import LogNorm, Normalize

from calib.figures import style


def _reduce(da, keep):
    """Mean over every dimension not in ``keep``; returns the array and the names averaged over."""
    over = [d for d in da.dims if d not in keep]
    return (da.mean(over) if over else da), over


def summary(ds, kind, name, columns, path):
    """Heat maps of the summary metrics over the two budget axes (NP x EG, particles x generations), one
    column per value of the first other swept parameter (noise level, window, ...), averaged over the rest
    (seeds); a line plot when fewer than two budget axes are swept."""
    plt = style.plt
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
    return style.save(fig, path)
