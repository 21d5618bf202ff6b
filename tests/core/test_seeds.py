"""The seed helper: named child streams are reproducible, independent of draw order, and distinct."""
import numpy as np
import pytest

from calib.core import seeds


def test_same_path_same_numbers_and_order_independent():
    a = seeds.stream(42, "method", "ide", 3).standard_normal(5)
    seeds.stream(42, "other").standard_normal(1000)  # drawing elsewhere first changes nothing
    b = seeds.stream(42, "method", "ide", 3).standard_normal(5)
    assert np.array_equal(a, b)


def test_paths_that_offsets_would_collide_are_distinct():
    # the old "seed + 1000 * i + r" scheme gave run 1000 of method 0 the seed of run 0 of method 1
    x = {seeds.child_seed(1000, "method", m, "run", r) for m in ("de", "ide") for r in range(1001)}
    assert len(x) == 2 * 1001
    assert seeds.child_seed(1, "a") != seeds.child_seed(2, "a") != seeds.child_seed(1, "b")


def test_streams_are_uncorrelated():
    u = seeds.stream(7, "noise", 0).standard_normal(200_000)
    v = seeds.stream(7, "noise", 1).standard_normal(200_000)
    assert abs(np.corrcoef(u, v)[0, 1]) < 5 / np.sqrt(200_000)  # 5 sigma of the null correlation


def test_child_seed_is_the_stream_and_fits_int64():
    s = seeds.child_seed(3, "session", 4)
    assert 0 <= s < 2**63
    assert np.array_equal(np.random.default_rng(seeds.seed_sequence(3, "session", 4)).random(3),
                          seeds.stream(3, "session", 4).random(3))


@pytest.mark.parametrize("bad", [-1, "", True, 1.5, None])
def test_bad_names_refused(bad):
    with pytest.raises((TypeError, ValueError)):
        seeds.stream(1, bad)
