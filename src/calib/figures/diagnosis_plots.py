"""The figures of ``calib diagnose`` drawn from plain data (arrays, strings): standardised residuals per segment
before and after the selected terms, and the Allan deviation of the static segments.

The data come from :mod:`calib.diagnosis.report` (``residual_data``, ``allan_data``); here only numpy and
matplotlib are needed (the figures layer sits below the diagnosis).
"""
from __future__ import annotations

import numpy as np

from calib.figures import style

AXES = ("x", "y", "z")


def residual(d: dict):
    """Standardised residuals (residual / sigma) per segment before and after, per sensor axis and row. Where no
    term was selected the two are the same numbers: one series per axis then, titled as the base model's."""
    plt = style.plt
    sensor, row, axis, window = (np.asarray(d[k]) for k in ("sensor", "row", "axis", "window"))
    before, after, sig = (np.asarray(d[k], float) for k in ("before", "after", "sigma"))
    same = np.array_equal(before, after, equal_nan=True)
    labels = list(d["labels"])
    rows = sorted({(si, r) for si, r in zip(sensor.tolist(), row.tolist())})
    fig, axs = plt.subplots(len(rows), 1, figsize=(10, 2.2 * len(rows)), sharex=True, squeeze=False)
    for ax, (si, r) in zip(axs[:, 0], rows):
        for a, col in zip(range(3), ("C0", "C1", "C2")):
            m = (sensor == si) & (row == r) & (axis == a)
            if not m.any():   # e.g. the norm model: one series, not three under an x/y/z legend
                continue
            x = window[m] + (a - 1) * 0.22
            first = (si, r) == rows[0]
            name = "norm" if d["kind"] == "norm" else AXES[a]
            if same:
                ax.plot(x, after[m] / sig[m], ".", color=col, ms=5, label=name if first else None)
                continue
            ax.plot(x, before[m] / sig[m], "o", mfc="none", color=col, ms=4,
                    label=f"{name} before" if first else None)
            ax.plot(x, after[m] / sig[m], ".", color=col, ms=5, label=f"{name} after" if first else None)
        for j, (uname, idx) in enumerate(d.get("unexplained") or ()):
            idx = np.asarray(idx, int)
            m = np.zeros(sensor.size, bool)
            m[idx] = True
            m &= (sensor == si) & (row == r)
            if m.any():   # where an unexplained misfit sits: the final model's residuals of that subset, ringed
                ax.plot(window[m] + (axis[m] - 1) * 0.22, after[m] / sig[m], "o", mfc="none", mec="C3",
                        ms=9 + 3 * j, mew=1.0, label=f"unexplained misfit: {uname}")
        ax.axhline(0, color="k", lw=0.5)
        for k in (-3, 3):
            ax.axhline(k, color="k", lw=0.5, ls=":")
        name = "norm residual" if d["kind"] == "norm" else f"{d['sensors'][si]} {d['row_names'][r]}"
        ax.set_ylabel(f"{name}\n(residual / sigma)")
    for ax in axs[:, 0]:
        if ax.get_legend_handles_labels()[1]:
            ax.legend(ncol=3 if same else 6, fontsize=7, loc="upper right")
    step = max(1, int(np.ceil(len(labels) / 40)))          # at most ~40 readable tick labels
    ticks = list(range(0, len(labels), step))
    axs[-1, 0].set_xticks(ticks)
    axs[-1, 0].set_xticklabels([labels[i] for i in ticks], rotation=90, fontsize=7)
    axs[-1, 0].set_xlabel("segment" + (f" (every {style.ordinal(step)} labelled)" if step > 1 else ""))
    title = d["title"] or ("residuals of the base model (no term selected)" if same else
                           "residuals before (open) and after (filled) the selected terms")
    fig.suptitle(title)
    longest = max((len(str(labels[i])) for i in ticks), default=0)
    # inches: two-line y label and tick numbers; suptitle; rotated 7 pt labels (~0.06 in a character) and x label
    style.fixed_margins(fig, left=0.95, right=0.15, top=0.45, bottom=0.55 + 0.065 * longest, hspace=0.2)
    return fig


def allan(panels: list):
    """Allan deviation of the static segments per sensor, with its confidence band; ``panels``: one
    ``(sensor, dict(tau, adev, lo, hi, edf, unit, confidence))`` per sensor the diagnosis has (no blank panel);
    taus with fewer than 2 equivalent degrees of freedom are left out (their interval is wider than the plot)."""
    plt = style.plt
    fig, axs = plt.subplots(1, max(len(panels), 1), figsize=(5 * max(len(panels), 1), 4), squeeze=False)
    if not panels:
        axs[0, 0].axis("off")
        axs[0, 0].text(0.5, 0.5, "no static segments: no Allan deviation", ha="center", va="center")
    for ax, (s, A) in zip(axs[0], panels):
        tau, adev, lo, hi = (np.asarray(A[k], float) for k in ("tau", "adev", "lo", "hi"))
        keep = np.asarray(A["edf"]) >= 2.0
        ncol = adev.shape[1]
        for a in range(min(3, ncol)):
            line, = ax.loglog(tau[keep], adev[keep, a], "o-", ms=3, label=f"{AXES[a]}" if ncol > 1 else s)
            ax.fill_between(tau[keep], lo[keep, a], hi[keep, a], color=line.get_color(), alpha=0.15,
                            label=f"{int(round(100 * A['confidence']))} % interval" if a == 0 else "_nolegend_")
        ax.set_xlabel("tau [s]")
        ax.set_ylabel(f"Allan deviation [{A['unit']}]")
        # at the top edge, where matplotlib would place it (no tick labels above the panel), given rather than
        # found by measuring every y tick label of the panel once more before drawing
        ax.set_title(f"{s} (pooled static segments)", y=1.0)
        ax.legend()
        style.in_view_ticks(ax)
    # inches: log tick labels and y label; title; tick labels and x label; each panel's own y label between panels
    style.fixed_margins(fig, left=0.85, right=0.15, top=0.35, bottom=0.55, wspace=0.95)
    return fig


FIGURES = {"residual": residual, "allan": allan}
