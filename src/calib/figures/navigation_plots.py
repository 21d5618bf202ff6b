"""The figure of the static navigation check (Liu et al. 2021, Fig. 10), drawn from the check's navigation errors
(:func:`calib.studies.navigation_stage.run_static_check`)."""
from __future__ import annotations

import numpy as np

from calib.figures import style

PANELS = (("vE_err", "east velocity error [m/s]"), ("vN_err", "north velocity error [m/s]"),
          ("lat_err_arcmin", "latitude error [′]"), ("lon_err_arcmin", "longitude error [′]"))


def static_check(res, path):
    """East/north velocity and latitude/longitude errors over time, one line per calibration of ``res`` (a dataset
    with dimension ``calibration`` and the variables of :data:`PANELS`, time in s). Where another calibration's
    errors exceed the default calibration's twenty-fold, the panel is linear within 1.2 times the default's largest
    error and logarithmic beyond, so the default's curve stays readable. Saved to ``path``."""
    plt = style.plt
    fig, axs = plt.subplots(2, 2, figsize=(9, 6), sharex=True)
    t = res["time"].values / 3600.0
    names = [str(m) for m in res["calibration"].values]
    for ax, (v, lab) in zip(axs.flat, PANELS):
        for m in names:
            ax.plot(t, res[v].sel(calibration=m).values, lw=1.4 if m == "default" else 0.9, label=m,
                    zorder=3 if m == "default" else 2)
        if "default" in names:   # keep the default calibration's curve readable beside much larger ones
            d = float(np.nanmax(np.abs(res[v].sel(calibration="default").values)))
            if d > 0 and float(np.nanmax(np.abs(res[v].values))) > 20 * d:
                ax.set_yscale("symlog", linthresh=1.2 * d)
                lab += "\n(linear within ±" + f"{1.2 * d:.2g}, log beyond)"
        ax.set_ylabel(lab)
    for ax in axs[-1]:
        ax.set_xlabel("time [h]")
    axs[0, 0].legend(fontsize=7)
    fig.suptitle("Liu et al. (2021) Fig. 10: static navigation with each method's calibration (true initial state)")
    fig.tight_layout()
    return style.save(fig, path)
