"""Throughput of the strapdown engine (a script that prints figures; not a unit test).

    python benchmarks/bench_navigation.py                      # kernel figures
    python benchmarks/bench_navigation.py --make-file F.nc --hours 240   # write a 100 Hz test recording
    python benchmarks/bench_navigation.py F.nc                 # + end-to-end navigate_recording(F.nc)
    python benchmarks/bench_navigation.py F.nc --skip-kernels --repeat 3 [--cold]   # end to end only, 3 runs

Figures (targets of the project brief in brackets):

* one stream, 100 Hz samples, navigation at 10 Hz (fused pre-integration + navigation): ns per sample [60]
* single-speed path, navigation at 100 Hz: ns per sample [100]
* 30 streams sharing pre-integrated 10 Hz increments: ns per 100 Hz sample per stream [10]
  (pre-integration, shared by all streams, is reported separately)
* scaling with duration and with the number of streams (three sizes each)
* end-to-end: reading + conversion + navigation of a recording, wall time and peak RSS [240 h in 5 s]
  (``--cold``: the file's pages are dropped from the page cache before each run, posix_fadvise DONTNEED on
  this file only, so the run reads from disk; without it the file is read as the page cache holds it)
* the yardstick: the fused navigation kernel against a minimal compiled loop over the same samples (six
  running sums per sample, the least a single-sample kernel does), timed in turn in the same run; their
  ratio is the kernel's cost in units of merely touching the samples

Every timing is the minimum over repeats (the machine is shared; medians are printed too).
"""
from __future__ import annotations

import argparse
import math
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

from calib.core import earth
from calib.nav import navigation
from calib.nav import reader
from calib.io import recording
from calib.nav import strapdown
from calib.nav.strapdown import NavInit
from calib.core.rotations import euler_to_dcm

LAT = math.radians(30.58)
ATT = (0.02, -0.01, 0.7)
DT = 0.01


def stationary_increments(n, rng):
    C = euler_to_dcm(*ATT)
    w = C.T @ earth.earth_rate_enu(LAT)
    f = C.T @ np.array([0.0, 0.0, float(earth.normal_gravity(LAT))])
    dth = np.tile(w * DT, (n, 1)) + rng.normal(0.0, 1e-7, (n, 3))
    dv = np.tile(f * DT, (n, 1)) + rng.normal(0.0, 1e-5, (n, 3))
    return dth, dv


def timeit(fn, repeat):
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return min(ts), float(np.median(ts))


@njit(cache=True, nogil=True)
def minimal_kernel(dth, dv):  # pragma: no cover - compiled
    """The least a single-sample kernel does: load the six increments of every sample and keep running sums."""
    a0 = a1 = a2 = v0 = v1 = v2 = 0.0
    for k in range(dth.shape[0]):
        a0 += dth[k, 0]
        a1 += dth[k, 1]
        a2 += dth[k, 2]
        v0 += dv[k, 0]
        v1 += dv[k, 1]
        v2 += dv[k, 2]
    return a0 + a1 + a2 + v0 + v1 + v2


def kernel_ratio(n=2_000_000, repeat=7, rng=None):
    """Fused two-speed navigation vs :func:`minimal_kernel` on the same samples, timed in turn (A B A B ...)."""
    rng = rng or np.random.default_rng(20240601)
    dth, dv = stationary_increments(n, rng)
    init = NavInit(lat=LAT, pitch=ATT[0], roll=ATT[1], yaw=ATT[2])
    minimal_kernel(dth[:10], dv[:10])
    strapdown.navigate_highrate(dth[:100], dv[:100], DT, 10, init, out_every=10)
    ta, tb, ratios = [], [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        strapdown.navigate_highrate(dth, dv, DT, 10, init, out_every=10)
        t1 = time.perf_counter()
        minimal_kernel(dth, dv)
        t2 = time.perf_counter()
        ta.append(t1 - t0)
        tb.append(t2 - t1)
        ratios.append((t1 - t0) / (t2 - t1))
    print(f"yardstick, {n:,} samples in memory: navigation (two-speed fused) {min(ta) / n * 1e9:.1f} ns/sample, "
          f"minimal compiled loop {min(tb) / n * 1e9:.2f} ns/sample; ratio min {min(ratios):.1f}, "
          f"median {float(np.median(ratios)):.1f} (pairs of the same run)")
    return min(ratios)


def kernels(repeat=5):
    rng = np.random.default_rng(20240601)
    init = NavInit(lat=LAT, pitch=ATT[0], roll=ATT[1], yaw=ATT[2])
    t0 = time.perf_counter()
    small = stationary_increments(1000, rng)
    strapdown.navigate_highrate(*small, DT, 10, init, out_every=10)
    strapdown.navigate_highrate(*small, DT, 1, init, out_every=10)
    D = strapdown.preintegrate(*small, 10)
    strapdown.navigate_multi(*D, 0.1, init, np.zeros((3, 3)), out_every=10)
    strapdown.navigate_multi(*D, 0.1, init, np.zeros((3, 3)), out_every=10, parallel=False)
    print(f"compile/load of the kernels: {time.perf_counter() - t0:.2f} s (cache=True: first run compiles)")
    n = 2_000_000
    dth, dv = stationary_increments(n, rng)
    print(f"\n--- single stream, {n:,} samples at 100 Hz ({n * DT / 3600:.2f} h) ---")
    b, m = timeit(lambda: strapdown.navigate_highrate(dth, dv, DT, 10, init, out_every=10), repeat)
    print(f"two-speed (10 Hz nav, fused):     {b / n * 1e9:7.1f} ns/sample (median {m / n * 1e9:.1f})   target <= 60")
    b, m = timeit(lambda: strapdown.navigate_highrate(dth, dv, DT, 1, init, out_every=100), repeat)
    print(f"single-speed (100 Hz nav, fused): {b / n * 1e9:7.1f} ns/sample (median {m / n * 1e9:.1f})   target <= 100")
    b, m = timeit(lambda: strapdown.preintegrate(dth, dv, 10), repeat)
    print(f"pre-integration alone (10:1):     {b / n * 1e9:7.1f} ns/sample (median {m / n * 1e9:.1f})")
    Dth, Dv = strapdown.preintegrate(dth, dv, 10)
    b, m = timeit(lambda: strapdown.navigate(Dth, Dv, 0.1, init, out_every=10), repeat)
    print(f"navigation step alone (10 Hz):    {b / len(Dth) * 1e9:7.1f} ns/step   (median {m / len(Dth) * 1e9:.1f})")

    kernel_ratio(n, rng=rng)

    print("\n--- 30 streams sharing pre-integrated increments (PSO generation) ---")
    gb = np.random.default_rng(1).uniform(-0.03, 0.03, (30, 3)) * earth.DEG_PER_H
    for par in (True, False):
        b, m = timeit(lambda: strapdown.navigate_multi(Dth, Dv, 0.1, init, gb, out_every=10, parallel=par), 3)
        print(f"parallel={par!s:5}: {b / (n * 30) * 1e9:6.2f} ns per 100 Hz sample per stream "
              f"(median {m / (n * 30) * 1e9:.2f}); {b / (len(Dth) * 30) * 1e9:.1f} ns per stream-step   target <= 10")

    print("\n--- scaling with duration (one stream, two-speed fused) ---")
    for hours in (0.5, 3.0, 24.0):
        nn = int(hours * 360_000)
        d1, d2 = stationary_increments(nn, rng)
        b, m = timeit(lambda: strapdown.navigate_highrate(d1, d2, DT, 10, init, out_every=10), 3)
        print(f"{hours:5.1f} h ({nn:>10,} samples): {b:7.3f} s, {b / nn * 1e9:6.1f} ns/sample")
        del d1, d2

    print("\n--- scaling with streams (3 h window pre-integrated, 10 Hz, parallel) ---")
    nn = 3 * 360_000
    d1, d2 = stationary_increments(nn, rng)
    D1, D2 = strapdown.preintegrate(d1, d2, 10)
    for S in (1, 10, 30, 100):
        g = np.random.default_rng(S).uniform(-0.03, 0.03, (S, 3)) * earth.DEG_PER_H
        b, m = timeit(lambda: strapdown.navigate_multi(D1, D2, 0.1, init, g, out_every=10), 3)
        print(f"S = {S:3d}: {b:7.3f} s per pass, {b / (nn * S) * 1e9:6.2f} ns per sample per stream")


def make_file(path, hours, chunk=1 << 20):
    """A stationary 100 Hz recording of float64 increments (rad, m/s) with a drift, written in chunks of about
    ``chunk`` samples, which are also the file's chunks along time (the layout of the simulator's sessions)."""
    n = int(round(hours * 3600 / DT))
    chunk = -(-n // -(-n // chunk))  # equal chunks, almost no padding in the last one
    C = euler_to_dcm(*ATT)
    drift = np.array([-0.01, 0.01, 0.01]) * earth.DEG_PER_H
    w = C.T @ earth.earth_rate_enu(LAT) + drift
    f = C.T @ np.array([0.0, 0.0, float(earth.normal_gravity(LAT))])
    rng = np.random.default_rng(7)
    attrs = {"attitude_pitch_deg": math.degrees(ATT[0]), "attitude_roll_deg": math.degrees(ATT[1]),
             "attitude_yaw_deg": math.degrees(ATT[2]), "note": "benchmark file of bench_navigation.py"}
    t0 = time.perf_counter()
    with recording.LongRecordingWriter(path, n, 1.0 / DT, latitude_deg=math.degrees(LAT), accel_units="m s-1",
                                       gyro_units="rad", extra_attrs=attrs, chunk_samples=chunk) as wr:
        for i0 in range(0, n, chunk):
            k = min(chunk, n - i0)
            wr.append(np.tile(f * DT, (k, 1)) + rng.normal(0, 1e-6, (k, 3)),
                      np.tile(w * DT, (k, 1)) + rng.normal(0, 1e-9, (k, 3)))
    print(f"wrote {path}: {n:,} samples ({hours} h), {Path(path).stat().st_size / 1e9:.2f} GB "
          f"in {time.perf_counter() - t0:.1f} s")


def evict(path):
    """Drop this file's pages from the page cache (only this file's): the next read comes from disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)


def end_to_end(path, repeat=1, cold=False):
    h = recording.read_header(path)
    cache = "cold (file evicted from the page cache before each run)" if cold else "page cache as it is"
    print(f"\n--- end to end: {path} ({h.n_samples:,} samples, {h.duration_s / 3600:.1f} h "
          f"at {h.sample_rate_hz:g} Hz), {cache} ---")
    strapdown.navigate_highrate(np.zeros((10, 3)), np.zeros((10, 3)), DT, 10, NavInit(lat=LAT))  # load kernels
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    walls = []
    for _ in range(repeat):
        if cold:
            evict(path)
        t0 = time.perf_counter()
        ds = navigation.navigate_recording(path, nav_rate_hz=10.0, output_interval_s=1.0)
        walls.append(time.perf_counter() - t0)
        print(f"navigate_recording: {walls[-1]:.2f} s wall ({walls[-1] / h.n_samples * 1e9:.1f} ns/sample incl. "
              f"reading)   target 240 h in <= 5 s")
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        out_mb, n_rec = ds.nbytes / 1e6, ds.sizes["time"]
        final = f"yaw {float(ds.yaw_err_arcmin[-1]):.3f} arcmin, lon {float(ds.lon_err_arcmin[-1]):.2f} arcmin"
        del ds
    if repeat > 1:
        print(f"navigate_recording over {repeat} runs: min {min(walls):.2f} s, median {float(np.median(walls)):.2f} s")
    print(f"peak RSS: {rss:.0f} MB (before: {rss0:.0f} MB); output {out_mb:.0f} MB, {n_rec:,} records")
    print(f"final errors: {final}")
    if cold:
        evict(path)
    t0 = time.perf_counter()
    for _ in reader.iter_raw_chunks(path, h):
        pass
    print(f"reading alone (calib.nav.reader.iter_raw_chunks, {'cold' if cold else 'page cache as it is'}): "
          f"{time.perf_counter() - t0:.2f} s")
    kernel_ratio()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recording", nargs="?", help="navigate this recording end to end")
    ap.add_argument("--make-file", help="write a stationary 100 Hz test recording here and exit")
    ap.add_argument("--hours", type=float, default=240.0)
    ap.add_argument("--skip-kernels", action="store_true")
    ap.add_argument("--repeat", type=int, default=1, help="end-to-end runs (min and median printed)")
    ap.add_argument("--cold", action="store_true", help="evict the recording from the page cache before each run")
    a = ap.parse_args(argv)
    if a.make_file:
        make_file(a.make_file, a.hours)
        return 0
    if a.recording:  # first, so that the peak RSS is that of the end-to-end run alone
        end_to_end(a.recording, a.repeat, a.cold)
    if not a.skip_kernels:
        kernels()
    return 0


if __name__ == "__main__":
    sys.exit(main())
