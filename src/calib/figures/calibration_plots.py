"""The figures of the calibration study (Liu et al. 2021): the Allan deviation of the static positions, the
objective's convergence over the generations of each method's runs, and the z-scores of the default calibration
over simulated sessions. Drawn from the numbers :mod:`calib.studies.calibration` computes."""
from __future__ import annotations

import numpy as np

from calib.figures import style


def noise_allan(panels, path):
    """Allan deviation pooled over the static positions, one panel per sensor, each axis with its 95 % interval.
    ``panels``: ``(sensor, tau, adev, lo, hi, unit)`` per sensor, the arrays (n_tau, n_axes) of at most three
    axes. Saved to ``path``."""
    plt = style.plt
    fig, axs = plt.subplots(1, 2, figsize=(9, 3.5))
    for ax, (sensor, tau, ad, lo, hi, unit) in zip(axs, panels):
        for j in range(ad.shape[1]):
            ax.loglog(tau, ad[:, j], "o-", ms=3, label="xyz"[j])
            ax.fill_between(tau, lo[:, j], hi[:, j], alpha=0.2)
        ax.set_xlabel("τ [s]")
        ax.set_ylabel(f"Allan deviation [{unit}]")
        ax.set_title(f"{sensor}: pooled over the static positions")
        ax.legend(fontsize=7)
    fig.tight_layout()
    return style.save(fig, path)


def convergence(hist, title, ylabel, path):
    """The objective per generation, one line per run (``hist``: runs x generations); a log axis where the values
    span a decade or more. Saved to ``path``."""
    plt = style.plt
    fig, ax = plt.subplots(figsize=(6, 3.6))
    g = np.arange(hist.shape[1])
    for i, h in enumerate(hist):
        ax.plot(g, h, lw=0.7, label=f"one line per run ({len(hist)} runs)" if i == 0 else "_nolegend_")
    style.auto_log(ax, hist)
    ax.set_xlabel("generation")
    ax.set_ylabel(ylabel)
    ax.set_title(title + f" ({len(hist)} runs)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return style.save(fig, path)


def z_scores(stats, names, main: str, n_seeds: int, path):
    """Mean and standard deviation over the seeds of z = (estimate - truth) / standard error, per parameter, one
    panel per sensor, the band |z| <= 1 shaded. ``stats``: ``{"with" | "segment": {"accel" | "gyro": (mean, std or
    None)}}``, arrays over the parameters; ``names``: the parameter names per sensor; ``main``: the key of the
    standard errors reported (``"with"``: with a long static record, drawn beside the segment-only ones);
    ``n_seeds``: the number of simulated sessions. Saved to ``path``."""
    plt = style.plt
    fig, axs = plt.subplots(1, 2, figsize=(10, 3.5), sharey=True)
    for ax, (sensor, title) in zip(axs, (("accel", "accel (9-parameter norm form)"), ("gyro", "gyro (eq. 25)"))):
        x = np.arange(len(names[sensor]))
        if main == "with":
            mean, sd = stats["segment"][sensor]
            ax.errorbar(x - 0.15, mean, yerr=sd, fmt="s", color="0.6", label="segment-only sigma")
        mean, sd = stats[main][sensor]
        ax.errorbar(x + (0.15 if main == "with" else 0.0), mean, yerr=sd, fmt="o", color="C0",
                    label="with long static record" if main == "with" else "segment-only sigma")
        ax.axhspan(-1, 1, color="C2", alpha=0.15)
        ax.set_xticks(x, names[sensor], rotation=60, fontsize=7)
        ax.set_xlabel("parameter")
        ax.set_title(title)
        ax.legend(fontsize=7)
    axs[0].set_ylabel("z = (estimate − truth) / SE: mean ± std")
    fig.suptitle(f"Standard errors against the truth over {n_seeds} simulated sessions")
    fig.tight_layout()
    return style.save(fig, path)
