"""T24 or T36 by blocked cross-validation (calib/models/tempmodel.py)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.dataset import Dataset
from calib.errors import DataError
from calib.models.tempmodel import blocks_within_steps, choose_temperature_model
from calib.synthetic import t24_dataset

TEMPS_C = (-30.0, -5.0, 20.0, 45.0, 70.0)


def test_t24_data_keep_t24_and_curved_data_choose_t36():
    """20 seeds each. T36 validates better in all 5 folds of T24 data by chance far less often than one
    time in a hundred, so 3 or more of 20 has a probability below 1e-4; on data with a 10 nT curve at the
    ends its gain is many standard errors in every seed."""
    kept = chosen = 0
    for seed in range(20):
        ds, _ = t24_dataset(np.random.default_rng(seed), temps_c=TEMPS_C, samples_per_point=4)
        kept += choose_temperature_model(ds).model == "t24"
        curve = np.outer(0.004 * (ds.temp_c - 20.0) ** 2, [1.0, 1.0, 0.0])
        curved = Dataset(ds.h_nt, ds.temp_c, ds.ref_nt + curve)
        choice = choose_temperature_model(curved)
        chosen += choice.model == "t36"
        assert choice.heldout_rms_nt["t36"] < choice.heldout_rms_nt["t24"]
    assert kept >= 18 and chosen == 20


def test_the_choice_records_its_figures_and_refuses_what_it_cannot_fit():
    ds, _ = t24_dataset(np.random.default_rng(30), temps_c=TEMPS_C, samples_per_point=4)
    choice = choose_temperature_model(ds)
    assert len(choice.fold_rms_nt["t24"]) == 5 and "held-out RMS" in choice.message
    assert set(choice.as_dict()) >= {"model", "heldout_rms_nt", "fold_rms_nt", "rule"}
    two, _ = t24_dataset(np.random.default_rng(31), temps_c=(-30.0, 70.0), samples_per_point=4)
    only = choose_temperature_model(two)
    assert only.model == "t24" and "fewer than three distinct temperatures" in only.message
    with pytest.raises(DataError, match="3 labels for"):
        choose_temperature_model(ds, blocks=[0, 1, 2])
    with pytest.raises(DataError, match="2 distinct labels"):
        choose_temperature_model(ds, blocks=np.arange(len(ds)) % 2)


def test_default_blocks_cut_every_temperature_step():
    temps = np.repeat([-30.0, 20.0, 70.0], 50)
    folds = blocks_within_steps(temps)
    for step in (-30.0, 20.0, 70.0):
        assert np.array_equal(np.bincount(folds[temps == step]), [10] * 5)
        assert np.all(np.diff(folds[temps == step]) >= 0)  # contiguous pieces in row order
