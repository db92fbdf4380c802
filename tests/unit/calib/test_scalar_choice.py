"""The scalar fit's options chosen by blocked cross-validation inside the rows it is given."""

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.models import scalar_choice


def _held_out_error_pct(cal, ds) -> float:
    return scalar_choice.norm_error_pct(cal.apply(ds.h_nt, ds.temp_c), ds.ref_norm_nt)


def test_uniform_coverage_leaves_nothing_to_choose():
    ds, _ = synthetic.scalar_dataset(np.random.default_rng(10), n=3000)
    cal = calib.fit(ds, "scalar")
    assert cal.stats["coverage_effective_share"] > 0.9
    assert not cal.stats["balance_orientations"] and not cal.stats["temperature_terms"]
    assert "validation" not in cal.stats  # balancing is not even a candidate


def test_uneven_coverage_with_white_noise_keeps_the_plain_fit():
    # dwell on the upper hemisphere. With white noise and the right model, the unweighted fit is the
    # efficient one (balancing only adds variance): validation must not be fooled by the coverage alone
    ds, truth = synthetic.scalar_dataset(np.random.default_rng(10), n=3000)
    up = truth.apply(ds.h_nt)[:, 2] > 0
    uneven = ds.subset(up | (np.arange(len(ds)) % 8 == 0))
    cal = calib.fit(uneven, "scalar")
    assert cal.stats["coverage_effective_share"] < 0.8
    record = cal.stats["validation"]
    assert set(record["scores_pct"]) == {"plain", "balanced"}
    assert all(len(s) == scalar_choice.FOLDS for s in record["scores_pct"].values())
    assert record["chosen"] == "plain" and not cal.stats["balance_orientations"]
    assert "folds" in record["verdicts"]["balanced"]
    plain = calib.fit(uneven, "scalar", balance_orientations=False)
    np.testing.assert_array_equal(cal.params["A"], plain.params["A"])


def test_temperature_terms_are_chosen_when_the_sensor_drifts_with_temperature():
    ds, truth = synthetic.scalar_dataset(np.random.default_rng(7), n=800, temps_c=[-20.0, 25.0, 70.0])
    cal = calib.fit(ds, "scalar")
    record = cal.stats["validation"]
    assert record["chosen"] == "temperature" and cal.stats["temperature_terms"]
    assert record["mean_pct"]["temperature"] < 0.5 * record["mean_pct"]["plain"]
    fresh, _ = synthetic.scalar_dataset(np.random.default_rng(70), params=truth.params, n=800,
                                        temps_c=[-10.0, 40.0])
    without = calib.fit(ds, "scalar", temperature_terms=False)
    assert _held_out_error_pct(cal, fresh) < 0.5 * _held_out_error_pct(without, fresh)


def test_temperature_terms_are_left_out_when_the_sensor_does_not_drift():
    params = synthetic.random_scalar_params(np.random.default_rng(8))  # no KA, no kc
    rng = np.random.default_rng(9)
    ds, _ = synthetic.scalar_dataset(rng, params=params, n=1500)
    ds.temp_c = np.repeat([-20.0, 25.0, 70.0], 500)  # a span, but nothing depends on it
    cal = calib.fit(ds, "scalar")
    assert cal.stats["validation"]["chosen"] == "plain"
    assert not cal.stats["temperature_terms"] and "KA_per_c" not in cal.params
    assert calib.fit(ds, "scalar", temperature_terms=True).stats["temperature_terms"]  # given: obeyed


@pytest.mark.parametrize(
    ("gains", "chosen"),
    [
        ([0.05, 0.04, 0.06, 0.05, 0.05], "balanced"),  # lower in every fold, far beyond the noise
        ([0.05, 0.04, 0.06, 0.05, -0.01], "plain"),  # worse in one fold
        ([0.001, 0.2, 0.001, 0.3, 0.001], "plain"),  # lower everywhere, but the gain is mostly noise
    ],
)
def test_an_alternative_must_win_every_fold_clearly(gains, chosen):
    plain = np.array([0.50, 0.42, 0.61, 0.47, 0.55])
    name, verdicts = scalar_choice.decide({"plain": plain, "balanced": plain - np.array(gains)}, "plain")
    assert name == chosen
    assert f"{sum(g > 0 for g in gains)} of 5 folds" in verdicts["balanced"]


def test_the_best_of_several_qualifying_alternatives_wins():
    plain = np.array([0.50, 0.42, 0.61, 0.47, 0.55])
    scores = {"plain": plain, "balanced": plain - 0.05, "temperature": plain - 0.2}
    assert scalar_choice.decide(scores, "plain")[0] == "temperature"


def test_folds_are_interleaved_contiguous_blocks():
    fold = scalar_choice.fold_of_rows(1000)
    assert np.bincount(fold).tolist() == [200] * scalar_choice.FOLDS
    held = np.flatnonzero(fold == 0)
    blocks = np.split(held, np.flatnonzero(np.diff(held) > 1) + 1)
    assert len(blocks) == scalar_choice.BLOCKS_PER_FOLD  # contiguous stretches, spread over the rows
    assert blocks[0][0] == 0 and blocks[1][0] == 1000 // scalar_choice.BLOCKS_PER_FOLD


def test_robust_validation_leaves_the_outliers_out():
    ds, truth = synthetic.scalar_dataset(np.random.default_rng(11), n=3000, outlier_fraction=0.01)
    up = truth.apply(ds.h_nt)[:, 2] > 0
    uneven = ds.subset(up | (np.arange(len(ds)) % 8 == 0))
    cal = calib.fit(uneven, "scalar", robust=True)
    record = cal.stats["validation"]
    assert record["chosen"] == "plain"
    # scores of clean rows: near the 10 nT noise on 50000 nT (0.02 %), not the outliers' 5000 nT
    assert max(max(s) for s in record["scores_pct"].values()) < 0.05
    assert cal.stats["n_outliers"] >= int(uneven.columns["is_outlier"].sum())


def test_too_few_rows_for_folds_keep_the_plain_variant():
    ds, _ = synthetic.scalar_dataset(np.random.default_rng(12), n=8, temps_c=[0.0, 40.0])
    cal = calib.fit(ds, "scalar")
    assert cal.stats["validation"]["chosen"] == "plain"
    assert "not identifiable in fold" in cal.stats["validation"]["verdicts"]["temperature"]
