"""One list of calibration models: calib's registry. The CLI, the plan, the fit and the report read it."""

from __future__ import annotations

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.errors import DataError
from calib.models import registry
from rig.analysis.heldout import models_for
from rig.cli.calib_cmds import MODEL_CHOICE
from rig.config import Fit
from rig.core.errors import ConfigError


def test_every_reader_of_the_model_list_agrees_with_the_registry():
    assert tuple(MODEL_CHOICE.choices) == registry.MODELS == tuple(registry.REGISTRY)
    assert Fit.model_validate({"models": list(registry.MODELS)}).models == list(registry.MODELS)
    with pytest.raises((ConfigError, ValueError)):
        Fit.model_validate({"models": ["t25"]})
    assert set(registry.PARAM_SHAPES) == set(registry.REGISTRY)


def test_the_report_offers_what_the_data_allows_by_the_registry():
    ds, _ = synthetic.t24_dataset(np.random.default_rng(3), samples_per_point=1)
    assert models_for(ds) == list(registry.MODELS)
    without_temp = ds.subset(np.ones(len(ds), bool))
    without_temp.temp_c = None
    assert models_for(without_temp) == [m for m, s in registry.REGISTRY.items() if not s.needs_temperature]


def test_calib_fit_dispatches_through_the_registry(monkeypatch):
    ds, _ = synthetic.t24_dataset(np.random.default_rng(4), samples_per_point=1)
    calls = []
    p12 = registry.REGISTRY["p12"]

    def counting(d, w, o):
        calls.append(o)
        return p12.fit_weighted(d, w, o)

    monkeypatch.setitem(registry.REGISTRY, "p12", registry.ModelSpec(
        "p12", p12.params, counting, vector=True, needs_temperature=False, options=frozenset()))
    cal = calib.fit(ds, "p12", temp_ref_c=5.0)
    assert cal.model == "p12" and calls[0].temp_ref_c == 5.0
    known = "t24, p12, scalar, t36"
    with pytest.raises(DataError, match=f"unknown calibration model 'nope' \\(known: {known}\\)"):
        calib.fit(ds, "nope")
