"""The one identifiability SVD (calib.calibration.identifiability): column scaling, rank, condition and the
weakest direction on Jacobians whose answers are known in closed form."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calib.calibration import identifiability as idf


def test_column_scaled_divides_by_norms_or_multiplies_by_scale():
    J = np.array([[3.0, 0.0, 1.0], [4.0, 0.0, -1.0]])
    np.testing.assert_allclose(idf.column_scaled(J), [[0.6, 0.0, 1 / math.sqrt(2)], [0.8, 0.0, -1 / math.sqrt(2)]])
    np.testing.assert_array_equal(idf.column_scaled(J, [2.0, 5.0, -1.0]), [[6.0, 0.0, -1.0], [8.0, 0.0, 1.0]])


def test_orthogonal_columns_of_any_size_are_perfectly_conditioned():
    Q = np.linalg.qr(np.random.default_rng(0).normal(size=(8, 4)))[0]
    r = idf.rank_summary(Q * [1e-6, 1.0, 3e4, 7.0], ("a", "b", "c", "d"))
    assert r.rank == 4 and r.n_params == 4
    np.testing.assert_allclose(r.singular_values, 1.0, rtol=1e-12)
    assert r.condition == pytest.approx(1.0, rel=1e-12)


def test_proportional_columns_give_one_null_direction():
    rng = np.random.default_rng(1)
    J = rng.normal(size=(10, 3))
    J[:, 2] = -4.0 * J[:, 0]  # after scaling column c is -a: a + c is invisible
    r = idf.rank_summary(J, ("a", "b", "c"), based_on="test")
    assert r.rank == 2 and r.singular_values[-1] < 1e-12 and r.condition > 1e12
    w = r.weakest
    assert w["a"] == pytest.approx(w["c"], abs=1e-12) and w["a"] == pytest.approx(1 / math.sqrt(2), abs=1e-12)
    assert w["b"] == pytest.approx(0.0, abs=1e-12)
    assert r.as_dict()["weakest_direction"] == {"a": 0.7071, "c": 0.7071}
    assert r.describe().startswith("rank 2 of 3")


def test_fewer_observations_than_parameters_pad_with_zeros():
    r = idf.rank_summary(np.array([[1.0, 2.0, 3.0]]), ("a", "b", "c"))
    assert r.rank == 1 and list(r.singular_values) == [1.0, 0.0, 0.0] and r.condition == math.inf


def test_null_space_report_and_rank_summary_agree():
    """analyze_jacobian with scale = 1/column norm is the same SVD as rank_summary."""
    rng = np.random.default_rng(2)
    J = rng.normal(size=(12, 5)) * [1.0, 1e3, 1e-3, 5.0, 1.0]
    J[:, 4] = J[:, 0] / 3.0 + J[:, 3] / 5.0
    s = 1.0 / np.linalg.norm(J, axis=0)
    rep = idf.analyze_jacobian(J, list("abcde"), s, rtol=1e-6)
    summ = idf.rank_summary(J, list("abcde"), rtol=1e-6)
    assert rep.rank == summ.rank == 4
    np.testing.assert_allclose(rep.singular_values / rep.singular_values[0], summ.singular_values, atol=1e-12)
