"""The figure of the IEEE Std 952 noise terms of a static record (``calib noise``): per sensor and axis the
measured Allan deviation with its confidence band, the fitted model and each fitted term's line, drawn from the
plain data of :func:`calib.signal.ieee952.figure_data`."""
from __future__ import annotations

import numpy as np

from calib.figures import style

#: colour, line style and legend entry of each term's line
TERM_STYLES = {"Q": ("tab:purple", (0, (1, 1)), "Q (slope -1)"), "N": ("tab:blue", "--", "N (slope -1/2)"),
               "B": ("tab:green", "-.", "B (flat)"), "K": ("tab:red", (0, (5, 1, 1, 1)), "K (slope +1/2)")}


def _term_label(t: str, T: dict, col: int) -> str:
    """``t = value [lo, hi]`` for a resolved term, ``t < upper bound`` (and the raw fit, when not zero) otherwise."""
    v, hi = T["value"][col], T["hi"][col]
    if T["resolved"][col]:
        return f"{t} = {v:.4g} [{T['lo'][col]:.4g}, {hi:.4g}]"
    return f"{t} < {hi:.3g}" + (f" (fit {v:.3g})" if v > 0 else "")


def noise_terms(panels: list, title: str = ""):
    """Log-log figure: one row per sensor of ``panels`` (:func:`calib.signal.ieee952.figure_data`), one column per
    axis; measured ADEV with its confidence band, the fitted model and each fitted term's line, the terms' values
    in a box. Returns the matplotlib figure (save it with :func:`calib.figures.style.save`)."""
    plt = style.plt
    naxes = max(len(d["axes"]) for d in panels)
    fig, axs = plt.subplots(len(panels), naxes, figsize=(3.3 * naxes, 2.9 * len(panels)), squeeze=False,
                            sharex=True)
    for row, d in enumerate(panels):
        tau, adev, tt = d["tau"], d["adev"], d["tau_model"]
        for col in range(naxes):
            ax = axs[row, col]
            if col >= len(d["axes"]):
                ax.set_visible(False)
                continue
            ax.fill_between(tau, d["band_lo"][:, col], d["band_hi"][:, col], color="0.8", lw=0,
                            label=f"{100 * d['confidence']:g} % band")
            ax.loglog(tau, adev[:, col], "o-", color="k", ms=3, lw=1.0, label="measured ADEV")
            ax.loglog(tt, d["model"][:, col], "-", color="tab:orange", lw=1.2, label="fitted model")
            for t, T in d["terms"].items():
                if T["drawn"][col]:
                    c, ls, lab = TERM_STYLES[t]
                    ax.loglog(tt, T["adev"][:, col], color=c, ls=ls, lw=1.0, label=lab)
            lo_y = max(float(np.min(d["band_lo"][:, col])) / 3.0, 1e-300)
            # headroom above the curve for the values; the long-tau band may run off the top
            ax.set_ylim(lo_y, float(np.max(adev[:, col])) * 40.0)
            txt = "\n".join(_term_label(t, T, col) for t, T in d["terms"].items())
            ax.text(0.97, 0.97, txt, transform=ax.transAxes, fontsize=6.5, va="top", ha="right",
                    bbox={"fc": "white", "ec": "0.7", "alpha": 0.9, "lw": 0.5})
            ax.set_title(f"{d['sensor']} {d['axes'][col]}", fontsize=9)
            ax.set_ylabel(f"Allan deviation [{d['unit']}]")
            if row == len(panels) - 1:
                ax.set_xlabel("averaging time \u03c4 [s]")
    handles = {}
    for ax in axs.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    fig.legend(list(handles.values()), list(handles.keys()), loc="lower center", ncol=min(7, len(handles)),
               fontsize=7, frameon=False)
    if title:
        fig.suptitle(title, fontsize=9)
    h = fig.get_figheight()   # fixed margins (inches): tight_layout costs seconds on log axes
    fig.subplots_adjust(left=0.75 / fig.get_figwidth(), right=0.99, bottom=0.85 / h, top=1 - 0.6 / h,
                        wspace=0.32, hspace=0.28 * 2.9 / max(h / len(panels), 1e-9))
    return fig
