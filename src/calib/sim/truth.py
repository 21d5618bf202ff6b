"""The truth sidecar (``calib-truth-1`` JSON) of a simulated session: the true sensor parameters, noise, effects,
site, attitude and seed the recording was made with. The diagnosis and the studies score against it; nothing in
the recording itself depends on it.
"""
from __future__ import annotations

import math

import numpy as np

from calib.core import earth
from calib.core.triad import PARAM_NAMES, TriadModel
from calib.sim import effects
from calib.sim.counts_engine import NOISE_BLOCK, noise_terms
from calib.sim.settings import PhysicalNoise, StaticLayout, UnitSettings
from calib.sim.trajectory import recorded_segments

TRUTH_FORMAT = "calib-truth-1"


def model_json(m: TriadModel) -> dict:
    """A triad's true model: K, E, b, the 12-parameter vector and its names, units."""
    return {"K": m.K.tolist(), "E": m.E.tolist(), "b": m.b.tolist(),
            "vector": m.to_vector().tolist(), "param_names": list(PARAM_NAMES),
            "input_unit": m.input_unit, "output_unit": m.output_unit}


def noise_json(noise: dict, accel: TriadModel, gyro: TriadModel, dt: float) -> dict:
    """The noise settings with the white noise per sample in counts and the noise block size."""
    d = dict(noise)
    sig_w = noise_terms(noise, dt)[0]
    d["per_sample_white_sigma_count"] = {"accel": (sig_w[:3] * accel.K).tolist(), "gyro": (sig_w[3:] * gyro.K).tolist()}
    d["noise_block_samples"] = NOISE_BLOCK
    return d


def calibration_truth(sim, generation_time_s: float = 0.0) -> dict:
    """The truth sidecar of :func:`calib.sim.calibration_session.simulate_calibration_session` for simulator
    ``sim`` (a :class:`calib.sim.calibration_session.CalibrationSimulator`); ``generation_time_s``: the wall
    time the recording took (0 when none was written)."""
    return {
        "format": TRUTH_FORMAT,
        "session": "calibration",
        "seed": sim.seed,
        "sample_rate_hz": sim.sample_rate_hz,
        "n_samples": sim.n_samples,
        "site": {"latitude_deg_recorded": sim.latitude_deg, "height_m": sim.height_m,
                 "latitude_deg_true": sim.site.latitude_deg, "gravity_m_s2_true": sim.site.gravity_m_s2,
                 "normal_gravity_m_s2_recorded_latitude":
                     float(earth.normal_gravity(math.radians(sim.latitude_deg), sim.height_m)),
                 "time_offset_s": sim.site.time_offset_s},
        "accel": model_json(sim.accel),
        "gyro": model_json(sim.gyro),
        "noise": noise_json(sim.noise, sim.accel, sim.gyro, 1.0 / sim.sample_rate_hz),
        "effects": sim.effects,
        "temperature": sim.temperature,
        "segments": [{"label": s.label, "kind": s.kind, "t_start_s": s.t_start_s, "duration_s": s.duration_s,
                      "axis": s.axis.tolist(), "rate_deg_s": s.rate_deg_s}
                     for s in recorded_segments(sim.plan)],
        "config": sim.cfg,
        "generation_time_s": generation_time_s,
    }


def static_physical_truth(c: dict, seed: int, layout: StaticLayout, noise: PhysicalNoise, mean_gyro_rad: np.ndarray,
                          mean_accel_m_s: np.ndarray) -> dict:
    """The truth sidecar of a physical-mode static session (merged config ``c``) without its wall time;
    ``mean_*``: the noise-free per-sample increments."""
    lat, h = layout.latitude_deg, layout.height_m
    return {
        "format": TRUTH_FORMAT, "session": "static", "mode": "physical", "seed": int(seed),
        "sample_rate_hz": layout.sample_rate_hz, "n_samples": layout.n_samples,
        "site": {"latitude_deg": lat, "height_m": h, "gravity_m_s2": float(earth.normal_gravity(math.radians(lat), h))},
        "attitude_deg": layout.attitude_deg, "cbn": layout.cbn.tolist(),
        "gyro_drift_deg_h": list(map(float, c["gyro_drift_deg_h"])),
        "accel_bias_m_s2": list(map(float, c["accel_bias_m_s2"])),
        "gyro_noise": noise.gyro_noise, "accel_vrw_ug_rthz": noise.accel_vrw_ug_rthz,
        "per_sample_sigma": {"gyro_rad": noise.sigma_gyro_rad, "accel_m_s": noise.sigma_accel_m_s},
        "mean_increment": {"gyro_rad": mean_gyro_rad.tolist(), "accel_m_s": mean_accel_m_s.tolist()},
        "noise_block_samples": NOISE_BLOCK, "config": c,
    }


def static_counts_truth(c: dict, seed: int, layout: StaticLayout, unit: UnitSettings,
                        site: effects.SiteTruth) -> dict:
    """The truth sidecar of a counts-mode static session (merged config ``c``, the unit at rest in the
    simulated world ``site``) without its wall time."""
    fs = layout.sample_rate_hz
    return {
        "format": TRUTH_FORMAT, "session": "static", "mode": "counts", "seed": int(seed),
        "sample_rate_hz": fs, "n_samples": layout.n_samples,
        "site": {"latitude_deg_recorded": layout.latitude_deg, "height_m": layout.height_m,
                 "latitude_deg_true": site.latitude_deg, "gravity_m_s2_true": site.gravity_m_s2,
                 "time_offset_s": site.time_offset_s},
        "attitude_deg": layout.attitude_deg, "cbn": layout.cbn.tolist(),
        "accel": model_json(unit.accel), "gyro": model_json(unit.gyro),
        "noise": noise_json(unit.noise, unit.accel, unit.gyro, 1.0 / fs), "effects": unit.effects,
        "temperature": unit.temperature, "config": c,
    }
