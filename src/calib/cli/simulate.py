"""``calib simulate calibration|navigation|static_check OUT.nc``: the synthetic sessions of the study (its data
stage), one file and its truth sidecar.

The library modules the functions need (numpy, netCDF, scipy and more behind them) are imported inside them:
loaded only when a command runs, so that ``calib --help`` and a usage error answer at once."""
from __future__ import annotations

import shutil
from pathlib import Path

from calib.cli.shared import emit, output_file, positive, study_config
from calib.core.errors import InputError


MAX_HOURS = 240.0            # longest synthetic recording without --force (He 2019's 240 h)


BYTES_PER_SAMPLE = 6 * 8 + 4  # accel + gyro float64 + float32 temperature: the largest a simulated sample takes


def cmd_simulate(a):
    from calib.io.atomic import output_set
    from calib.studies import stages

    cfg = study_config(a.config)
    if a.hours is not None:
        if a.kind == "calibration":
            raise InputError("--hours applies to 'navigation' and 'static_check'; the calibration session's length "
                             "follows from calibration_session in the config")
        positive(a.hours, "--hours")
        if a.hours > MAX_HOURS and not a.force:
            raise InputError(f"--hours {a.hours:g} is above {MAX_HOURS:g} h", fix="pass --force for a longer recording")
    if a.seed is not None and a.seed < 0:
        raise InputError(f"--seed must be >= 0 (got {a.seed})")
    key = {"calibration": "calibration_session", "navigation": "navigation_session"}.get(a.kind, a.kind)
    seed = stages.session_seed(cfg["seeds"]["data"], key) if a.seed is None else a.seed
    truth = a.truth or str(Path(a.out).with_suffix(".truth.json"))
    output_file(a.out, "recording")
    output_file(truth, "truth file")
    if a.kind != "calibration":
        _check_disk(a.out, a.hours or cfg[key]["duration_h"],
                    cfg[key].get("sample_rate_hz", cfg["calibration_session"]["sample_rate_hz"]))
    with output_set():   # the recording and its truth sidecar: both or neither
        if a.kind == "calibration":
            stages.simulate_calibration(cfg["calibration_session"], cfg["site"], seed, a.out, truth)
        elif a.kind == "navigation":
            s = dict(cfg["navigation_session"])
            if a.hours is not None:
                s["duration_h"] = a.hours
            stages.simulate_navigation(s, cfg["site"], seed, a.out, truth)
        else:
            c = dict(cfg["static_check"])
            if a.hours is not None:
                c["duration_h"] = a.hours
            stages.simulate_static_check(c, cfg["calibration_session"], cfg["site"], seed, a.out, truth)
    emit(f"wrote {a.out} (truth in {truth})")


def _check_disk(out, hours, fs):
    """Refuse a long recording that would not fit on the disk of its folder."""
    need = float(hours) * 3600.0 * float(fs) * BYTES_PER_SAMPLE * 1.02 + 16e6
    folder = Path(out).parent if str(Path(out).parent) else Path(".")
    free = shutil.disk_usage(folder).free
    if need > free:
        raise InputError(f"{hours:g} h at {fs:g} Hz needs about {need / 1e9:.2f} GB but only {free / 1e9:.2f} GB "
                         "are free", file=folder, fix="free space, write elsewhere or shorten --hours")


def register(sub) -> None:
    """Add the ``simulate`` sub-command."""
    s = sub.add_parser("simulate", help="synthetic sessions (data stage)")
    s.add_argument("kind", choices=["calibration", "navigation", "static_check"])
    s.add_argument("out")
    s.add_argument("--config", help="study config (default: config/config.yaml of the calib source tree)")
    s.add_argument("--seed", type=int)
    s.add_argument("--hours", type=float,
                   help=f"length of a navigation / static_check session, 0 < H <= {MAX_HOURS:g}")
    s.add_argument("--truth")
    s.add_argument("--force", action="store_true", help=f"allow --hours above {MAX_HOURS:g}")
    s.set_defaults(fn=cmd_simulate)
