"""Stop-when-good-enough: target standard errors checked on a Gram accumulator fed point by point."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calib.design.targets import check_targets
from calib.errors import DataError
from calib.models.gram import GramAccumulator
from calib.synthetic import t24_dataset

TARGETS = {"S": 1e-4, "K": 2e-6, "kb": 0.05, "b": 3.0}


def points(rng_seed: int = 0):
    """The synthetic campaign as points (temperature step x direction) of 20 samples, steps interleaved
    so every temperature is present early, as a ramp campaign would give."""
    ds, _ = t24_dataset(np.random.default_rng(rng_seed), temps_c=(-30.0, 70.0, 20.0), samples_per_point=20)
    point = np.arange(ds.n) // 20
    order = np.argsort(point % 26 * 3 + point // 26, kind="stable")  # direction-major across steps
    return [ds.subset(order[k : k + 20]) for k in range(0, ds.n, 20)]


def test_not_met_before_a_fit_exists_then_met_and_consistent_with_a_fresh_fit():
    acc = GramAccumulator(20.0)
    seen = []
    first_met = None
    history = []
    for p in points():
        acc.add(p.h_nt, p.temp_c, p.ref_nt)
        seen.append(p)
        status = check_targets(acc, TARGETS)
        history.append(status.worst_ratio)
        if len(seen) == 1:
            assert not status.met and math.isinf(status.worst_ratio) and "no fit yet" in status.message
        if status.met and first_met is None:
            first_met = len(seen)
            fresh = GramAccumulator(0.0)  # another centring, same absolute-tau errors
            for q in seen:
                fresh.add(q.h_nt, q.temp_c, q.ref_nt)
            se = fresh.solve().std_errors
            assert se["S"].max() <= TARGETS["S"] * 1.001 and se["K"].max() <= TARGETS["K"] * 1.001
            assert se["b_nt"].max() <= TARGETS["b"] * 1.001
            assert se["kb_nt_per_c"].max() <= TARGETS["kb"] * 1.001
    assert first_met is not None and 3 < first_met < len(history)
    finite = [r for r in history if math.isfinite(r)]
    assert finite[-1] < finite[0] / 3  # the worst ratio falls as points arrive


def test_worst_group_and_ratio():
    acc = GramAccumulator(20.0)
    for p in points():
        acc.add(p.h_nt, p.temp_c, p.ref_nt)
    se = acc.solve().std_errors
    targets = {"S": se["S"].max() * 2, "K": se["K"].max() / 4, "kb": 1.0, "b_nt": 100.0}
    status = check_targets(acc, targets)
    assert not status.met and status.worst == "K"
    assert status.worst_ratio == pytest.approx(4.0)
    assert status.ratios["S"] == pytest.approx(0.5)
    assert "K at 4.00 x" in status.message


def test_too_few_samples_is_never_met():
    acc = GramAccumulator(20.0)
    for p in points()[:12]:  # 4 directions at 3 temperatures
        acc.add(p.h_nt, p.temp_c, p.ref_nt)
    assert acc.solve() is not None  # a fit exists
    status = check_targets(acc, {"S": 1.0}, min_samples=500)
    assert not status.met and "240 samples, at least 500" in status.message


@pytest.mark.parametrize(("targets", "words"), [
    ({"Q": 1.0}, "unknown parameter group 'Q'"),
    ({"S": -1.0}, "S = -1.0: must be a positive number"),
    ({"K": "small"}, "must be a positive number"),
    ({}, "none given"),
])
def test_bad_targets_are_one_clear_line(targets, words):
    with pytest.raises(DataError, match=words):
        check_targets(GramAccumulator(), targets)
