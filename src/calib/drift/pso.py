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

A particle's cost depends on its own position only, so a position the swarm has already visited is not
evaluated again (:class:`RowMemo`): in the paper variant particles often come to rest on their personal or the
global best, and about a third of the evaluations of a run repeat an earlier one. The costs, and so every
number of the run, are the same as with every evaluation done.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib.calibration.optimizers import particle_swarm


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


class RowMemo:
    """``cost(X) -> (P,)`` evaluated only on the rows of ``X`` not seen before (in one call per generation).

    ``cost`` must be row-wise: the cost of a row depends on that row alone, bit for bit, whatever the other rows
    of the call (true of :class:`calib.drift.psobe.NavigationCost`: its streams are navigated independently).
    Rows are matched by their exact bytes. ``evaluated`` counts the rows passed to ``cost``.
    """

    def __init__(self, cost):
        self.cost = cost
        self.seen: dict[bytes, float] = {}
        self.evaluated = 0

    def __call__(self, X) -> np.ndarray:
        X = np.ascontiguousarray(X, dtype=float)
        keys = [row.tobytes() for row in X]
        new = {}
        for i, k in enumerate(keys):
            if k not in self.seen and k not in new:
                new[k] = i
        if new:
            idx = np.fromiter(new.values(), dtype=np.intp, count=len(new))
            c = np.asarray(self.cost(X[idx]), dtype=float).reshape(-1)
            if c.size != idx.size:
                raise ValueError(f"cost returned {c.size} values for {idx.size} particles")
            self.evaluated += idx.size
            self.seen.update(zip(new, c.tolist()))
        return np.array([self.seen[k] for k in keys], dtype=float)


def minimize(cost, rng: np.random.Generator, settings: PSOSettings, dim: int = 3, progress=None) -> PSOResult:
    """Minimise ``cost(X) -> (P,)`` over particles ``X (P, dim)`` with PSO (He 2019 eqs. 16-17).

    ``cost`` is evaluated once per generation on the swarm's positions not visited before (:class:`RowMemo`; the
    navigation of those particles runs in one compiled pass), so it must be row-wise. Returns the global best
    and the per-generation history.
    """
    s = settings
    lo, hi = np.full(dim, s.lower), np.full(dim, s.upper)
    paper = s.variant == "paper"
    sw = particle_swarm(RowMemo(cost), lo, hi, rng, s.particles, s.generations,
                        c1=s.c1, c2=s.c2, vlim=s.v_max,  # velocity limit of He 2019 §III.A
                        inertia=s.inertia if paper else (s.w_start, s.w_end),
                        fixed_coefficients=(s.r1, s.r2) if paper else None, init_velocity="zero",
                        gbest_update="strict", keep_trajectory=True, progress=progress)
    span = hi - lo
    pinned = [d for d in range(dim) if min(sw.gbest[d] - lo[d], hi[d] - sw.gbest[d]) <= 1e-9 * span[d]]
    return PSOResult(sw.gbest, sw.gcost, sw.history, sw.trajectory, sw.nfev, pinned)


def accuracy(estimate, reference):
    """Estimation accuracy Ac = (1 - |(eta_e - eta_i) / eta_i|) x 100 % (He 2019 eq. 19)."""
    estimate, reference = np.asarray(estimate, float), np.asarray(reference, float)
    return (1.0 - np.abs((estimate - reference) / reference)) * 100.0
