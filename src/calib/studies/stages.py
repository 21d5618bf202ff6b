"""One function per workflow stage, shared by the Snakemake scripts and the ``calib`` command line.

Each takes plain values (paths and config sections), writes its products atomically, and logs progress
through ``print`` (the workflow sends it to the rule's log).
"""
from __future__ import annotations

import time

from calib.core.seeds import SESSIONS, session_seed  # noqa: F401 - re-exported (the CLI, tests)
from calib.core.progress import Progress
from calib.io.netcdf import provenance
from calib.sim.calibration_session import simulate_calibration_session
from calib.sim.static_session import simulate_static_session

CAL_SESSION_KEYS = ("sample_rate_hz", "dwell_s", "step_deg", "positions_per_phase", "rotation_rates_deg_s",
                    "revolutions", "rotation_axes", "transition_s", "move_rate_deg_s", "sensor", "noise", "effects",
                    "conceal", "temperature")


def _site(site):
    return {k: site[k] for k in ("latitude_deg", "height_m") if k in site}


def calibration_cfg(session: dict, site: dict) -> dict:
    """The simulator configuration of the calibration session (``calibration_session`` and ``site`` sections)."""
    cfg = {k: session[k] for k in CAL_SESSION_KEYS if k in session}
    cfg["site"] = _site(site)
    return cfg


def static_check_cfg(check: dict, session: dict, site: dict) -> dict:
    """The simulator configuration (counts mode) of the static check recording of the calibrated unit."""
    cfg = {k: session[k] for k in ("sample_rate_hz", "sensor", "noise", "effects", "conceal", "temperature")
           if k in session}
    cfg.update(mode="counts", duration_h=check["duration_h"], attitude_deg=check["attitude_deg"], site=_site(site))
    return cfg


def simulate_calibration(session: dict, site: dict, seed: int, out, truth, rule="cli"):
    """Data stage: the Liu 2021 calibration session (24 positions + ± rotations)."""

    cfg = calibration_cfg(session, site)
    t = time.perf_counter()
    simulate_calibration_session(cfg, seed, out, truth, prov=provenance(rule, cfg, seed))
    print(f"wrote {out} in {time.perf_counter() - t:.1f} s")


def simulate_static_check(check: dict, session: dict, site: dict, seed: int, out, truth, rule="cli"):
    """Data stage: a static recording (counts) of the calibrated unit for Liu 2021's navigation check."""

    cfg = static_check_cfg(check, session, site)
    bar = Progress(1, "static check")
    simulate_static_session(cfg, seed, out, truth, prov=provenance(rule, cfg, seed),
                            progress=lambda d, n: (setattr(bar, "total", n), bar(d)))


def simulate_navigation(session: dict, site: dict, seed: int, out, truth, rule="cli"):
    """Data stage: He 2019 §IV.A stationary navigation data (physical increments, chunked)."""

    cfg = dict(session)
    cfg.update(mode="physical", site=_site(site))
    bar = Progress(1, "navigation session")
    simulate_static_session(cfg, seed, out, truth, prov=provenance(rule, cfg, seed),
                            progress=lambda d, n: (setattr(bar, "total", n), bar(d)))
