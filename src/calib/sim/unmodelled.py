"""Physics outside the diagnosis library, injected into a simulated session's noise-free output.

The diagnosis (:mod:`calib.diagnosis`) fits the signatures of the terms of :mod:`calib.sim.effects`. A proof that
it says "not understood" when the data holds something else needs effects made by a code path it does not share:
this module. Each effect changes the noise-free increments of a session
(:meth:`calib.sim.calibration_session.CalibrationSimulator.clean_increments`, ``int N dt`` per sample, accel then
gyro, in counts) through the unit's true linear model ``N = K E x + b`` (:class:`calib.core.triad.TriadModel`; inputs
``x`` in g and deg/h, Liu 2021 eqs. 1-4): the input is recovered from the clean output, changed, and mapped back.
The sensor noise and the pulse counter then run on the changed increments as on any other session, so the noise
is the simulator's own.

Effects (``spec`` entries, each ``{"effect": NAME, ...}``); times are those of the sample centres, ``t = (k +
1/2) dt`` from the first sample (the simulator's convention: sample ``k`` covers ``[k dt, (k + 1) dt)``):

* ``scale_drift`` -- the scale factor of one sensor axis changes linearly in time by ``ppm`` over the session
  (no temperature channel records why): ``N_i += ppm 1e-6 (t / T) (K E x)_i``.
* ``periodic_bias`` -- a bias oscillating with ``amplitude`` (input unit: ug for accelerometers, deg/h for
  gyros) and ``period_s``: ``N_i += K_i A sin(2 pi t / P)``.
* ``bias_step`` -- the bias of one axis jumps by ``step`` (input unit: ug or deg/h) at ``at_fraction`` of the
  session.
* ``quartic`` -- an accelerometer axis with a fourth-order nonlinearity ``k4_ug_per_g4``:
  ``N_i += K_i k4 1e-6 x_i^4`` (x in g).
* ``stop_attitude`` -- each static stop of the turntable off its recorded attitude by a small rotation, each
  component drawn from N(0, ``arcsec``^2) (seeded): ``x -> exp(-[phi x]) x`` (an exact rotation) for both triads during the stop.
* ``random_walk_bias`` -- the bias of one axis wanders as a random walk of density ``q`` (ug/sqrt(s) for
  accelerometers, deg/h/sqrt(s) for gyros): ``b_k = b_k-1 + q sqrt(dt) w_k``, w ~ N(0, 1), starting at 0; the walk is
  drawn per noise seed (:func:`inject_per_seed`, stream ``unmodelled_random_walk``), so every seed of a proof
  session sees another path. The simulator's own bias model is a Gauss-Markov process (bounded); a random walk is
  not in the library (the diagnosis's bias drift is a warm-up exponential plus a linear trend).
"""
from __future__ import annotations

import math

import numpy as np

from calib.core import seeds
from calib.core.rotations import rotvec_to_dcm

EFFECTS = ("scale_drift", "periodic_bias", "bias_step", "quartic", "stop_attitude", "random_walk_bias")
#: effects drawn anew for every noise seed (applied by :func:`inject_per_seed`, skipped by :func:`inject`)
PER_SEED = ("random_walk_bias",)
_AXES = {"x": 0, "y": 1, "z": 2}
_COLS = {"accel": slice(0, 3), "gyro": slice(3, 6)}
#: input units per ug (accelerometer, input g) and per deg/h (gyro, input deg/h)
_SMALL_UNIT = {"accel": 1e-6, "gyro": 1.0}


def _axis(e: dict) -> int:
    a = e.get("axis", "x")
    if a not in _AXES:
        raise ValueError(f"unmodelled effect {e.get('effect')!r}: axis {a!r}, one of x, y, z")
    return _AXES[a]


def inject(sim, clean: np.ndarray, spec: list[dict], segment_index=None, segment_kind=None, seed: int = 0):
    """Noise-free increments ``clean`` (n, 6) [count] of ``sim`` (a :class:`CalibrationSimulator`) with the
    effects of ``spec`` added (module docstring). ``segment_index`` (n,) and ``segment_kind`` (per segment) are
    needed by ``stop_attitude``; ``seed`` draws its attitude errors (stream ``unmodelled_stop_attitude``)."""
    out = np.array(clean, dtype=np.float64, copy=True)
    n = len(out)
    dt = 1.0 / float(sim.sample_rate_hz)
    t = (np.arange(n) + 0.5) * dt
    T = n * dt
    models = {"accel": sim.accel, "gyro": sim.gyro}
    for e in spec:
        name = e.get("effect")
        if name not in EFFECTS:
            raise ValueError(f"unmodelled effect {name!r}; one of {', '.join(EFFECTS)}")
        if name in PER_SEED:
            continue
        if name == "stop_attitude":
            if segment_index is None or segment_kind is None:
                raise ValueError("stop_attitude needs the session's segment_index and segment_kind")
            rng = seeds.stream(int(seed), "unmodelled_stop_attitude")
            sig = math.radians(float(e["arcsec"]) / 3600.0)
            seg = np.asarray(segment_index)
            for s, kind in enumerate(segment_kind):
                if str(kind) != "static":
                    continue
                m = seg == s
                if not m.any():
                    continue
                phi = sig * rng.standard_normal(3)
                R = rotvec_to_dcm(-phi)  # body frame turned by phi: inputs seen as exp(-[phi x]) x
                for sensor, cols in _COLS.items():
                    mod = models[sensor]
                    rate = out[m, cols] / dt
                    x = mod.inverse(rate)
                    out[m, cols] = mod.forward(x @ R.T) * dt
            continue
        sensor = e.get("sensor", "accel")
        if sensor not in _COLS:
            raise ValueError(f"unmodelled effect {name!r}: sensor {sensor!r}, accel or gyro")
        mod, i, col = models[sensor], _axis(e), _COLS[sensor].start + _axis(e)
        if name == "scale_drift":
            x = mod.inverse(out[:, _COLS[sensor]] / dt)
            ke_x = x @ mod.KE.T
            out[:, col] += float(e["ppm"]) * 1e-6 * (t / T) * ke_x[:, i] * dt
        elif name == "periodic_bias":
            amp = float(e["amplitude"]) * _SMALL_UNIT[sensor]
            out[:, col] += mod.K[i] * amp * np.sin(2.0 * math.pi * t / float(e["period_s"])) * dt
        elif name == "bias_step":
            step = float(e["step"]) * _SMALL_UNIT[sensor]
            out[:, col] += mod.K[i] * step * (t >= float(e.get("at_fraction", 0.5)) * T) * dt
        elif name == "quartic":
            if sensor != "accel":
                raise ValueError("quartic: accelerometers only")
            x = mod.inverse(out[:, _COLS[sensor]] / dt)
            out[:, col] += mod.K[i] * float(e["k4_ug_per_g4"]) * 1e-6 * x[:, i] ** 4 * dt
    return out


def inject_per_seed(sim, clean: np.ndarray, spec: list[dict], seed: int) -> np.ndarray:
    """``clean`` with the effects of ``spec`` that are drawn per noise seed (:data:`PER_SEED`) added for ``seed``;
    ``clean`` itself when ``spec`` holds none."""
    todo = [e for e in spec if e.get("effect") in PER_SEED]
    if not todo:
        return clean
    out = np.array(clean, dtype=np.float64, copy=True)
    dt = 1.0 / float(sim.sample_rate_hz)
    models = {"accel": sim.accel, "gyro": sim.gyro}
    for k, e in enumerate(todo):
        sensor = e.get("sensor", "accel")
        if sensor not in _COLS:
            raise ValueError(f"unmodelled effect {e['effect']!r}: sensor {sensor!r}, accel or gyro")
        i = _axis(e)
        rng = seeds.stream(int(seed), "unmodelled_random_walk", k)
        walk = np.cumsum(float(e["q"]) * _SMALL_UNIT[sensor] * math.sqrt(dt) * rng.standard_normal(len(out)))
        out[:, _COLS[sensor].start + i] += models[sensor].K[i] * walk * dt
    return out
