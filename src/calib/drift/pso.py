"""Particle swarm optimisation for gyro-drift estimation (He 2019 §III, eqs. 16-19).

Particles are gyro-drift triplets [deg/h] in the body frame. The swarm *maximises* a fitness; He 2019 uses
the navigation-error functional J of eq. (18), which is minimised, so the fitness used here is ``-J`` and
the history stores ``J`` of the global best (He 2019 Figure 3 plots a fitness that decreases).

Two variants, chosen in config:

* ``paper`` — eqs. (16)-(17) with the paper's settings: c1 = c2 = 1, r1 = r2 = 1 (deterministic pulls),
  inertia w = 1, velocity clamped to [v_min, v_max] = +-0.1/100 deg/h, positions kept inside the search
  range [-0.03, 0.03] deg/h by clipping (He 2019 does not say how it treats the range; clipping is ours).
  Initial velocities: zero (not stated in the paper).
* ``standard`` — the common PSO of Shi & Eberhart (1998): r1, r2 ~ U(0, 1) per particle and dimension,
  inertia decreasing linearly from w_start to w_end, c1 = c2 = 2 by default, same clamp and range.

Every random draw comes from the ``numpy.random.Generator`` passed in.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class PSOSettings:
    particles: int = 30
    generations: int = 50
    c1: float = 1.0
    c2: float = 1.0
    variant: str = "paper"  # paper | standard
    r1: float = 1.0  # paper variant only
    r2: float = 1.0
    inertia: float = 1.0  # paper variant
    w_start: float = 0.9  # standard variant
    w_end: float = 0.4
    v_max: float = 0.1 / 100  # deg/h
    lower: float = -0.03  # deg/h
    upper: float = 0.03

    @classmethod
    def from_config(cls, d: dict) -> "PSOSettings":
        s = cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})
        if s.variant not in ("paper", "standard"):
            raise ValueError(f"pso.variant: {s.variant!r} is not 'paper' or 'standard'")
        if not s.lower < s.upper:
            raise ValueError(f"pso search range: lower {s.lower} must be below upper {s.upper}")
        return s


@dataclass
class PSOResult:
    best: np.ndarray  # (D,) global best position
    best_cost: float  # J at the global best
    history: np.ndarray  # (G+1,) J of the global best after each generation (index 0: initial swarm)
    positions: np.ndarray  # (G+1, P, D) swarm positions per generation
    n_evaluations: int
    pinned: list = field(default_factory=list)  # dims whose best sits on a bound of the search range


def minimize(cost, rng: np.random.Generator, settings: PSOSettings, dim: int = 3, progress=None) -> PSOResult:
    """Minimise ``cost(X) -> (P,)`` over particles ``X (P, dim)`` with PSO (He 2019 eqs. 16-17).

    ``cost`` is evaluated once per generation on the whole swarm (the navigation of all particles runs in
    one compiled pass). Returns the global best and the per-generation history.
    """
    s = settings
    P, G = s.particles, s.generations
    lo, hi = np.full(dim, s.lower), np.full(dim, s.upper)
    x = lo + rng.random((P, dim)) * (hi - lo)
    v = np.zeros((P, dim))
    c = np.asarray(cost(x), dtype=float)
    pbest, pcost = x.copy(), c.copy()
    g = int(np.argmin(pcost))
    gbest, gcost = pbest[g].copy(), float(pcost[g])
    hist = [gcost]
    traj = [x.copy()]
    for m in range(G):
        if s.variant == "paper":
            w, r1, r2 = s.inertia, s.r1, s.r2
        else:
            w = s.w_start + (s.w_end - s.w_start) * m / max(G - 1, 1)
            r1, r2 = rng.random((P, dim)), rng.random((P, dim))
        v = w * v + s.c1 * r1 * (pbest - x) + s.c2 * r2 * (gbest - x)  # eq. 16
        np.clip(v, -s.v_max, s.v_max, out=v)  # velocity limit of He 2019 §III.A
        x = np.clip(x + v, lo, hi)  # eq. 17, kept in the search range
        c = np.asarray(cost(x), dtype=float)
        better = c < pcost
        pbest[better], pcost[better] = x[better], c[better]
        g = int(np.argmin(pcost))
        if pcost[g] < gcost:
            gbest, gcost = pbest[g].copy(), float(pcost[g])
        hist.append(gcost)
        traj.append(x.copy())
        if progress is not None:
            progress(m + 1)
    span = hi - lo
    pinned = [d for d in range(dim) if min(gbest[d] - lo[d], hi[d] - gbest[d]) <= 1e-9 * span[d]]
    return PSOResult(gbest, gcost, np.array(hist), np.array(traj), P * (G + 1), pinned)


def accuracy(estimate, reference):
    """Estimation accuracy Ac = (1 - |(eta_e - eta_i) / eta_i|) x 100 % (He 2019 eq. 19)."""
    estimate, reference = np.asarray(estimate, float), np.asarray(reference, float)
    return (1.0 - np.abs((estimate - reference) / reference)) * 100.0
