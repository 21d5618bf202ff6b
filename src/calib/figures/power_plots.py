"""The detection-power figure of the mismatch diagnosis's proof: the fraction of seeds in which each injected
effect is named against its magnitude (:func:`calib.studies.diagnosis_stage.proof_stage`)."""
from __future__ import annotations

import numpy as np

from calib.figures import style


def detection_power(power: dict, path):
    """Detection rate against the injected magnitude (as a fraction of the proof magnitude), one line per
    effect, the 80 % line and the binomial standard error of each point. ``power``: {effect: {"points":
    [{"scale", "detected", "n"}, ...]}}, the proof's power table (:mod:`calib.studies.diagnosis_proof`); an empty
    one gives a figure that says no scan was run. Saved to ``path``."""
    plt = style.plt
    fig, ax = plt.subplots(figsize=(8, 5))
    for i, (nm, p) in enumerate(power.items()):
        pts = sorted(p["points"], key=lambda q: q["scale"])
        if not pts:
            continue
        x = np.array([q["scale"] for q in pts])
        r = np.array([q["detected"] / q["n"] for q in pts])
        se = np.sqrt(r * (1 - r) / np.array([q["n"] for q in pts]))
        ax.errorbar(x, r, yerr=se, marker="o", ms=4, capsize=2, lw=1, label=nm,
                    color=f"C{i % 10}", ls="-" if i < 10 else "--")
    if not power:
        ax.set_axis_off()
        ax.text(0.5, 0.5, "no detection-power scan in this run (diagnosis.proof.power_seeds: 0)",
                ha="center", va="center", transform=ax.transAxes)
        return style.save(fig, path)
    ax.axhline(0.8, color="k", lw=0.8, ls=":")
    ax.set_xscale("log")
    style.plain_log_ticks(ax, "x")
    ax.set_ylim(-0.03, 1.03)
    ax.set_xlabel("injected magnitude / proof magnitude")
    ax.set_ylabel("fraction of seeds in which the effect is named")
    ax.set_title("Detection power of the mismatch diagnosis (dotted: 80 %)")
    ax.legend(fontsize=7, loc="lower right", ncol=2)
    fig.tight_layout()
    return style.save(fig, path)
