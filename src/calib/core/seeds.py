"""The one seed helper: every random draw of ``calib`` comes from a root seed and a path of stream names.

A study config holds a few root seeds (``seeds: {data: ..., calibration: ..., drift: ..., diagnosis: ...}``).
Everything random below a root is a *named child stream*: ``stream(root, "static_check")``,
``stream(root, "method", "ide", "run", 3)``. The path is turned into a ``numpy.random.SeedSequence`` spawn
key (each name by a stable hash, each integer as itself), so

* two streams with different paths are statistically independent (the SeedSequence guarantee), however close
  their numbers look: no ``seed + 1000 * i + r`` arithmetic, which collides as soon as a count grows past an
  offset;
* a stream depends only on its root and path, not on how many other streams were drawn before it, so a stage
  rerun alone, a sweep point or a worker process draws exactly the numbers it would draw in the full study.

:func:`child_seed` gives the same stream as a plain integer for the places that hand a seed on (a file
attribute, a worker process, the simulator's own streams).
"""
from __future__ import annotations

import hashlib

import numpy as np

__all__ = ["name_key", "seed_sequence", "stream", "child_seed", "SESSIONS", "session_seed"]


def name_key(name) -> int:
    """The spawn-key entry of one path element: an integer as itself, a string by a stable 32-bit hash."""
    if isinstance(name, (bool, np.bool_)):
        raise TypeError("a stream name is a string or a non-negative integer, not a bool")
    if isinstance(name, (int, np.integer)):
        if name < 0:
            raise ValueError(f"stream index must be >= 0, got {name}")
        return int(name)
    if isinstance(name, str) and name:
        return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")
    raise TypeError(f"a stream name is a non-empty string or a non-negative integer, got {name!r}")


def seed_sequence(root, *path) -> np.random.SeedSequence:
    """``SeedSequence(root, spawn_key=path)`` with the names of ``path`` as :func:`name_key` integers."""
    if isinstance(root, np.random.SeedSequence):
        return np.random.SeedSequence(root.entropy, spawn_key=tuple(root.spawn_key) + tuple(map(name_key, path)))
    return np.random.SeedSequence(int(root), spawn_key=tuple(name_key(p) for p in path))


def stream(root, *path) -> np.random.Generator:
    """The generator (PCG64) of the named child stream ``path`` of ``root``."""
    return np.random.Generator(np.random.PCG64(seed_sequence(root, *path)))


def child_seed(root, *path) -> int:
    """A 63-bit integer seed for the named child stream ``path`` of ``root`` (to hand on as a number)."""
    return int(seed_sequence(root, *path).generate_state(2, np.uint32).view(np.uint64)[0] >> np.uint64(1))


#: the synthetic sessions of a study; each draws its noise from the named child stream of ``seeds.data``
SESSIONS = ("calibration_session", "static_check", "navigation_session", "calibration_z", "drift_noise_seeds")


def session_seed(data_seed: int, session: str) -> int:
    """The seed of one synthetic session of a study: the child stream ``session`` of the root ``seeds.data``."""
    if session not in SESSIONS:
        raise ValueError(f"unknown session {session!r}; one of {', '.join(SESSIONS)}")
    return child_seed(int(data_seed), session)
