"""What a plan is made and checked with (rig/planning/inputs.py): the station's thermal commissioning, a
designed plan's recorded values, the station's statements, in that order, each with its origin; the
simulated world's own values never."""

from __future__ import annotations

import dataclasses
import math

import pytest
import yaml

from rig.config import CONFIGS_DIR, Plan
from rig.config.commissioning_file import ThermalDut, ThermalRecord
from rig.config.loading import load_campaign
from rig.core.errors import ConfigError
from rig.planning.inputs import planning_inputs, require_duts
from rig.schedules.compile import check_plan
from tests.unit.rig.test_plan import coil_station, make_plan

LAB = CONFIGS_DIR / "stations" / "sim-lab.yaml"
DEMO = CONFIGS_DIR / "plans" / "demo.yaml"


def thermal_record(duts: list[str], *, rate=2.8, lag_s=500.0, set_reset="pair") -> ThermalRecord:
    return ThermalRecord(
        start_air_c=21.5, step_c=(25.0, 40.0), commanded_rate_c_per_min=5.0, rate_c_per_min=rate,
        overshoot_c=0.5, duration_s=7200.0, set_reset=set_reset, sample_s=0.2, move_s=0.4,
        chamber_read_s=0.01, moves=8,
        duts={name: ThermalDut(lag_s=lag_s + 100 * i, lag_se_s=1.0, offset_c=0.1 * i, residual_c=0.05,
                               temp_source="t", noise_nt=(20.0, 30.0, 25.0)) for i, name in enumerate(duts)})


def with_thermal(station, record: ThermalRecord):
    """The station as loaded with a commissioning file that has this thermal section."""
    commissioned = station.field_source.commissioned
    com = dataclasses.replace(commissioned, record=commissioned.record.model_copy(update={"thermal": record}))
    return station.model_copy(update={"field_source": station.field_source.with_commissioning(com)})


@pytest.fixture(scope="module")
def lab():
    return load_campaign(DEMO, LAB).station


def test_the_thermal_commissioning_gives_every_number_with_its_origin(lab):
    station = with_thermal(lab, thermal_record([d.name for d in lab.duts]))
    plan = make_plan(set_reset="pair")
    inputs = planning_inputs(plan, station)
    assert inputs.missing() == [] and not inputs.stated_rate
    dut = inputs.duts["dut1"]
    assert dut.noise_nt == 30.0 and dut.lag_s == 500.0 and dut.offset_c == 0.0  # read as the plan reads
    assert inputs.duts["dut3"].lag_s == 700.0 and inputs.duts["dut3"].offset_c == pytest.approx(0.2)
    assert inputs.rate_c_per_min == 2.8 and inputs.chamber.start_c == 21.5 and inputs.overshoot_c() == 0.5
    assert inputs.timing.sample_s == 0.2 and inputs.timing.point_overhead_s == pytest.approx(0.43)
    text = "\n".join(inputs.lines())
    assert "the air moves at up to 2.8 degC/min, overshoot 0.5 degC" in text
    assert text.count("thermal commissioning") == 3 and "stated limit" not in text
    # a plan read without SET/RESET pairs: each reading is one of the pair's two (sqrt 2 noisier)
    plain = planning_inputs(make_plan(set_reset="off"), station)
    assert plain.duts["dut1"].noise_nt == pytest.approx(30.0 * math.sqrt(2.0))


def test_a_chamber_faster_than_its_stated_limit_is_planned_at_the_limit(lab):
    station = with_thermal(lab, thermal_record([d.name for d in lab.duts], rate=9.0))
    assert planning_inputs(make_plan(), station).rate_c_per_min == 5.0


def test_a_step_plans_stability_waits_follow_the_measured_lags(lab):
    plan = make_plan(temperatures={"steps": [20, 40], "ramp_c_per_min": 2.0,
                                   "stability": {"band_c": 0.5, "dwell_s": 100}})
    slow = check_plan(plan, with_thermal(lab, thermal_record([d.name for d in lab.duts], lag_s=900.0)))
    fast = check_plan(plan, with_thermal(lab, thermal_record([d.name for d in lab.duts], lag_s=100.0)))
    assert slow.breakdown_s["stability"] > fast.breakdown_s["stability"] + 2000.0
    # the pace: 0.2 s a sample of every DUT, 0.43 s a point beyond its settle_s (plan: 5 samples, 1 s)
    n_points = len(slow.points)
    assert slow.breakdown_s["sampling"] == pytest.approx(n_points * 5 * 0.2)
    assert slow.breakdown_s["moves+settle"] == pytest.approx(n_points * (1.0 + 0.43))


def test_a_stated_dut_is_said_to_be_stated_and_nothing_is_read_from_the_simulated_world():
    station = coil_station(expect={"noise_nt": 200.0, "thermal_lag_s": 700.0})
    inputs = planning_inputs(make_plan(), station)
    dut = inputs.duts["m"]
    assert dut.lag_s == 700.0 and dut.noise_nt == 200.0 and dut.offset_c is None  # no SET/RESET: plain
    assert dut.origin == "stated in the station (duts[].expect), not measured"
    assert inputs.chamber.start_c == 22.0 and station.sim.air_c == 20.0  # the simulated air is not read
    assert "the station's stated limit, not a measurement" in inputs.lines()[0]


def test_without_any_source_the_design_is_refused_naming_the_three_ways():
    station = coil_station()
    inputs = planning_inputs(make_plan(), station)
    assert inputs.missing() == ["m"] and inputs.slowest_lag_s() is None
    with pytest.raises(ConfigError, match=r"station s: no measured or stated noise and thermal lag for m: "
                       r"give `rig design --from SESSION`.*`rig commission --thermal`.*duts\[\]\.expect"):
        require_duts(inputs, station)


def test_a_designed_plan_is_checked_with_what_it_was_designed_with(tmp_path):
    station = coil_station(expect={"noise_nt": 200.0, "thermal_lag_s": 700.0})
    plan = Plan.model_validate({
        "name": "d", "fields": {"kind": "cube24"}, "samples_per_point": 2, "stop_when": {"K": 1e-6},
        "temperatures": {"mode": "designed", "rate_c_per_min": 2.0, "legs": [{"to_c": 40, "sweeps": 2}],
                         "assumed": {"m": {"noise_nt": 15.0, "lag_s": 350.0, "offset_c": -0.3}},
                         "timing": {"sample_s": 0.5, "point_overhead_s": 0.7, "measured_by": "session x"}}})
    inputs = planning_inputs(plan, station)
    assert (inputs.duts["m"].lag_s, inputs.duts["m"].offset_c) == (350.0, -0.3)
    assert inputs.duts["m"].origin == "the plan's assumed values"
    assert (inputs.timing.sample_s, inputs.timing.point_overhead_s) == (0.5, 0.7)
    assert inputs.timing.origin == "the plan's timing, measured by session x"
    yaml.safe_dump(plan.model_dump(mode="json"))  # the recorded values are plain data
