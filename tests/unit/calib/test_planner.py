"""The least-time schedule (calib/design/planner.py): its thermal prediction, its search, and its
decisions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calib.design.planner import (
    CHECK,
    END,
    ChamberModel,
    DutModel,
    Leg,
    Pace,
    State,
    air_path,
    crossing,
    crossing_rate,
    design_schedule,
    element_path,
    predict,
    summarise,
    sweeps_with_hold,
    worst_ratios,
)
from calib.design.sequential import next_leg
from calib.errors import DataError
from calib.synthetic import coil_directions
from calib.thermal.lag import settling_lag_s

FIELDS = 50_000 * coil_directions(26)
PACE = Pace(FIELDS, 20, 4.0)  # a sweep of 104 s
TARGETS = {"S": 2e-5, "K": 5e-7, "b": 0.6, "kb": 0.015}
CHAMBER = ChamberModel((-30.0, 70.0), 3.0, (20.0,), 1)


def duts(*lags_s: float, sigma: float = 21.0) -> list[DutModel]:
    return [DutModel(f"d{i}", sigma, lag) for i, lag in enumerate(lags_s)]


def test_the_element_follows_a_ramp_and_a_hold_as_a_first_order_lag():
    t = np.linspace(0, 4000, 2001)
    air, legs = air_path(t, 0.0, 20.0, [Leg(50.0, 100, 3.0)], 40.0)
    assert air[0] == 20 and air[-1] == 50 and np.all(legs == 0)
    assert air[np.searchsorted(t, 300)] == pytest.approx(35.0)  # 3 degC/min for 5 min
    tau = 500.0
    element = element_path(t, air, tau, 20.0)
    # during the ramp the exact solution is air - r tau (1 - exp(-t/tau)); after it, an exponential approach
    r = 3.0 / 60
    ramp = t <= 600
    np.testing.assert_allclose(element[ramp], air[ramp] - r * tau * (1 - np.exp(-t[ramp] / tau)), atol=1e-6)
    lag_at_600 = r * tau * (1 - math.exp(-600 / tau))
    hold = t > 600
    np.testing.assert_allclose(element[hold], 50 - lag_at_600 * np.exp(-(t[hold] - 600) / tau), atol=1e-6)
    # an element that starts away from the air decays towards it with its own lag
    warm = element_path(t, np.full_like(t, 20.0), tau, 30.0)
    np.testing.assert_allclose(warm, 20 + 10 * np.exp(-t / tau), atol=1e-9)


def test_the_settling_lag_is_read_from_a_dwell():
    t = np.arange(0, 1800, 10.0)
    temp = -30 + 4.0 * np.exp(-t / 700.0) + np.random.default_rng(1).normal(0, 0.004, t.size)
    assert settling_lag_s(t, temp, -30.0) == pytest.approx(700, rel=0.05)
    assert settling_lag_s(t, np.full_like(t, -30.0), -30.0) is None  # nothing to read
    assert settling_lag_s(t[:20], temp[:20], -30.0) is None  # 190 s of a 700 s decay: too short to tell


def test_crossing_rate_is_the_chambers_unless_the_slowest_dut_cannot_follow():
    assert crossing_rate(5.0, 100.0, 900.0) == 5.0  # 100 degC / 15 min = 6.7 > 5
    assert crossing_rate(5.0, 100.0, 3600.0) == pytest.approx(100 / 60)


def test_check_legs_reach_their_temperature_and_hold_there():
    legs = crossing(ChamberModel((-30, 70), 3.0, (45.0, 20.0, -5.0), 1), 70.0, -30.0, 100.0)
    assert [leg.to_c for leg in legs] == [45.0, 20.0, -5.0] and {leg.kind for leg in legs} == {CHECK}
    # 25 degC at 3 degC/min = 500 s = 5 sweeps of 100 s while ramping, then the one at the check
    assert [leg.sweeps for leg in legs] == [6, 6, 6]
    assert sweeps_with_hold(20.0, 20.0, 3.0, 100.0, 2) == 2
    pred = predict(State.start(duts(300.0), 70.0), legs, Pace(FIELDS, 20, 100 / 26), duts(300.0), 20.0)
    ends = np.cumsum([leg.sweeps for leg in legs]) - 1
    np.testing.assert_allclose(pred.air_c[ends], [45.0, 20.0, -5.0])  # the air is there for the last sweep


def test_the_design_meets_the_targets_and_nothing_shorter_of_its_shape_does():
    models = duts(300.0, 900.0)
    schedule = design_schedule(models, CHAMBER, PACE, TARGETS, start_c=22.0, max_duration_s=12 * 3600)
    assert schedule.met
    kinds = [leg.kind for leg in schedule.legs]
    assert kinds[0] == kinds[-1] == END and CHECK in kinds
    assert {schedule.legs[0].to_c, schedule.legs[-1].to_c} == {-30.0, 70.0}
    worst = max(r[-1].max() for r in schedule.ratios.values())
    assert worst <= 1.0
    # one sweep less at the far end misses a target
    shorter = [*schedule.legs[:-1], Leg(schedule.legs[-1].to_c, schedule.legs[-1].sweeps - 1, 3.0)]
    assert not summarise(shorter, models, PACE, TARGETS, 20.0, 22.0).met


def test_a_slower_dut_needs_a_longer_campaign_and_a_noisier_one_too():
    base = design_schedule(duts(300.0), CHAMBER, PACE, TARGETS, start_c=22.0, max_duration_s=12 * 3600)
    slow = design_schedule(duts(1200.0), CHAMBER, PACE, TARGETS, start_c=22.0, max_duration_s=12 * 3600)
    noisy = design_schedule(duts(300.0, sigma=42.0), CHAMBER, PACE, TARGETS, start_c=22.0,
                            max_duration_s=12 * 3600)
    assert slow.duration_s > base.duration_s
    assert noisy.duration_s > base.duration_s


def test_unreachable_targets_give_the_closest_schedule_not_met():
    schedule = design_schedule(duts(300.0), CHAMBER, PACE, {"K": 1e-12}, start_c=22.0,
                               max_duration_s=3 * 3600)
    assert not schedule.met and "not met" in schedule.message
    assert schedule.duration_s <= 3 * 3600 + PACE.sweep_s


def test_bad_models_are_refused():
    with pytest.raises(DataError, match="lag"):
        design_schedule(duts(0.0), CHAMBER, PACE, TARGETS, start_c=22.0, max_duration_s=3600)
    with pytest.raises(DataError, match="noise"):
        design_schedule(duts(300.0, sigma=math.nan), CHAMBER, PACE, TARGETS, start_c=22.0,
                        max_duration_s=3600)
    with pytest.raises(DataError, match="range"):
        design_schedule(duts(300.0), ChamberModel((70.0, -30.0), 3.0), PACE, TARGETS, start_c=22.0,
                        max_duration_s=3600)


def _state_after(legs: list[Leg], models) -> tuple[State, dict]:
    pred = predict(State.start(models, 22.0), legs, PACE, models, 20.0)
    ratios = worst_ratios(pred, models, TARGETS, 20.0)
    return pred.state(len(pred.t_s) - 1), {n: float(r[-1].max()) for n, r in ratios.items()}


def test_decisions_stay_while_the_air_ramps_cross_when_worth_it_and_stop_when_done():
    models = duts(300.0, 600.0)
    first = Leg(70.0, 3, 3.0, END, 22.0)
    state, ratios = _state_after([first], models)
    early = next_leg(state, [first], models, CHAMBER, PACE, TARGETS, max_duration_s=12 * 3600,
                     ratios_now=ratios)
    assert not early.stop and not early.new_leg  # the air is not at 70 yet: stay
    held = Leg(70.0, 14, 3.0, END, 22.0)
    state, ratios = _state_after([held], models)
    crossing_now = next_leg(state, [held], models, CHAMBER, PACE, TARGETS, max_duration_s=12 * 3600,
                            ratios_now=ratios)
    assert crossing_now.new_leg and crossing_now.leg.to_c == 20.0 and crossing_now.leg.kind == CHECK
    # targets met but the model check not yet visited: no stop
    done = {n: 0.5 for n in ratios}
    assert not next_leg(state, [held], models, CHAMBER, PACE, TARGETS, max_duration_s=12 * 3600,
                        ratios_now=done).stop
    legs = [held, Leg(20.0, 18, 3.0, CHECK, 70.0), Leg(-30.0, 30, 3.0, END, 20.0)]
    state, ratios = _state_after(legs, models)
    final = next_leg(state, legs, models, CHAMBER, PACE, TARGETS, max_duration_s=12 * 3600, ratios_now=done)
    assert final.stop and "meets" in final.reason


def test_an_overshoot_beyond_the_ends_brings_the_slowest_dut_there_sooner():
    """The air goes end -/+ overshoot (beyond the DUTs' offsets), within the air's limits; every DUT must
    still come within the end tolerance, and with a slow DUT that happens sooner."""
    from dataclasses import replace

    from calib.design.planner import air_end

    models = [DutModel("fast", 21.0, 300.0, offset_c=0.2), DutModel("slow", 21.0, 900.0, offset_c=-0.3)]
    covered = replace(CHAMBER, end_tolerance_c=0.25, air_limits_c=(-40.0, 85.0))
    boosted = replace(covered, overshoot_c=5.0)
    assert air_end(covered, models, -30.0) == -30.2 and air_end(covered, models, 70.0) == 70.3
    assert air_end(boosted, models, -30.0) == -35.2 and air_end(boosted, models, 70.0) == 75.3
    assert air_end(replace(boosted, overshoot_c=20.0), models, -30.0) == -40.0  # the air's limit
    plain = design_schedule(models, covered, PACE, {"b": 5.0}, start_c=22.0, max_duration_s=12 * 3600)
    sooner = design_schedule(models, boosted, PACE, {"b": 5.0}, start_c=22.0, max_duration_s=12 * 3600)
    assert plain.met and sooner.met
    assert sooner.duration_s < 0.85 * plain.duration_s
    ends = [leg.to_c for leg in sooner.legs if leg.kind == END]
    assert sorted(ends) == [-35.2, 75.3]
