"""Which static intervals and samples a field calibration uses: IMU-TK's threshold search, mikoff's standstill
rule."""
from __future__ import annotations


import numpy as np

from calib.signal import detect
from calib.fieldcal.accelerometer import fit_accel_norm
from calib.fieldcal.results import IMU_TK_DEFAULTS, MIN_INTERVALS

# =========================================================================== reference selection rules


def imu_tk_intervals(accel, fs: float, k: float, *, init_samples: int = 5000, window: int = 101,
                     samples_per_interval: int = 100, stat=None) -> np.ndarray:
    """Static intervals as IMU-TK selects them (accelerometer only).

    Threshold ``k`` x the variance magnitude of samples ``[0, init_samples]`` (inclusive, as IMU-TK's
    ``DataInterval(0, n_init)``); centred window of ``window`` samples; IMU-TK scans only the samples with a
    full window, so an interval starts no earlier than ``window // 2`` and one still open at the end stops at
    ``n - window // 2 - 1``; intervals with ``stop - start < samples_per_interval`` are dropped. Returns
    ``[start, stop)`` pairs (``stop`` = IMU-TK's ``end_idx``, the first non-static sample). ``stat``: the
    accel's :func:`calib.signal.detect.moving_variance_norm` with ``window``, when the caller has it already.
    """
    accel = np.asarray(accel, dtype=np.float64)
    n = len(accel)
    h = window // 2
    thr = k * detect.variance_norm(accel[:init_samples + 1])
    s = detect.moving_variance_norm(accel, window) if stat is None else stat
    iv = detect.runs(s < thr)
    if len(iv) == 0:
        return iv
    iv[:, 0] = np.maximum(iv[:, 0], h)
    iv[:, 1] = np.minimum(iv[:, 1], n - h - 1)
    return iv[(iv[:, 1] - iv[:, 0]) >= samples_per_interval]


def imu_tk_accel_search(accel, fs: float, gravity: float, *, k=None, init_samples: int = 5000, window: int = 101,
                        samples_per_interval: int = 100, min_intervals: int = 12, **fit_kwargs):
    """IMU-TK's accelerometer procedure: for each threshold multiplier in ``k`` (default 2..10), intervals by
    :func:`imu_tk_intervals`, a norm fit on the first ``samples_per_interval`` samples of each (skipped when
    fewer than ``min_intervals``); keeps the multiplier with the smallest final cost (1/2 SSR).

    Returns ``(fit, k_chosen, intervals, table)``; ``table`` lists (k, n_intervals, cost, rms) per multiplier.
    """
    ks = IMU_TK_DEFAULTS["k"] if k is None else ([k] if np.ndim(k) == 0 else list(k))
    best, table = None, []
    for kk in ks:
        iv = imu_tk_intervals(accel, fs, kk, init_samples=init_samples, window=window,
                              samples_per_interval=samples_per_interval)
        if len(iv) < min_intervals:
            table.append((kk, len(iv), None, None))
            continue
        fit = fit_accel_norm(accel, iv, gravity, samples_per_interval=samples_per_interval,
                             min_intervals=min(min_intervals, MIN_INTERVALS), **fit_kwargs)
        cost = 0.5 * fit.residual_rms ** 2 * fit.n_residuals
        table.append((kk, len(iv), cost, fit.residual_rms))
        if best is None or cost < best[0]:
            best = (cost, fit, kk, iv)
    if best is None:
        raise detect.StaticDetectionError(
            f"IMU-TK rule: no threshold multiplier in {ks} gives {min_intervals} intervals of "
            f"{samples_per_interval} samples (found {[t[1] for t in table]}) -- fix: larger multipliers, a "
            "longer initial rest (init_samples) or more static positions")
    return best[1], best[2], best[3], table


def mikoff_standstill(gyro_rad_s, threshold: float = 0.13, guard: int = 60) -> np.ndarray:
    """Standstill flags as mikoff/imu-calib's ``generate_standstill_flags`` sets them (reimplemented).

    A sample is quiet when ``|w| < threshold`` [rad s-1]. It is a standstill sample when it is quiet, more than
    ``guard`` samples have passed since the last non-quiet sample (none before counts as passed), and no
    non-quiet sample with index >= ``guard`` follows within ``guard`` samples (the tool clears the ``guard``
    samples before each motion; its slice does nothing for motions earlier than ``guard``).
    """
    w = np.asarray(gyro_rad_s, dtype=float)
    n = len(w)
    motion = ~(np.linalg.norm(w, axis=1) < threshold)
    idx = np.arange(n)
    last = np.maximum.accumulate(np.where(motion, idx, -1))
    ok_after = (last < 0) | (idx - last > guard)
    mot_late = motion & (idx >= guard)
    nxt = np.where(mot_late, idx, n + 10 * guard)
    nxt = np.minimum.accumulate(nxt[::-1])[::-1]
    # the next late motion strictly after i
    nxt_after = np.concatenate([nxt[1:], [n + 10 * guard]])
    ok_before = (nxt_after - idx) > guard
    return (~motion) & ok_after & ok_before
