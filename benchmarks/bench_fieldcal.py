"""Benchmark of calib.fieldcal on the shared real recordings: per-log times and the acceptance
metrics next to their targets (the peers' published numbers).

Run: .venv/bin/python benchmarks/bench_fieldcal.py [--data DIR]  (default $CALIB_DATA, else ../shared/data)
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from calib import fieldcal
from calib.ingest import importers

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "import"

IMU_TK_SCALES = np.array([414.459, 412.01, 414.649])  # counts per m/s^2 (IMU-TK's inverse scale factors)
MIKOFF_REF = {"imu0": 0.0552, "imu1": 0.0542, "imu2": 0.0571}  # better of IMU-TK and the authors' tool, m/s^2


def _import(name, data):
    s = importers.load_settings(CONFIG / f"{name}.yaml")
    s["data_dir"] = str(data)
    t0 = time.perf_counter()
    ds = importers.import_dataset(s)
    return ds, time.perf_counter() - t0


def _cal(ds, settings):
    t0 = time.perf_counter()
    res = fieldcal.fieldcal_recording(ds, settings)
    return res, time.perf_counter() - t0


def _line(what, value, target, ok, info=False):
    """One metric line; ``info`` lines (variants, context) are marked meets/misses and never fail the run."""
    verdict = ("meets" if ok else "misses") if info else ("PASS" if ok else "FAIL")
    print(f"  {what:<58s} {value:<34s} target {target:<26s} {verdict}")
    return ok or info


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--data", default=str(importers.default_data_root()),
                    help="folder of the shared recordings (default: $CALIB_DATA, else ../shared/data)")
    args = ap.parse_args(argv)
    data = Path(args.data)
    # warm the numba cache so that per-log times are steady-state
    w = np.zeros((3, 3))
    fieldcal.integrate_quaternions(w, np.full(3, 0.01), np.array([0]), np.array([2]))
    ok = True

    print("imu_tk_xsens (g = 9.81744 m/s^2)")
    ds, t_imp = _import("imu_tk_xsens", data)
    # the acceptance run is IMU-TK's own procedure; the fixed 10x threshold and the project's
    # default detection are shown for comparison (info)
    for label, det, info in (("IMU-TK rule, k searched 2..10 (acceptance)", {"rule": "imu_tk"}, False),
                             ("IMU-TK rule, k = 10 fixed", {"rule": "imu_tk", "k": 10}, True),
                             ("detect_static defaults, all interval samples", {}, True)):
        res, t = _cal(ds, {"gravity_m_s2": 9.81744, "detection": det})
        sf = res.accel.scale_factors
        dev = np.abs(sf / IMU_TK_SCALES - 1).max()
        print(f" {label}: {len(res.intervals)} intervals, import {t_imp:.2f} s, calibration {t:.2f} s"
              + (f", k = {res.metrics['imu_tk_k']}" if "imu_tk_k" in res.metrics else ""))
        ok &= _line("accel norm residual RMS (per sample, fit samples) [m/s^2]", f"{res.accel.residual_rms:.5f}",
                    "<= 0.0080", res.accel.residual_rms <= 0.0080, info)
        _line("accel scale factors [count per m/s^2]", np.array2string(sf, precision=3),
              "IMU-TK 414.459 412.01 414.649", True, True)
        ok &= _line("  max deviation from IMU-TK's", f"{dev * 100:.4f} %", "<= 0.05 %", dev <= 5e-4, info)
        print(f"  accel identifiability: {res.accel.identifiability.describe()}")
        ok &= _line("gyro gravity-direction residual RMS (g-sensitive bias) [deg]", f"{res.gyro.residual_rms:.3f}",
                    "<= 0.3", res.gyro.residual_rms <= 0.3, info)
        print(f"  gyro scale factors [count per rad/s]: {np.array2string(res.gyro.scale_factors, precision=1)}; "
              f"before calibration {res.gyro.extra['rms_before_deg']:.2f} deg; "
              f"identifiability: {res.gyro.identifiability.describe()}")
        tk, t2 = _cal(ds, {"gravity_m_s2": 9.81744, "detection": det, "gyro": {"bias": "initial"}})
        est, _ = _cal(ds, {"gravity_m_s2": 9.81744, "detection": det, "gyro": {"bias": "estimate"}})
        _line("gyro RMS with IMU-TK's bias (initial rest, no g-sens.) [deg]", f"{tk.gyro.residual_rms:.3f}",
              "<= 0.3", tk.gyro.residual_rms <= 0.3, True)
        _line("gyro RMS with the bias estimated (constant) [deg]", f"{est.gyro.residual_rms:.3f}", "<= 0.3",
              est.gyro.residual_rms <= 0.3, True)

    print("\nmikoff_mpu9150 (g = 9.81 m/s^2)")
    for unit, ref in MIKOFF_REF.items():
        ds, t_imp = _import(f"mikoff_{unit}", data)
        res, t = _cal(ds, {"gravity_m_s2": 9.81, "evaluate": ["mikoff_standstill"]})
        m = res.metrics
        print(f" {unit}: {len(res.intervals)} intervals, import {t_imp:.2f} s, calibration {t:.2f} s")
        ok &= _line("static-norm RMS over the authors' standstill samples [m/s^2]",
                    f"{m['static_norm_rms_mikoff_standstill']:.5f} ({m['n_mikoff_standstill_samples']} samples)",
                    f"<= {1.01 * ref:.5f} (1.01 x {ref})", m["static_norm_rms_mikoff_standstill"] <= 1.01 * ref)
        _line("  ratio to the reference", f"{m['static_norm_rms_mikoff_standstill'] / ref:.4f}", "<= 1.01",
              m["static_norm_rms_mikoff_standstill"] <= 1.01 * ref, True)
        _line("static-norm RMS over our own intervals (fit samples) [m/s^2]", f"{res.accel.residual_rms:.5f}",
              f"<= {1.01 * ref:.5f} (ratio {res.accel.residual_rms / ref:.4f})", res.accel.residual_rms <= 1.01 * ref,
              True)
        ok &= _line("time per log (import + calibration)", f"{t_imp + t:.2f} s", "< 2 s", t_imp + t < 2.0)
        print(f"  accel scale factors {np.array2string(res.accel.scale_factors, precision=4)}; gyro direction "
              f"RMS {res.gyro.residual_rms:.3f} deg (before {res.gyro.extra['rms_before_deg']:.3f}); "
              f"accel {res.accel.identifiability.describe()}")

    print("\nimucal_ferraris (g = 9.81 m/s^2)")
    ds, t_imp = _import("imucal_ferraris_A", data)
    res, t = _cal(ds, {"gravity_m_s2": 9.81, "evaluate": ["directions"]})
    print(f" session A (m/s^2, deg/s): method {res.method}, import {t_imp:.2f} s, calibration {t:.2f} s")
    ok &= _line("static-norm RMS (per sample, six positions) [m/s^2]", f"{res.accel.residual_rms:.5f}",
                "<= 0.015 (imucal 0.0148)", res.accel.residual_rms <= 0.015)
    _line("  with the full least-squares bias instead", f"{res.accel.extra['static_norm_rms_lsq_bias']:.5f}",
          "<= 0.015", res.accel.extra["static_norm_rms_lsq_bias"] <= 0.015, True)
    _line("gravity-direction check over the 90/180 deg flips [deg]", f"{res.metrics['direction_check_rms_deg']:.3f}",
          "< 1.8 (1 % of a flip)", res.metrics["direction_check_rms_deg"] < 1.8, True)
    turns = res.metrics["turn_angles_deg"]
    print("  turns [deg]: " + ", ".join(f"{k}: {turns[k]['xyz'.index(k)]:+.1f}" for k in "xyz"))
    print(f"  note: {res.accel.notes[0]}")
    ds, t_imp = _import("imucal_ferraris_B", data)
    res, t = _cal(ds, {"gravity_m_s2": 9.81})
    print(f" session B (counts): method {res.method}, import {t_imp:.2f} s, calibration {t:.2f} s")
    turns = res.metrics["turn_angles_deg"]
    pos = all(turns[ax]["xyz".index(ax)] > 0 for ax in "xyz")
    ok &= _line("calibrated turns about their labelled axes [deg]",
                ", ".join(f"{ax} {turns[ax]['xyz'.index(ax)]:+.1f}" for ax in "xyz"), "positive (+360)", pos)
    gsf = res.gyro.scale_factors * math.pi / 180
    asf = res.accel.scale_factors * 9.80665
    _line("gyro scale factors [count per deg/s]", np.array2string(gsf, precision=2), "about 16.4 (README), 3 %",
          bool(np.all(np.abs(gsf / 16.4 - 1) < 0.03)), True)
    _line("accel scale factors [count per g]", np.array2string(asf, precision=1), "about 2048 (README), 5 %",
          bool(np.all(np.abs(asf / 2048 - 1) < 0.05)), True)
    _line("static-norm RMS (per sample) [m/s^2]", f"{res.accel.residual_rms:.5f}", "-", True, True)
    print("\nALL TARGETS MET" if ok else "\nSOME TARGETS MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
