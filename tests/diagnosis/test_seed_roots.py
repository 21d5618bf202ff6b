"""The proofs' seeds by construction (config/seed_roots.yaml): the study's, the .test and the held-out proof run on
roots no tuning used, and no stream they draw is one a tuning root or a test drew -- compared stream by stream (the
named child streams calib.core.seeds derives from each root), not only as root integers."""
from __future__ import annotations

from pathlib import Path

import yaml

from calib.core import seeds
from calib.studies.diagnosis_proof import proof_streams

ROOT = Path(__file__).resolve().parents[2]
ROOTS = yaml.safe_load((ROOT / "config" / "seed_roots.yaml").read_text())
CONFIGS = {"study": ROOT / "config" / "config.yaml", "test": ROOT / ".test" / "config.yaml",
           "heldout": ROOT / "config" / "proof_heldout.yaml"}
#: the recordings a real-recording proof can run on (each seeds its limits and its proof by its name)
RECORDINGS = sorted(p.stem for p in (ROOT / "config" / "import").glob("*.yaml"))
#: how far the tuning roots' streams are compared: ten times the seeds of the largest configured proof
TUNING_DRAWS = 1000


def _proof_counts(path) -> tuple[int, int]:
    pr = ((yaml.safe_load(path.read_text()).get("diagnosis") or {}).get("proof") or {})
    return int(pr.get("n_seeds", 0)), int(pr.get("power_seeds", 0))


def _streams(root: int, n_seeds: int, power_seeds: int) -> set[int]:
    """The seed of every stream a proof with root ``root`` draws: the simulator seeds of the concealed-effect proof
    and the child seeds the real-recording proof draws its limits and injections from."""
    st = proof_streams(root, n_seeds, power_seeds)
    sim = {st["template"], *st["noise"], *st["power"]}
    real = {seeds.child_seed(root, part, name) for part in ("limits", "proof") for name in RECORDINGS}
    return sim | real


def test_the_configurations_use_the_listed_proof_roots():
    for name, path in CONFIGS.items():
        assert yaml.safe_load(path.read_text())["seeds"]["diagnosis"] == ROOTS["proof"][name], path


def test_proof_roots_are_fresh_and_distinct():
    proof = list(ROOTS["proof"].values())
    assert len(set(proof)) == len(proof)
    assert not set(proof) & set(ROOTS["tuning"]["roots"])


def test_no_stream_a_proof_draws_was_drawn_by_tuning():
    """Every stream of every proof root (its configured seed counts) against every stream of every tuning root up
    to ten times those counts and the tests' own simulator seeds: disjoint, and each proof's streams disjoint from
    the other proofs'."""
    tuning = set()
    for r in ROOTS["tuning"]["roots"]:
        tuning |= _streams(r, TUNING_DRAWS, TUNING_DRAWS) | {r}
    drawn = {}
    for name, path in CONFIGS.items():
        n, p = _proof_counts(path)
        assert n > 0, path
        drawn[name] = _streams(ROOTS["proof"][name], n, p)
        assert len(drawn[name]) == 1 + n + p + 2 * len(RECORDINGS), name    # no two streams of one proof coincide
        assert not drawn[name] & tuning, name
        assert min(drawn[name]) >= ROOTS["tuning"]["simulator_seeds_below"], name
    names = list(drawn)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not drawn[a] & drawn[b], (a, b)
