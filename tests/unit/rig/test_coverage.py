"""Every calibration states the DUT temperatures its data covers, and acceptance fails a DUT whose data
does not reach both ends of the plan's range within the plan's stability band: a calibration must not
extrapolate over part of the range it is sold for."""

from __future__ import annotations

import numpy as np
import pytest

import calib
from calib.synthetic import t24_dataset
from rig.analysis.acceptance import judge
from rig.config import Plan
from rig.config.plan import Acceptance


def fitted(temps_c):
    ds, _ = t24_dataset(np.random.default_rng(5), temps_c=temps_c, samples_per_point=4, temp_jitter_c=0.0)
    return ds, calib.fit(ds, "t24")


def test_a_calibration_states_the_temperatures_its_data_covers():
    _, cal = fitted((-30.0, 20.0, 70.0))
    assert cal.stats["temperature_range_c"] == [-30.0, 70.0]
    for model in ("p12", "scalar"):  # every model, not only T24
        ds, _ = fitted((-10.0, 40.0))
        assert calib.fit(ds, model).stats["temperature_range_c"] == [-10.0, 40.0]


@pytest.mark.parametrize(("temps", "passes"), [
    ((-30.0, 20.0, 70.0), True),
    ((-29.6, 20.0, 69.6), True),  # within the band of 0.5 of each end
    ((-15.5, 20.0, 52.8), False),  # a design that never let the DUTs reach the ends
    ((-30.0, 20.0, 69.0), False),
])
def test_acceptance_fails_a_dut_whose_data_does_not_cover_the_plans_range(temps, passes):
    ds, cal = fitted(temps)
    failed, figures, _ = judge(Acceptance(), ds, cal, range_c=(-30.0, 70.0), band_c=0.5)
    coverage = [f for f in failed if f.startswith("coverage")]
    assert (coverage == []) is passes, failed
    assert figures["temperature_low_c"] == min(temps) and figures["temperature_high_c"] == max(temps)
    if not passes:
        assert "does not reach the plan's -30 .. 70 degC within 0.5" in coverage[0]


@pytest.mark.parametrize(("temperatures", "range_c", "band_c"), [
    ({"steps": [-20, 0, 40], "stability": {"band_c": 0.3}}, (-20, 40), 0.3),
    ({"mode": "ramp", "range_c": [70, -30], "rate_c_per_min": 2}, (-30, 70), 0.5),
    ({"mode": "sequential", "range_c": [-30, 70], "stability": {"band_c": 0.8}}, (-30, 70), 0.8),
    ({"mode": "designed", "rate_c_per_min": 2, "legs": [{"to_c": 70.2, "sweeps": 3},
                                                        {"to_c": 20, "sweeps": 1, "check": True},
                                                        {"to_c": -30.4, "sweeps": 3}]}, (-30.4, 70.2), 0.5),
    ({"mode": "designed", "rate_c_per_min": 2, "range_c": [-30, 70],
      "legs": [{"to_c": 70.2, "sweeps": 3}, {"to_c": -30.4, "sweeps": 3}]}, (-30, 70), 0.5),
])
def test_each_schedule_states_the_range_its_dut_data_must_cover(temperatures, range_c, band_c):
    plan = Plan.model_validate({"name": "p", "temperatures": temperatures, "fields": {"kind": "cube24"},
                                "samples_per_point": 2, "stop_when": {"K": 1e-6}})
    assert plan.temperatures.covered_c() == range_c and plan.temperatures.band_c() == band_c
