"""The figure of the real-recording proof (:mod:`calib.studies.real_proof`): the detection power curves of the
library terms on each shared recording, drawn from the stage's plain results (dicts of numbers and strings, the
limits as :func:`calib.studies.real_proof.reported_result` gives them)."""
from __future__ import annotations

from calib.figures import style

#: legend names of the reported size parameters (any other: the part of its name before the first underscore,
#: ``k2_ug_per_g2`` -> ``k2``)
SHORT = {"scale_factor_asymmetry_ppm": "SF asymmetry"}


def _short(parameter: str) -> str:
    name = parameter.split("[")[0]
    return SHORT.get(name, name.split("_")[0])


def limits_figure(results, path):
    """Power curves of the library terms on each usable recording: fraction named against the injected magnitude
    in baseline standard errors."""
    plt = style.plt
    use = [r for r in results if any(L.get("points") and L["kind"] == "library" for L in r.get("limits", []))]
    n = max(1, len(use))
    fig, axes = plt.subplots(1, n, figsize=(3.2 * n + 0.6, 3.0), squeeze=False, sharey=True)
    for ax, r in zip(axes[0], use):
        for j, L in enumerate(q for q in r["limits"] if q["kind"] == "library" and q.get("points")):
            x = [p["multiple_of_se"] for p in L["points"]]
            y = [p["rate"] for p in L["points"]]
            ax.plot(x, y, marker="o", ms=3, lw=1, color=f"C{j % 10}",
                    label=f"{_short(L['parameter'])} {L['axis']}" if ax is axes[0][0] else None)
        ax.axhline(0.95, color="k", lw=0.8, ls=":")
        ax.set_xscale("log")
        style.plain_log_ticks(ax, "x")
        ax.set_title(r["recording"], fontsize=9)
        ax.set_xlabel("injected / baseline se")
    axes[0][0].set_ylabel("fraction named")
    if use:
        axes[0][0].legend(fontsize=6, loc="lower right")
    fig.tight_layout()
    return style.save(fig, path)
