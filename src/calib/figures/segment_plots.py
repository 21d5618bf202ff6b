"""Figures of static segments over a recording's signal: the intervals a field calibration used
(:func:`calib.studies.realdata.calibrate`) and the intervals of the static detection with its variance statistics
and thresholds (:func:`calib.signal.detect.detect_static`)."""
from __future__ import annotations

import math

import numpy as np

from calib.figures import style


def static_intervals(ds, iv, rule, path):
    """Accelerometer and gyro magnitude over time of the recording ``ds`` (``calib-recording-1``) with the static
    intervals ``iv`` ((m, 2) ``[start, stop)`` sample indices) shaded; ``rule``: how they were found, in the title.
    Saved to ``path``."""
    plt = style.plt
    fs = float(ds.attrs["sample_rate_hz"])
    t = np.arange(ds.sizes["time"]) / fs
    fig, axs = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    for ax, var in zip(axs, ("accel", "gyro")):
        ax.plot(t, np.linalg.norm(ds[var].values.astype(float), axis=1), lw=0.5, color="k")
        for a, b in iv:
            ax.axvspan(a / fs, b / fs, color="C2", alpha=0.25, lw=0)
        ax.set_ylabel(f"|{var}| [{ds[var].attrs['units']}]")
    axs[-1].set_xlabel("time [s]")
    axs[0].set_title(f"{ds.attrs.get('sensor', '')}: {len(iv)} static intervals ({rule})"[:110], fontsize=8)
    fig.tight_layout()
    return style.save(fig, path)


def static_detection(accel, gyro, fs: float, detection, path, *, title: str = "",
                     accel_units: str = "", gyro_units: str = "", max_points: int = 8000):
    """Figure of the static intervals found by :func:`calib.signal.detect.detect_static` (``detection``, a
    :class:`~calib.signal.detect.StaticDetection`) over the signal; written deterministically via
    :func:`calib.figures.style.save`.

    Panels: accel axes, gyro axes (both with the static intervals shaded), and the variance magnitudes with
    their thresholds (log scale). Long records are drawn as the min/max envelope of buckets, about
    ``max_points`` points per line (the intervals are drawn exactly). Returns the path written.
    """
    plt = style.plt
    accel = np.asarray(accel, dtype=np.float64)
    gyro = np.asarray(gyro, dtype=np.float64)
    n = accel.shape[0]
    step = max(1, int(math.ceil(2 * n / max_points)))

    def env(y):
        """(t, y) thinned to the min and max of each bucket of ``step`` samples (spikes survive)."""
        if step == 1:
            return np.arange(n) / fs, y
        m = n // step
        b = y[:m * step].reshape(m, step)
        tt = (np.arange(m) * step + step / 2) / fs
        return np.repeat(tt, 2), np.column_stack([b.min(axis=1), b.max(axis=1)]).ravel()

    fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for ax, data, name, u in ((axs[0], accel, "accel", accel_units), (axs[1], gyro, "gyro", gyro_units)):
        for j, c in enumerate("xyz"):
            ax.plot(*env(data[:, j]), lw=0.6, label=c)
        ax.set_ylabel(f"{name} [{u}]" if u else name)
        ax.legend(loc="upper right", fontsize=7, ncol=3)
    axs[2].semilogy(*env(np.maximum(detection.stat_accel, 1e-300)), lw=0.6, label="accel variance magnitude")
    axs[2].axhline(detection.threshold, color="C0", ls="--", lw=0.8, label="accel threshold")
    if detection.stat_gyro is not None:
        axs[2].semilogy(*env(np.maximum(detection.stat_gyro, 1e-300)), lw=0.6, color="C1",
                        label="gyro variance magnitude")
        axs[2].axhline(detection.gyro_threshold, color="C1", ls="--", lw=0.8, label="gyro threshold")
    axs[2].legend(loc="upper right", fontsize=7)
    axs[2].set_ylabel("variance magnitude")
    axs[2].set_xlabel("time from start [s]")
    for ax in axs:
        for a, b in detection.intervals:
            ax.axvspan(a / fs, b / fs, color="0.85", zorder=0, lw=0)
    head = f"{detection.count} static intervals (window {detection.window}, min {detection.min_samples} samples)"
    fig.suptitle(f"{title}\n{head}" if title else head, fontsize=9)
    fig.tight_layout()
    return style.save(fig, path)
