"""The figures of the gyro-drift study (He et al. 2019): the drift estimated in each PSOBE test (Fig. 2), the
objective of the global best over the generations (Fig. 3), the navigation errors with and without compensation
(Fig. 4), the estimators' errors in Cramér–Rao bounds over noise seeds, and the drift of a real static recording.
Drawn from the numbers :mod:`calib.studies.drift` computes."""
from __future__ import annotations

import math

import numpy as np
from matplotlib.ticker import MaxNLocator

from calib.figures import style

AXES = ("x", "y", "z")


def estimates_per_test(path, est, truth, crb):
    """He et al. (2019) Fig. 2: each test's estimate (``est``: tests x 3, deg/h) against the reference ``truth``
    with the band of two Cramér–Rao bounds ``crb`` (deg/h; a non-finite bound draws no band)."""
    plt = style.plt
    fig, axs = plt.subplots(3, 1, figsize=(6.5, 6.5), sharex=True)
    k = np.arange(1, len(est) + 1)
    for i, ax in enumerate(axs):
        ax.plot(k, est[:, i], "o-", ms=3, lw=0.8, label="PSOBE estimate")
        ax.axhline(truth[i], color="k", lw=1, label="reference")
        if np.isfinite(crb[i]):
            ax.axhspan(truth[i] - 2 * crb[i], truth[i] + 2 * crb[i], color="C2", alpha=0.15, label="reference ± 2 CRB")
        ax.set_ylabel(f"ε_{AXES[i]} [°/h]")
    axs[0].legend(fontsize=7, loc="best")
    axs[-1].set_xlabel("test")
    axs[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.suptitle("He et al. (2019) Fig. 2: gyro drift estimated in each PSOBE test")
    fig.tight_layout()
    style.save(fig, path)


def convergence(path, hist, unit):
    """He et al. (2019) Fig. 3: the objective J (eq. 18) of the global best per generation of one test."""
    plt = style.plt
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(np.arange(len(hist)), hist, "o-", ms=3)
    style.auto_log(ax, hist)
    ax.set_xlabel("generation")
    ax.set_ylabel(f"J of eq. 18 (position in {unit})")
    ax.set_title("He et al. (2019) Fig. 3: J of the global best, test 1")
    fig.tight_layout()
    style.save(fig, path)


def navigation_errors(path, ds):
    """He et al. (2019) Fig. 4: the attitude, velocity and position errors of the first two streams of ``ds``
    (uncompensated and compensated by the PSOBE mean) over time."""
    plt = style.plt
    panels = [("pitch_err", "pitch [′]"), ("roll_err", "roll [′]"), ("yaw_err", "yaw [′]"),
              ("vE_err", "east velocity [m/s]"), ("vN_err", "north velocity [m/s]"),
              ("lon_err", "longitude [′]"), ("lat_err", "latitude [′]")]
    fig, axs = plt.subplots(4, 2, figsize=(9, 9), sharex=True)
    t = ds["time"].values / 3600.0
    for ax, (var, lab) in zip(axs.flat, panels):
        for s, color in zip(ds["stream"].values[:2], ("C0", "C3")):
            ax.plot(t, ds[var].sel(stream=s).values, color=color, lw=0.8,
                    label="without compensation" if s == "uncompensated" else "compensated (PSOBE mean)")
        ax.set_ylabel(lab)
    axs.flat[-1].axis("off")
    axs.flat[0].legend(fontsize=7)
    for ax in axs[-1]:
        ax.set_xlabel("time [h]")
    axs[2, 1].set_xlabel("time [h]")
    fig.suptitle("He et al. (2019) Fig. 4: navigation errors with and without drift compensation")
    fig.tight_layout()
    style.save(fig, path)


def noise_seed_z(path, z, names, n_seeds):
    """Histograms of each estimator's drift error in Cramér–Rao bounds (``z``: estimators x seeds x 3) against
    N(0, 1), one panel per axis. PSOBE is left out: its drift-only model is biased by the accelerometer bias (the
    study's table says by how much)."""
    plt = style.plt
    fig, axs = plt.subplots(1, 3, figsize=(9, 3), sharey=True)
    bins = np.linspace(-4, 4, 33)
    xs = np.linspace(-4, 4, 200)
    for j, ax in enumerate(axs):
        for i, m in enumerate(names):
            if m != "pso":
                ax.hist(z[i, :, j], bins=bins, density=True, alpha=0.5, label=m)
        ax.plot(xs, np.exp(-xs**2 / 2) / math.sqrt(2 * math.pi), "k", lw=1, label="N(0, 1)")
        ax.set_xlabel(f"z of ε_{AXES[j]}")
    axs[0].set_ylabel("probability density")
    axs[0].legend(fontsize=7)
    fig.suptitle(f"Drift error in Cramér–Rao bounds over {n_seeds} noise seeds")
    fig.tight_layout()
    style.save(fig, path)


def real_drift(path, ests, mean_gyro, band, win_s):
    """The PSOBE estimates of a real static recording (mean ± std over its tests, deg/h) beside the mean gyro
    output with its allowed band (Earth rate unknown + 2 Allan sigma)."""
    plt = style.plt
    fig, ax = plt.subplots(figsize=(6, 3.5))
    x = np.arange(3)
    ax.errorbar(x - 0.1, ests.mean(0), yerr=ests.std(0), fmt="o", label="PSOBE estimate (mean ± std over tests)")
    ax.errorbar(x + 0.1, mean_gyro, yerr=band, fmt="s", label="mean gyro output ± (Ω + 2σ)")
    ax.set_xticks(x, [f"ε_{a}" for a in AXES])
    ax.set_xlabel("gyro axis (body frame)")
    ax.set_ylabel("drift [°/h]")
    ax.legend(fontsize=7)
    ax.set_title(f"Real static recording, {win_s:.0f} s window")
    fig.tight_layout()
    style.save(fig, path)
