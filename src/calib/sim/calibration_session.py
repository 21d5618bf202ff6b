"""The Liu 2021 calibration session: the turntable path (24 static positions and the ± rotation windows,
:mod:`calib.sim.trajectory`) of the simulated unit written as a ``calib-recording-1`` file of integer pulse counts
(:mod:`calib.sim.counts_engine`), with its truth sidecar (:mod:`calib.sim.truth`). A deterministic function of
``(cfg, seed)``; the seed changes the noise only.
"""
from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.core.triad import TriadModel
from calib.io import recording
from calib.io.atomic import write_json
from calib.io.netcdf import provenance
from calib.sim import effects
from calib.sim.counts_engine import NOISE_BLOCK, SENSOR_NAME, CountsEngine, counts_recording_attrs
from calib.sim.settings import (CALIBRATION_DEFAULTS, SimConfigError, merge, sample_rate, simulated_site, site,
                                unit_settings)
from calib.sim.trajectory import Trajectory, calibration_plan, plan_duration, sample_segment_index, segment_table
from calib.sim.truth import calibration_truth


@dataclass
class CalibrationSimulator:
    """Everything :func:`simulate_calibration_session` derives from ``(cfg, seed)`` before generating."""

    cfg: dict
    seed: int
    plan: list
    trajectory: Trajectory
    accel: TriadModel
    gyro: TriadModel
    noise: dict
    effects: dict
    temperature: dict
    latitude_deg: float       # recorded (assumed) latitude
    height_m: float
    site: effects.SiteTruth   # the world actually simulated
    sample_rate_hz: float
    n_samples: int

    def inputs(self, t):
        lat = math.radians(self.site.latitude_deg)
        k = self.trajectory.kinematics(t, lat, self.site.height_m, self.site.gravity_m_s2)
        return k.f_b, k.w_ib_b, k.w_nb_b, k.dw_nb_b

    def engine(self, seed: int | None = None, clean: np.ndarray | None = None) -> CountsEngine:
        """The counts generator of the session for noise ``seed`` (default: the simulator's own seed);
        ``clean``: precomputed noise-free increments (:meth:`clean_increments`)."""
        return CountsEngine(self.accel, self.gyro, self.noise, self.effects, self.site, self.sample_rate_hz,
                            self.seed if seed is None else int(seed), self.inputs, self.temperature, n_nodes=3,
                            clean=clean)

    def clean_increments(self) -> np.ndarray:
        """Noise-free increments int N dt of every sample (n_samples, 6) [count], accel then gyro: they do not
        depend on the noise seed, so one evaluation of the kinematics serves every seed of the session."""
        n = self.n_samples
        eng = self.engine()
        out = np.empty((n, 6))
        for i0 in range(0, n, NOISE_BLOCK):
            k = min(NOISE_BLOCK, n - i0)
            out[i0:i0 + k] = eng.clean_increments(i0, k)
        return out

    def noise_key(self, seed: int | None = None) -> tuple:
        """The key :meth:`noise_increments` returns for ``seed``, without drawing the noise."""
        return self.engine(seed).noise_key() + (self.n_samples,)

    def noise_increments(self, seed: int | None = None) -> tuple[tuple, np.ndarray]:
        """``(key, noise)``: the noise increments (n_samples, 6) [count] of noise ``seed``
        (:meth:`calib.sim.counts_engine.CountsEngine.noise_increments`, drawn in the blocks :meth:`counts` draws
        them in) and the key of everything they depend on (seed, noise terms, scale factors, sample count):
        sessions of the same unit with equal keys have equal noise."""
        n = self.n_samples
        eng = self.engine(seed)
        key = eng.noise_key() + (n,)
        out = np.empty((n, 6))
        for i0 in range(0, n, NOISE_BLOCK):
            k = min(NOISE_BLOCK, n - i0)
            out[i0:i0 + k] = eng.noise_increments(k)
        return key, out

    def counts(self, seed: int | None = None, clean: np.ndarray | None = None,
               noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Accelerometer and gyro counts per sample (n_samples, 3 each) for noise ``seed`` (default: the
        simulator's own): exactly the samples :func:`simulate_calibration_session` writes for that seed.
        ``clean``: :meth:`clean_increments`, computed once for many seeds of the same configuration. ``noise``:
        :meth:`noise_increments` of the same seed (e.g. computed once for every session of the unit)."""
        acc, gyr, _ = self.engine(seed, clean).run(self.n_samples, NOISE_BLOCK, noise)
        return acc, gyr


def build_calibration_simulator(cfg: dict, seed: int) -> CalibrationSimulator:
    """Resolve and validate a calibration-session configuration (keys:
    :data:`calib.sim.settings.CALIBRATION_DEFAULTS`)."""
    where = "calibration_session"
    c = merge(cfg, CALIBRATION_DEFAULTS, where)
    lat, h = site(c, where)
    fs = sample_rate(c, where)
    try:
        plan = calibration_plan(step_deg=float(c["step_deg"]), positions_per_phase=int(c["positions_per_phase"]),
                                dwell_s=float(c["dwell_s"]), rotation_rates_deg_s=list(c["rotation_rates_deg_s"]),
                                revolutions=c["revolutions"], rotation_axes=c["rotation_axes"],
                                transition_s=list(c["transition_s"]), move_rate_deg_s=float(c["move_rate_deg_s"]),
                                time_grid_s=1.0 / fs)
    except ValueError as exc:
        raise SimConfigError(f"{where}: {exc}") from exc
    acc, gyr, noise, eff, temp = unit_settings(c, where)
    n = int(math.floor(plan_duration(plan) * fs + 1e-6))
    return CalibrationSimulator(c, int(seed), plan, Trajectory(plan), acc, gyr, noise, eff, temp, lat, h,
                                simulated_site(lat, h, eff), fs, n)


def calibration_session_channels(sim: CalibrationSimulator) -> dict:
    """The seed-independent parts of a calibration-session recording: ``segment_index``, ``table_angle``, the
    segment table and the global attributes (:func:`calibration_session_dataset` takes them precomputed when many
    noise seeds of one session are generated)."""
    n, fs = sim.n_samples, sim.sample_rate_hz
    return {"segment_index": sample_segment_index(sim.plan, n, fs),
            "table_angle": sim.trajectory.kinematics(np.arange(n) / fs,
                                                     math.radians(sim.latitude_deg)).table_angle_deg,
            "segments": segment_table(sim.plan),
            "attrs": counts_recording_attrs(sim.cfg["conceal"], sim.effects, sim.noise["quantize"],
                                            {"session": "calibration"})}


def calibration_session_dataset(sim: CalibrationSimulator, seed: int | None = None, clean: np.ndarray | None = None,
                                channels: dict | None = None):
    """The in-memory recording (``xarray.Dataset``) of the session for noise ``seed`` (default: the simulator's
    own): exactly the dataset :func:`simulate_calibration_session` writes. ``clean``
    (:meth:`CalibrationSimulator.clean_increments`) and ``channels`` (:func:`calibration_session_channels`):
    seed-independent parts computed once for many seeds of the same session."""
    acc, gyr, temp = sim.engine(seed, clean).run(sim.n_samples, NOISE_BLOCK)
    fixed = calibration_session_channels(sim) if channels is None else channels
    return recording.make_dataset(
        acc, gyr, sample_rate_hz=sim.sample_rate_hz, latitude_deg=sim.latitude_deg, height_m=sim.height_m,
        accel_units="count", gyro_units="count", accel_kind="increment", gyro_kind="increment",
        source="synthetic", sensor=SENSOR_NAME, temperature=temp, segment_index=fixed["segment_index"],
        segments=fixed["segments"], table_angle=fixed["table_angle"], extra_attrs=dict(fixed["attrs"]))


def simulate_calibration_session(cfg: dict, seed: int, out_path, truth_path=None, prov=None) -> Path:
    """Simulate the Liu 2021 calibration session and write it as a ``calib-recording-1`` file.

    ``cfg``: see :data:`calib.sim.settings.CALIBRATION_DEFAULTS` (the ``calibration_session`` section plus
    ``site``). Output: accel/gyro int32 counts per sample (``sample_kind='increment'``, ``units='count'``),
    ``temperature``, ``segment_index`` (-1 in transitions), ``table_angle`` and the segment table.
    ``truth_path``: JSON sidecar with the true sensor parameters, noise, effects, site and seed
    (:func:`calib.sim.truth.calibration_truth`). With ``conceal: true`` nothing in the recording names the
    effects.
    """
    t_wall = _time.perf_counter()
    sim = build_calibration_simulator(cfg, seed)
    ds = calibration_session_dataset(sim)
    if prov is None:
        prov = provenance("simulate_calibration_session", cfg, seed)
    out = recording.write(ds, out_path, prov)
    if truth_path is not None:
        write_json(calibration_truth(sim, generation_time_s=_time.perf_counter() - t_wall), truth_path)
    return out
