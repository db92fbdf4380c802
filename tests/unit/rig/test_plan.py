"""Plan compilation (stable ids, deterministic order), field sets, and limit checks without hardware."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from calib.stats.directions import fibonacci_directions
from rig.config import DEFAULT_STATION, Plan, Station, load_station
from rig.core.errors import ConfigError, LimitError
from rig.fieldsources import fieldsets
from rig.schedules.compile import check_plan, compile_plan, point_id


def make_plan(**overrides) -> Plan:
    data = {
        "name": "p",
        "temperatures": {"steps": [-20, 0, 25, 60], "ramp_c_per_min": 2.0,
                         "stability": {"band_c": 0.5, "dwell_s": 100}},
        "fields": {"kind": "cube24", "magnitude_nt": 50_000},
        "samples_per_point": 5,
        "settle_s": 1.0,
    }
    data.update(overrides)
    return Plan.model_validate(data)


def coil_station(*, expect: dict | None = None, **coil_overrides) -> Station:
    """A simulated coil station; `expect` states its DUT's noise and lag as a lab would (planning reads
    nothing of the simulated world)."""
    coils = {"kind": "coils", "transport": {"kind": "sim"}, "max_current_a": 2.0,
             "coil_constants_nt_per_a": [[50_000, 0, 0], [0, 50_000, 0], [0, 0, 50_000]],
             "ambient_nt": [0, 0, 0]}
    coils.update(coil_overrides)
    return Station.model_validate({
        "name": "s",
        "sim": {"air_c": 20.0},
        "chamber": {"type": "watlow_f4t", "transport": {"kind": "sim"},
                    "limits": {"min_setpoint_c": -40, "max_setpoint_c": 85, "max_ramp_c_per_min": 5}},
        "field_source": coils,
        "duts": [{"name": "m", "type": "hmc5883l", "transport": {"kind": "sim"}, "temp_source": "t",
                  "options": {"rate_hz": 7.5}, **({} if expect is None else {"expect": expect})}],
        "temperature_sensors": [{"name": "t", "type": "tmp117", "transport": {"kind": "sim"}, "beside": "m"}],
        # 'measure' needs a reference magnetometer to measure it with
        "reference_magnetometers": [{"name": "ref", "type": "mmc5983ma", "transport": {"kind": "sim"},
                                     "calibration": "ref.t24.yaml", "temp_source": "self"}],
    })


def table_station() -> Station:
    data = coil_station().model_dump()
    data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"}, "az_limits_deg": [-180, 180],
                            "el_limits_deg": [-90, 90], "site_field": {"vector_nt": [19000, 900, 45000]}}
    return Station.model_validate(data)


def test_point_ids_are_stable_zero_padded_and_temperature_major():
    points = compile_plan(make_plan(field_order="listed"), coil_station())
    assert len(points) == 4 * 24
    assert [p.id for p in points[:2]] == ["T01-F01", "T01-F02"]
    assert points[24].id == "T02-F01" and points[-1].id == "T04-F24"
    assert [p.index for p in points] == list(range(96))
    assert points[30].temp_index == 2 and points[30].field_index == 7 and points[30].setpoint_c == 0
    assert point_id(3, 7, 8, 150) == "T03-F007"
    assert point_id(3, 7, 8, 48, "O") == "T03-O07"


def test_each_step_takes_every_field_once_in_an_order_of_its_own():
    """The default order: a permutation per step, different from step to step and from the listed order,
    the same on every compilation (a resume takes the plan's own order)."""
    points = compile_plan(make_plan(), coil_station())
    listed = compile_plan(make_plan(field_order="listed"), coil_station())
    steps = [[p.field_index for p in points if p.temp_index == t] for t in range(1, 5)]
    assert all(sorted(step) == list(range(1, 25)) for step in steps)
    assert len({tuple(step) for step in steps}) == 4 and steps[0] != list(range(1, 25))
    assert [p.temp_index for p in points] == [p.temp_index for p in listed]  # still temperature-major
    assert [p.index for p in points] == list(range(96))
    by_id = {p.id: p for p in listed}
    assert all(p.command == by_id[p.id].command for p in points)  # an id names the same target
    assert [p.id for p in compile_plan(make_plan(), coil_station())] == [p.id for p in points]
    said = {order: [line for line in check_plan(make_plan(field_order=order), coil_station()).summary_lines()
                    if line.startswith("field order")] for order in ("shuffled", "listed")}
    assert said == {"shuffled": ["field order: a fresh one at each step (field_order: shuffled; listed keeps "
                                 "the plan's)"],
                    "listed": ["field order: the plan's (field_order: listed)"]}


def test_the_shuffled_order_is_the_same_on_any_interpreter():
    """A resumed session goes on in the order it began with: the order comes from random.random() alone,
    which Python keeps the same across versions, so it is pinned here."""
    points = compile_plan(make_plan(), coil_station())
    assert [p.field_index for p in points[:24]] == [11, 2, 21, 18, 20, 8, 1, 19, 23, 4, 6, 3, 13, 17, 5, 22,
                                                    24, 16, 14, 12, 7, 10, 9, 15]


def test_a_moving_schedule_refuses_a_shuffled_order(tmp_path):
    from rig.config import CONFIGS_DIR, load_plan

    text = (CONFIGS_DIR / "plans" / "ramp-campaign.yaml").read_text()
    path = tmp_path / "ramp.yaml"
    path.write_text(text + "\nfield_order: shuffled\n")
    with pytest.raises(ConfigError) as info:
        load_plan(path)
    assert str(info.value).startswith(f"{path}: field_order: a moving schedule sweeps the fields in the "
                                      "listed order")
    assert f"(line {text.count(chr(10)) + 2})" in str(info.value)


def test_compilation_is_deterministic():
    a = compile_plan(make_plan(), coil_station())
    b = compile_plan(make_plan(), coil_station())
    assert [(p.id, p.field_nt) for p in a] == [(p.id, p.field_nt) for p in b]


def test_coil_targets_have_the_plan_magnitudes():
    plan = make_plan(fields={"kind": "fibonacci", "n": 10, "magnitudes_nt": [30_000, 60_000]},
                     field_order="listed")
    points = compile_plan(plan, coil_station())
    norms = [np.linalg.norm(p.field_nt) for p in points[:20]]
    assert np.allclose(norms[:10], 30_000) and np.allclose(norms[10:], 60_000)
    assert points[0].target == {"field_nt": list(points[0].field_nt)}


def test_cube_rotations_form_the_rotation_group_of_the_cube():
    rots = fieldsets.cube_rotations()
    assert len(rots) == 24
    for r in rots:
        assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
    keys = {tuple(r.round().astype(int).ravel()) for r in rots}
    assert len(keys) == 24
    for a, b in itertools.product(rots, repeat=2):  # closed under composition
        assert tuple((a @ b).round().astype(int).ravel()) in keys


def test_cube24_directions_are_distinct_and_span_every_axis():
    d = fieldsets.cube24_directions()
    assert d.shape == (24, 3)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert len({tuple(v.round(9)) for v in d}) == 24
    assert np.allclose(d.mean(axis=0), 0.0)
    assert fieldsets.span_ratio(d) == pytest.approx(1.0)  # isotropic: d.T d = 8 I


def test_fibonacci_directions_are_spread_evenly():
    d = fibonacci_directions(200)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.linalg.norm(d.mean(axis=0)) < 0.01
    nearest = [np.sort(np.linalg.norm(d - v, axis=1))[1] for v in d]
    assert min(nearest) > 0.5 * max(nearest)  # no clumps, no big holes


def test_turntable_orientations_and_ids():
    plan = make_plan(fields={"kind": "grid"}, field_order="listed")
    points = compile_plan(plan, table_station())
    assert len(points) == 4 * 16 and points[0].id == "T01-O01"
    assert points[1].command == (0.0, -90.0) and points[4].command == (-90.0, 0.0)  # a turn per tilt
    assert points[1].target == {"az_deg": 0.0, "el_deg": -90.0}


def test_field_kind_must_suit_the_field_source():
    with pytest.raises(ConfigError, match="needs a turntable"):
        compile_plan(make_plan(fields={"kind": "grid"}), coil_station())
    with pytest.raises(ConfigError, match="needs coils"):
        compile_plan(make_plan(), table_station())


def test_over_current_is_caught_with_the_limit_named():
    plan = make_plan(fields={"kind": "vectors", "vectors_nt": [[0, 0, 50_000], [0, 0, 120_000]]})
    with pytest.raises(LimitError) as info:
        check_plan(plan, coil_station())
    msg = str(info.value)
    assert "T01-F02" in msg and "max_current_a 2 A" in msg and "2.400 A in coil z" in msg


def test_ambient_counts_in_the_currents():
    plan = make_plan(fields={"kind": "vectors", "vectors_nt": [[0, 0, -60_000]]})
    check_plan(plan, coil_station())  # 1.2 A without ambient
    with pytest.raises(LimitError, match="max_current_a"):
        check_plan(plan, coil_station(ambient_nt=[0, 0, 45_000]))  # 2.1 A


def test_unmeasured_ambient_is_checked_for_the_worst_case():
    plan = make_plan(fields={"kind": "vectors", "vectors_nt": [[0, 0, 40_000]]})
    report = check_plan(plan, coil_station(ambient_nt="measure", ambient_max_nt=50_000))
    assert "largest coil current 1.800 A" in report.source_lines
    assert any("not yet measured" in w for w in report.warnings)
    with pytest.raises(LimitError, match="ambient_max_nt"):
        check_plan(plan, coil_station(ambient_nt="measure", ambient_max_nt=70_000))


def test_setpoint_outside_the_chamber_limits_is_named():
    with pytest.raises(LimitError) as info:
        check_plan(make_plan(temperatures={"steps": [25, 90]}), coil_station())
    msg = str(info.value)
    assert "step 2 setpoint 90 degC" in msg and "max_setpoint_c 85" in msg and "min_setpoint_c -40" in msg


def test_ramp_above_the_chamber_limit_is_named():
    plan = make_plan(temperatures={"steps": [25, {"setpoint_c": 40, "ramp_c_per_min": 8}]})
    expected = "step 2 ramp 8 degC/min exceeds chamber.limits max_ramp_c_per_min 5$"
    with pytest.raises(LimitError, match=expected):
        check_plan(plan, coil_station())


def test_turntable_angle_outside_limits_is_named():
    plan = make_plan(fields={"kind": "orientations", "angles_deg": [[0, 0], [90, 120]]})
    expected = r"T01-O02 angle 120 deg is outside field_source.el_limits_deg \[-90, 90\]"
    with pytest.raises(LimitError, match=expected):
        check_plan(plan, table_station())


def test_duration_estimate_adds_up_from_its_parts():
    plan = make_plan(temperatures={"steps": [30, 10], "ramp_c_per_min": 2.0,
                                   "stability": {"band_c": 0.5, "dwell_s": 100}},
                     fields={"kind": "directions", "directions": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
                     samples_per_point=4, settle_s=2.0)
    report = check_plan(plan, coil_station(expect={"noise_nt": 200, "thermal_lag_s": 600}))
    b = report.breakdown_s
    # from a room's 22 degC (nothing measured where the air starts; the simulated 20 degC is not read)
    assert b["ramps"] == pytest.approx((8 + 20) / 2.0 * 60)
    # the mount lags the ramp by 2/60 degC/s x 600 s = 20 degC (capped at the step), decays to 0.5 degC
    lag = 600.0  # as the station states it
    assert b["stability"] == pytest.approx(lag * np.log(8 / 0.5) + 100 + lag * np.log(20 / 0.5) + 100)
    unknown = check_plan(plan, coil_station()).breakdown_s  # no lag known: the dwells alone, said so
    assert unknown["stability"] == pytest.approx(200)
    assert b["moves+settle"] == pytest.approx(6 * 2.0)
    # hmc5883l at rate_hz 7.5, after the TMP117 beside it (one-shot, 8 conversions of 15.5 ms)
    assert b["sampling"] == pytest.approx(6 * 4 * (1 / 7.5 + 8 * 0.0155))
    assert report.duration_s == pytest.approx(sum(b.values()))
    assert report.samples_per_dut == 24 and report.n_temperatures == 2 and report.n_fields == 3


def test_turntable_moves_count_in_the_estimate():
    plan = make_plan(temperatures={"steps": [20]}, fields={"kind": "orientations",
                                                          "angles_deg": [[90, 0], [90, 45]]}, settle_s=0)
    report = check_plan(plan, table_station())
    assert report.breakdown_s["moves+settle"] == pytest.approx((90 + 45) / 10.0)
    assert any(w.startswith("T24: ") and "not identifiable" in w for w in report.warnings)


def test_a_single_temperature_cannot_identify_the_t24_temperature_terms():
    report = check_plan(make_plan(temperatures={"steps": [25]}), coil_station())
    assert any("K and kb are not identifiable" in w for w in report.warnings)
    assert check_plan(make_plan(fit={"models": ["p12"]}, temperatures={"steps": [25]}),
                      coil_station()).warnings == []


def test_coplanar_field_set_is_warned_about():
    flat = [[1, 0, 0], [0, 1, 0], [1, 1, 0], [-1, 0, 0]]
    plan = make_plan(fields={"kind": "directions", "directions": flat})
    assert any("barely span" in w for w in check_plan(plan, coil_station()).warnings)


def test_shipped_plans_pass_against_the_default_station():
    from rig.config import CONFIGS_DIR, load_plan

    station = load_station(DEFAULT_STATION)
    demo = check_plan(load_plan(CONFIGS_DIR / "plans" / "demo.yaml"), station)
    assert demo.n_temperatures >= 4 and demo.warnings == []
    temps = [p.setpoint_c for p in demo.points[:: demo.n_fields]]
    assert min(temps) <= -20 and max(temps) >= 60
    full = check_plan(load_plan(CONFIGS_DIR / "plans" / "full-campaign.yaml"), station)
    assert (full.n_temperatures, full.n_fields, full.points[0].samples) == (8, 48, 50)


def test_the_default_turntable_grid_is_enough_for_t24():
    data = table_station().model_dump()
    data["field_source"]["el_limits_deg"] = [-180, 180]
    report = check_plan(make_plan(fields={"kind": "grid"}), Station.model_validate(data))
    assert report.n_fields == 16 and report.warnings == []
    tilted_only = make_plan(fields={"kind": "grid", "az_deg": [0], "el_deg": [0, 90]})
    assert any(w.startswith("T24: ") for w in check_plan(tilted_only, Station.model_validate(data)).warnings)


def test_an_older_plan_bounding_p12s_b_nt_bounds_its_h0_nt():
    """P12's raw offset is h0_nt now (calib/equations.py RENAMED_PARAMS): a plan written for the old name
    still loads, and its limits apply to the same parameter."""
    import calib
    from calib import synthetic
    from rig.analysis.acceptance import judge

    plan = make_plan(fit={"models": ["p12"]},
                     acceptance={"bounds": {"b_nt": [-1.0, 1.0]}, "max_std_error": {"b_nt": 1e-6}})
    plan.acceptance.check_against(["p12"])
    ds, truth = synthetic.p12_dataset(np.random.default_rng(3), samples_per_point=2)
    failed, figures, _ = judge(plan.acceptance, ds, calib.fit(ds, "p12"))
    assert any(f.startswith("bounds.b_nt ") for f in failed)
    assert any(f.startswith("std_error.b_nt") for f in failed) and figures["std_error.b_nt"] > 1e-6
    assert np.max(np.abs(truth.params["h0_nt"])) > 1.0
    with pytest.raises(ValueError, match="p12 has no parameter 'c_nt'"):
        make_plan(fit={"models": ["p12"]}, acceptance={"bounds": {"c_nt": [0, 1]}})
