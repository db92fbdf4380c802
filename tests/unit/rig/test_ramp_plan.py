"""Continuous-ramp plans: strict syntax, chamber limits and the sweep's pace, stable ids, rig check."""

from __future__ import annotations

import pytest
import yaml

from rig.config import Plan
from rig.config.loading import load_campaign
from rig.core.errors import ConfigError, LimitError
from rig.core.yamlload import load_model
from rig.schedules.compile import check_campaign, check_plan, compile_plan
from rig.schedules.ramp import MAX_SWEEP_SPAN_FRACTION
from tests.unit.rig.test_plan import coil_station, make_plan

RAMP = {"mode": "ramp", "range_c": [-30, 70], "rate_c_per_min": 2.0, "cycles": 1}


def ramp_plan(**temps) -> Plan:
    return make_plan(temperatures={**RAMP, **temps}, samples_per_point=2)


def test_ramp_points_have_stable_ids_legs_and_nominal_temperatures():
    points = compile_plan(ramp_plan(), coil_station())
    assert points == compile_plan(ramp_plan(), coil_station())  # deterministic
    ids = [p.id for p in points]
    assert len(set(ids)) == len(ids)
    assert ids[0] == "R1U-S001-F01" and ids[25] == "R1U-S002-F02"
    assert ids[-1].startswith("R1D-") and ids[-1].endswith("-F24")
    up = [p for p in points if p.rising]
    down = [p for p in points if not p.rising]
    assert len(up) == len(down) and up[0].setpoint_c == -30 and down[0].setpoint_c == 70
    assert [p.setpoint_c for p in up] == sorted(p.setpoint_c for p in up)
    assert max(p.setpoint_c for p in up) == 70 and min(p.setpoint_c for p in down) == -30
    assert [p.index for p in points] == list(range(len(points)))


def test_two_cycles_give_four_legs():
    points = compile_plan(ramp_plan(cycles=2), coil_station())
    assert {p.id[:3] for p in points} == {"R1U", "R1D", "R2U", "R2D"}
    assert max(p.leg for p in points) == 4


def test_check_estimates_ramps_sweeps_and_the_span_of_one_sweep():
    plan = ramp_plan(end_hold_s=300)
    report = check_plan(plan, coil_station())
    b = report.breakdown_s
    assert b["ramps"] == pytest.approx(2 * 100 / 2.0 * 60)
    assert b["end holds"] == 600 and b["to start"] == pytest.approx(52 / 5 * 60)  # from a room at 5/min
    assert report.duration_s == pytest.approx(sum(b.values()))
    text = "\n".join(report.summary_lines())
    assert "sweeps x 24 fields" in text and "one sweep of 24 fields" in text and "spanning" in text


def test_ramp_is_much_shorter_than_the_same_steps():
    steps = make_plan(temperatures={"steps": [-30, -15, 0, 15, 25, 40, 55, 70], "ramp_c_per_min": 2.0,
                                    "stability": {"band_c": 0.3, "rate_c_per_min": 0.05, "dwell_s": 600}},
                      samples_per_point=2)
    station = coil_station(expect={"noise_nt": 200, "thermal_lag_s": 600})
    ramp = check_plan(ramp_plan(), station).duration_s
    assert ramp < 0.5 * check_plan(steps, station).duration_s


@pytest.mark.parametrize("temps, match", [
    ({"rate_c_per_min": 8}, "rate_c_per_min: 8 degC/min exceeds chamber.limits max_ramp_c_per_min 5"),
    ({"range_c": [-50, 70]}, r"range_c\[0\]: -50 degC is outside chamber.limits"),
    ({"range_c": [-30, 90]}, r"range_c\[1\]: 90 degC is outside"),
])
def test_ramp_outside_the_chamber_limits_is_named(temps, match):
    with pytest.raises(LimitError, match=match):
        check_plan(ramp_plan(**temps), coil_station())


def test_a_ramp_too_fast_for_the_field_source_is_refused_with_the_rate_to_use():
    plan = make_plan(temperatures={**RAMP, "range_c": [20, 30], "rate_c_per_min": 5}, samples_per_point=50)
    with pytest.raises(LimitError, match=f"at most {MAX_SWEEP_SPAN_FRACTION:.0%} of the range") as info:
        check_plan(plan, coil_station())
    assert "ramp at <=" in str(info.value) and "temperatures.rate_c_per_min" in str(info.value)


@pytest.mark.parametrize("temps, match", [
    ({"mode": "rmp"}, "mode must be ramp, designed or sequential"),
    ({"cycles": 0}, "cycles"),
    ({"range_c": [20, 20]}, "range_c: start and end must differ"),
    ({"rate_c_per_min": -1}, "rate_c_per_min"),
    ({"steps": [1, 2]}, "steps"),
])
def test_ramp_syntax_is_strict(temps, match):
    text = yaml.safe_dump({"name": "p", "temperatures": {**RAMP, **temps}, "samples_per_point": 1,
                           "fields": {"kind": "cube24"}})
    with pytest.raises(ConfigError, match=match):
        load_model(Plan, "p.yaml", text)


def test_errors_name_the_plan_file_and_line(tmp_path):
    plan = tmp_path / "r.yaml"
    plan.write_text("name: r\ntemperatures:\n  mode: ramp\n  range_c: [-30, 70]\n  rate_c_per_min: 9\n"
                    "fields: {kind: cube24}\nsamples_per_point: 1\n")
    from tests.system.campaign_helpers import SIM_STATION

    with pytest.raises(LimitError, match=r"r.yaml: temperatures.rate_c_per_min: .* \(line 5\)"):
        check_campaign(load_campaign(plan, SIM_STATION))


def test_stop_when_is_validated_and_its_worst_case_stated():
    base = {"name": "p", "temperatures": RAMP, "samples_per_point": 1, "fields": {"kind": "cube24"}}
    with pytest.raises(ConfigError, match="stop_when.Q: unknown parameter group"):
        load_model(Plan, "p.yaml", yaml.safe_dump({**base, "stop_when": {"Q": 1}}))
    with pytest.raises(ConfigError, match="stop_when.K"):
        load_model(Plan, "p.yaml", yaml.safe_dump({**base, "stop_when": {"K": 0}}))
    for plan in (ramp_plan(), make_plan()):
        plan = plan.model_copy(update={"stop_when": {"K": 1e-6, "b": 5}})
        report = check_plan(plan, coil_station())
        assert any("stop_when K 1e-06, b 5" in line and "worst case the whole plan" in line
                   for line in report.summary_lines())


def test_step_plans_are_unchanged():
    assert make_plan().ramp is None
    points = compile_plan(make_plan(field_order="listed"), coil_station())
    assert [p.id for p in points[:2]] == ["T01-F01", "T01-F02"]
