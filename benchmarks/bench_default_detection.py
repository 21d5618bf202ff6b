"""The field calibration's default static-interval detection (no settings) against the tuned settings (the
detection on the true static intervals), over the static-pose protocols of ``tests/fieldcal/conftest.py``
(defaults that work): the slow, complete version of ``tests/fieldcal/test_default_detection.py``, with the same
judgement (:func:`test_default_detection.judge`: run as ``calib fieldcal`` runs it; good = exit 0, residual over
the true static samples within 1 % of the tuned one's, accel scale factors within 3 stated standard errors of the
truth widened by the tuned settings' own error).

Prints one line per session and a summary: exit codes, the good rate (of the sessions whose true intervals
determine every accel parameter, and of all), how often the stated interval covers the truth without the
widening for the default and for the tuned settings (the per-sample norm fit's bias, not the detection's), and the
times.

Run: .venv/bin/python benchmarks/bench_default_detection.py [--seeds 10030:10230] [--json out.jsonl]
Seeds 0-199 tuned calib.fieldcal.default_detection; 10000-10029 are the CI test's, 10030-10229 the slow test's.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "fieldcal"))

from test_default_detection import MIN_GOOD, good, judge  # noqa: E402


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="10030:10230", help="first:stop (stop excluded)")
    p.add_argument("--json", help="write one JSON line per session here")
    a = p.parse_args(argv)
    logging.disable(logging.WARNING)
    lo, hi = (int(v) for v in a.seeds.split(":"))
    rows, fh = [], open(a.json, "w") if a.json else None
    t_all = time.perf_counter()
    for seed in range(lo, hi):
        t0 = time.perf_counter()
        r = judge(seed)
        r["time_s"] = time.perf_counter() - t0
        rows.append(r)
        if fh:
            fh.write(json.dumps(r, default=str) + "\n")
            fh.flush()
        what = (f"residual {100 * r['residual_rel']:+7.3f} %  scale factors {'in ' if r['sf_ok'] else 'OUT'}  "
                f"{r['n_intervals']:3d} intervals  {r['chosen']}" if r["exit"] == 0 else r.get("message", "")[:150])
        print(f"{seed:6d} {r['units']:5s} rest {r['rest_s']:5.1f} s  {r['n_poses']:2d} poses  "
              f"wait {r['min_wait_s']:4.2f} s  noise x{r['noise']:5.2f}  {r['time_s']:5.2f} s  "
              f"{'' if r['determinable'] else '(not determinable) '}"
              f"exit {r['exit']}  {what}", flush=True)
    n = len(rows)
    det = [r for r in rows if r["determinable"]]
    ok = [r for r in rows if r["exit"] == 0]
    e3 = [r for r in rows if r["exit"] == 3]
    times = np.array([r["time_s"] for r in rows])
    print(f"\n{n} sessions, seeds {lo}-{hi - 1}, {time.perf_counter() - t_all:.0f} s; per session (generation, "
          f"tuned fit, default) median {np.median(times):.2f} s, 90th percentile {np.percentile(times, 90):.2f} s, max "
          f"{times.max():.2f} s")
    print(f"exit 0: {len(ok)}, exit 3: {len(e3)} (naming a settings key: {sum(r['key_named'] for r in e3)}), other: "
          f"{n - len(ok) - len(e3)}")
    ng = sum(good(r) for r in det)
    print(f"good: {ng} of the {len(det)} sessions whose true intervals determine every accel parameter "
          f"({100 * ng / max(len(det), 1):.1f} %, needed {100 * MIN_GOOD:.0f} %); of all {n}: "
          f"{sum(good(r) for r in rows)}")
    bad0 = [r for r in det if r["exit"] == 0 and not good(r)]
    print(f"determinable sessions exiting 0 without being good: {len(bad0)} {[r['seed'] for r in bad0]}")
    print(f"largest residual excess at exit 0: {100 * max((r['residual_rel'] for r in ok), default=0):.3f} %")
    cov = [r for r in ok if r["determinable"]]
    print(f"stated interval (3 x scale_factor_std) covers the truth, without widening: default "
          f"{sum(r['sf_in_stated_interval_of_truth'] for r in cov)} / {len(cov)}, tuned "
          f"{sum(r['tuned_sf_in_stated_interval_of_truth'] for r in cov)} / {len(cov)}")
    if fh:
        fh.close()


if __name__ == "__main__":
    main()
