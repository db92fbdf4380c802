"""The compact form of an offset per group of rows (calib/uncertainty/rowgroups.py) gives what the dense a_ref
gives: the Jacobians of every linearised model, the budget's lines and its Monte Carlo draws."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.dataset import Dataset
from calib.uncertainty.budgeting import _by_quantity, _scalar_data, budget
from calib.uncertainty.linearise import linearised
from calib.uncertainty.propagation import InputSource
from calib.uncertainty.rowgroups import RowGroups


def _groups(n: int, k: int, seed: int) -> np.ndarray:
    index = np.random.default_rng(seed).integers(0, k, n)
    index[index == 2] = 3  # a group without rows
    return index


def _cases():
    ds, _ = synthetic.t24_dataset(np.random.default_rng(3), temps_c=(-20.0, 25.0, 60.0), samples_per_point=2)
    yield ds, "t24"
    yield ds, "p12"
    rng = np.random.default_rng(5)
    ref = rng.normal(size=(600, 3))
    ref *= 50_000.0 / np.linalg.norm(ref, axis=1, keepdims=True)
    a = np.eye(3) * 1.02 + np.triu(rng.normal(0, 0.01, (3, 3)), 1)
    h = np.linalg.solve(a, ref.T).T + np.array([100.0, -50.0, 30.0]) + rng.normal(0, 10.0, ref.shape)
    yield Dataset(h, None, ref), "scalar"


@pytest.mark.parametrize("case", range(3))
def test_compact_jacobian_is_the_dense_one(case):
    ds, model = list(_cases())[case]
    cal = calib.fit(ds, model)
    lin = linearised(ds, cal, None)
    groups = RowGroups.offsets(_groups(len(ds), 6, case), 6)
    dense, compact = lin.ref_jacobian(groups.dense()), lin.ref_jacobian(groups)
    assert np.any(np.abs(dense) > 0)
    np.testing.assert_allclose(compact, dense, rtol=1e-9, atol=1e-12 * np.max(np.abs(dense)))


def test_sums_and_rows_agree_with_the_dense_array():
    index = _groups(300, 5, 1)
    groups = RowGroups.offsets(index, 5)
    values = np.random.default_rng(2).normal(size=(300, 4, 3))
    expected = np.stack([values[index == k].sum(axis=0) for k in range(5)])
    np.testing.assert_allclose(groups.sums(values), expected, rtol=1e-12, atol=1e-12)
    q = np.random.default_rng(3).normal(size=(7, 15))
    np.testing.assert_array_equal(groups.rows_times(q), np.einsum("niq,mq->mni", groups.dense(), q))
    m, n = 7, 300
    rng_a, rng_b = np.random.default_rng(4), np.random.default_rng(4)
    compact = _scalar_data(rng_a, [(q, groups, None)], m, n, None)[1]
    dense = _scalar_data(rng_b, [(q, _by_quantity(groups.dense(), n), None)], m, n, None)[1]
    np.testing.assert_allclose(compact, dense, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("model", ["t24", "p12"])
def test_budget_lines_match_with_the_compact_form(model):
    ds, _ = synthetic.t24_dataset(np.random.default_rng(8), temps_c=(-20.0, 25.0, 60.0), samples_per_point=2)
    cal = calib.fit(ds, model)
    groups = RowGroups.offsets(_groups(len(ds), 4, 9), 4)
    sigma = np.diag(np.full(12, 25.0))
    fields = 50_000.0 * synthetic.coil_directions()
    grid = (np.repeat(fields, 2, axis=0), np.tile([-20.0, 60.0], len(fields)))
    out = []
    for a in (groups, groups.dense()):
        source = InputSource("wander", sigma, ref_nt=a, distribution="rectangular")
        b = budget(ds, cal, [source], grid, rng=np.random.default_rng(11), monte_carlo="always")
        out.append(b)
    lines = [{c["source"]: c["contribution_nt"] for c in b.contributions} for b in out]
    assert lines[0]["wander"] > 0
    for name in lines[1]:
        assert lines[0][name] == pytest.approx(lines[1][name], rel=1e-9)
    assert out[0].expanded_vector_error_nt == pytest.approx(out[1].expanded_vector_error_nt, rel=1e-9)


def test_a_wrong_shape_is_named():
    ds, _ = synthetic.t24_dataset(np.random.default_rng(8), temps_c=(-20.0, 60.0))
    groups = RowGroups.offsets(np.zeros(len(ds) - 1, int), 1)
    source = InputSource("wander", np.eye(3), ref_nt=groups)
    with pytest.raises(calib.errors.DataError, match="wander.*shape"):
        source.sensitivities(ds)
    assert dataclasses.replace(source, ref_nt=RowGroups.offsets(np.zeros(len(ds), int), 1)).sensitivities(ds)
