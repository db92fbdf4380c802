"""The numbers behind the report, on calib's synthetic data with known truth."""

from __future__ import annotations

import numpy as np
import pytest

import calib
from calib import synthetic
from rig.analysis import heldout


def _fit(ds, model):
    return calib.fit(ds, model, robust=True)


@pytest.fixture(scope="module")
def t24_data():
    rng = np.random.default_rng(11)
    ds, truth = synthetic.t24_dataset(rng, temps_c=(-20.0, 10.0, 40.0), samples_per_point=4, noise_nt=10.0)
    ds.columns["point"] = np.array([f"T{g}-F{i // 4}" for i, g in enumerate(ds.group)])
    return ds, truth


def test_coverage_gaps_none_for_a_full_sphere():
    assert heldout.coverage_gaps(heldout.fibonacci_directions(100) * 5e4) == []


def test_coverage_gaps_found_in_the_empty_hemisphere():
    d = heldout.fibonacci_directions(300)
    gaps = heldout.coverage_gaps(d[d[:, 2] > 0.2] * 5e4)
    assert gaps, "the lower hemisphere is empty"
    assert all(el < 0 for _, el, _ in gaps)
    assert max(g[2] for g in gaps) > 90  # the south pole is > 90 deg from any sample


def test_nearest_sample_angle():
    got = heldout.nearest_sample_deg(
        np.array([[0.0, 0, 1], [1.0, 0, 0]]), np.array([[1.0, 0, 0], [0, 1.0, 1.0]])
    )
    np.testing.assert_allclose(got, [45.0, 0.0], atol=0.05)  # directions are deduplicated at 1e-3


def test_steps_from_integer_groups_plan_ids_or_temperatures():
    ds = calib.Dataset(
        h_nt=np.zeros((4, 3)),
        temp_c=np.array([25.0, 25.2, -10.0, 60.0]),
        ref_nt=None,
        group=np.array([3, 3, 1, 5]),
    )
    assert heldout.step_of_each_row(ds).tolist() == [3, 3, 1, 5]
    ds.group = np.array(["T02-F01", "T02-F02", "T01-F01", "T07-O03"])
    assert heldout.step_of_each_row(ds).tolist() == [2, 2, 1, 7]
    ds.group = None
    assert heldout.step_of_each_row(ds).tolist() == [2, 2, 1, 3]  # numbered by temperature


def test_folds_keep_points_together(t24_data):
    ds, _ = t24_data
    folds, text = heldout.fold_of_each_row(ds, labels=ds.columns["point"])
    assert "5-fold over" in text and set(folds.tolist()) == {0, 1, 2, 3, 4}
    for p in np.unique(ds.columns["point"]):
        assert len(set(folds[ds.columns["point"] == p].tolist())) == 1


def test_folds_without_labels_are_contiguous_blocks(t24_data):
    ds, _ = t24_data
    folds, text = heldout.fold_of_each_row(ds)
    assert "contiguous blocks" in text
    assert np.count_nonzero(np.diff(folds)) <= 19  # 20 blocks


def test_cross_validation_ranks_the_models(t24_data):
    ds, _ = t24_data
    folds, _ = heldout.fold_of_each_row(ds, labels=ds.columns["point"])
    t24 = heldout.cross_validate(ds, "t24", _fit, folds, _fit(ds, "t24"))
    p12 = heldout.cross_validate(ds, "p12", _fit, folds, _fit(ds, "p12"))
    # vector RMS of pure 10 nT noise per axis: held-out a little above the fitted value
    assert 9.0 < t24.fit_vector_rms < t24.heldout_vector_rms < 12.0
    assert t24.folds == 5 and t24.note == ""
    assert p12.heldout_vector_rms > 5 * t24.heldout_vector_rms  # P12 has no temperature terms


def test_cross_validation_reports_folds_that_cannot_be_fitted():
    rng = np.random.default_rng(3)
    ds, _ = synthetic.t24_dataset(rng, temps_c=(20.0, 40.0), samples_per_point=2)
    folds = (ds.temp_c > 30).astype(int)  # each fold holds one temperature: T24 cannot fit the other
    score = heldout.cross_validate(ds, "t24", _fit, folds)
    assert score.folds == 0 and "2 fold(s) could not be fitted" in score.note
    assert np.isnan(score.heldout_vector_rms)


def test_outliers_of_a_calibration_read_from_file(t24_data):
    ds, truth = t24_data
    bad = ds.subset(slice(None))
    bad.h_nt = bad.h_nt.copy()
    bad.h_nt[[5, 50, 300]] += 3000.0
    err = heldout.errors(bad, truth)  # truth has no outlier flags, like a loaded calibration
    assert np.flatnonzero(heldout.outlier_rows(truth, err)).tolist() == [5, 50, 300]


def test_errors_before_and_after(t24_data):
    ds, truth = t24_data
    e = heldout.errors(ds, truth)
    np.testing.assert_allclose(e.vector_before, ds.h_nt - ds.ref_nt)
    assert heldout.rms(e.vector_after) < 15 < heldout.rms(e.vector_before)
    scalar = calib.Calibration("scalar", {"A": np.eye(3), "c_nt": np.zeros(3)}, {})
    assert heldout.errors(ds, scalar).vector_after is None  # known only up to a rotation


def test_step_table(t24_data):
    ds, truth = t24_data
    err = heldout.errors(ds, truth)
    flagged = np.zeros(len(ds), bool)
    flagged[:3] = True
    rows = heldout.step_table(ds, flagged, err)
    assert [r.step for r in rows] == [0, 1, 2]
    assert [round(r.temp_c) for r in rows] == [-20, 10, 40]
    assert sum(r.samples for r in rows) == len(ds) and rows[0].outliers == 3


def test_systematic_error_by_point():
    d = np.array([[1.0, 0, 0], [3.0, 0, 0], [0, 2.0, 0], [0, 4.0, 0], [0, 9.0, 0]])
    res = np.array([[3.0, 0, 0], [5.0, 0, 0], [1.0, 1.0, 0], [-1.0, 1.0, 0], [500.0, 0, 0]])
    keep = np.array([True, True, True, True, False])  # the outlier row is left out
    groups = np.array(["a", "a", "b", "b", "b"])
    mean_dir, err, per_point = heldout.systematic_error_by_point(groups, d, res, keep)
    assert per_point
    np.testing.assert_allclose(mean_dir, [[2, 0, 0], [0, 3, 0]])
    np.testing.assert_allclose(err, [4.0, 1.0])  # |mean residual|: the +-1 in x of point b cancels
    _, err, per_point = heldout.systematic_error_by_point(None, d, res, keep)
    assert not per_point and err.tolist() == pytest.approx([3, 5, np.sqrt(2), np.sqrt(2)])
