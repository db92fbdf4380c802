"""Station and plan files: the shipped configs load, and every mistake names file, key path and line."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from rig.config import CONFIGS_DIR, DEFAULT_STATION, Plan, Station, load_plan, load_station
from rig.config.loading import load_campaign
from rig.core.errors import ConfigError
from rig.devices.simulated.world import dut_truths, world_field
from rig.fieldsources.fieldmaths import TYPICAL_FIELD_NT

PLAN = """\
name: t
temperatures:
  ramp_c_per_min: 2
  stability: {band_c: 0.5, dwell_s: 60}
  steps:
    - -20
    - 0
    - setpoint_c: 25
      stability:
        band_c: BAND
fields: {kind: cube24}
samples_per_point: 3
"""

STATION = """\
name: s
chamber:
  type: watlow_f4t
  transport: {kind: sim}
  limits: {min_setpoint_c: -40, max_setpoint_c: 85, max_ramp_c_per_min: 5}
field_source:
  kind: coils
  transport: {kind: sim}
  max_current_a: 2
  coil_constants_nt_per_a: [[50000, 0, 0], [0, 50000, 0], [0, 0, 50000]]
  ambient_nt: [0, 0, 0]
duts:
  - name: m0
    type: mmc5983ma
    transport: {kind: i2c, bus: 1, address: 0x30}
    temp_source: tmp0
temperature_sensors:
  - name: tmp0
    type: tmp117
    transport: {kind: sim}
    beside: m0
"""


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def error_of(fn, *args) -> str:
    with pytest.raises(ConfigError) as info:
        fn(*args)
    return str(info.value)


@pytest.mark.parametrize("name", ["sim.yaml", "lab-example.yaml"])
def test_shipped_stations_load(name):
    station = load_station(CONFIGS_DIR / "stations" / name)
    assert len(station.duts) >= 2
    simulated = station.simulated_devices()
    assert all(simulated.values()) == (name == "sim.yaml")
    assert not any(simulated.values()) or name == "sim.yaml"


def test_sim_station_has_the_required_devices():
    station = load_station(DEFAULT_STATION)
    types = {d.type for d in station.duts}
    assert {"mmc5983ma", "serialmag"} <= types
    mmc = next(d for d in station.duts if d.type == "mmc5983ma")
    assert any(s.beside == mmc.name and s.type == "tmp117" for s in station.temperature_sensors)
    assert station.chamber.type == "watlow_f4t"
    assert set(station.sim.duts) == {d.name for d in station.duts}


@pytest.mark.parametrize("name", ["demo.yaml", "full-campaign.yaml"])
def test_shipped_plans_load(name):
    plan = load_plan(CONFIGS_DIR / "plans" / name)
    assert isinstance(plan, Plan)
    assert len(plan.temperatures.step_list()) >= 4


def test_value_error_names_file_key_path_and_line(tmp_path):
    path = write(tmp_path, "plan.yaml", PLAN.replace("BAND", "-1"))
    expected = f"{path}: temperatures.steps[2].stability.band_c: must be > 0 (line 10)"
    assert error_of(load_plan, path) == expected


def test_unknown_key_is_rejected_with_its_line(tmp_path):
    text = PLAN.replace("BAND", "0.3").replace("samples_per_point", "sample_per_point")
    path = write(tmp_path, "plan.yaml", text)
    msg = error_of(load_plan, path)
    assert msg == f"{path}: sample_per_point: unknown key; did you mean 'samples_per_point'? (line 12)"


def test_unknown_key_deep_in_a_union_member(tmp_path):
    text = STATION.replace("bus: 1, address: 0x30", "bus: 1, adress: 0x30")
    msg = error_of(load_station, write(tmp_path, "station.yaml", text))
    assert "duts[0].transport.adress: unknown key; did you mean 'address'? (line 15)" in msg


def test_missing_key_names_the_key_and_its_parent_line(tmp_path):
    text = STATION.replace("  max_current_a: 2\n", "")
    msg = error_of(load_station, write(tmp_path, "station.yaml", text))
    assert "field_source.max_current_a: required key is missing (line 6)" in msg


def test_wrong_transport_kind_for_a_chamber(tmp_path):
    text = STATION.replace("  transport: {kind: sim}\n  limits",
                           "  transport: {kind: i2c, bus: 1, address: 3}\n  limits")
    msg = error_of(load_station, write(tmp_path, "station.yaml", text))
    assert msg.endswith("chamber.transport.kind: 'i2c' is not one of 'modbus_tcp', 'modbus_rtu', 'sim' "
                        "(line 4)")
    no_kind = STATION.replace("duts:\n  - name: m0", "duts:\n  - name: m0\n    transport: {bus: 1}", 1)
    no_kind = no_kind.replace("    transport: {kind: i2c, bus: 1, address: 0x30}\n", "")
    msg = error_of(load_station, write(tmp_path, "station.yaml", no_kind))
    assert msg.endswith("duts[0].transport: required key 'kind' is missing (line 14)")


def test_cross_reference_error_is_blamed_on_the_key(tmp_path):
    text = STATION.replace("temp_source: tmp0", "temp_source: tmp9")
    msg = error_of(load_station, write(tmp_path, "station.yaml", text))
    assert msg == (f"{tmp_path / 'station.yaml'}: duts[0].temp_source: no temperature sensor 'tmp9' "
                   "(sensors: tmp0; or 'self') (line 16)")


def test_limits_must_be_ordered(tmp_path):
    text = STATION.replace("min_setpoint_c: -40,", "min_setpoint_c: 90,")
    msg = error_of(load_station, write(tmp_path, "station.yaml", text))
    assert "chamber.limits.max_setpoint_c: must be above min_setpoint_c (line 5)" in msg


def test_option_not_valid_for_the_dut_type(tmp_path):
    text = STATION.replace("    temp_source: tmp0", "    options: {gain: 3}\n    temp_source: tmp0")
    msg = error_of(load_station, write(tmp_path, "station.yaml", text))
    assert "duts[0].options.gain: not an option of mmc5983ma" in msg


def test_singular_coil_constants_are_rejected(tmp_path):
    text = STATION.replace("[0, 0, 50000]]", "[50000, 0, 0]]")
    msg = error_of(load_station, write(tmp_path, "station.yaml", text))
    assert "field_source.coil_constants_nt_per_a: matrix is singular" in msg


def test_duplicate_device_names(tmp_path):
    text = STATION.replace("  - name: tmp0", "  - name: m0").replace("beside: m0", "beside: m0")
    msg = error_of(load_station, write(tmp_path, "station.yaml", text))
    assert "temperature_sensors[0].name: device name 'm0' is used twice" in msg


REFERENCE = """\
reference_magnetometers:
  - name: ref0
    type: mmc5983ma
    transport: {kind: sim}
    calibration: ref0.t24.yaml
    temp_source: self
"""


def test_turntable_site_field_forms(tmp_path):
    base = STATION.split("field_source:")[0] + "field_source:\n  kind: turntable\n  transport: {kind: sim}\n"
    tail = "duts:" + STATION.split("duts:")[1] + REFERENCE
    wmm = "{model: wmm, lat_deg: 52, lon_deg: 5, alt_km: 0.1, date: 2026-01-01}"
    for site, kind in [("{vector_nt: [1, 2, 3]}", "SiteFromVector"), (wmm, "SiteFromModel"),
                       ("{reference_magnetometer: ref0}", "SiteFromReference")]:
        station = load_station(write(tmp_path, "t.yaml", base + f"  site_field: {site}\n" + tail))
        assert type(station.field_source.site_field).__name__ == kind
    dut_as_reference = base + "  site_field: {reference_magnetometer: m0}\n" + tail
    msg = error_of(load_station, write(tmp_path, "t.yaml", dut_as_reference))
    assert "field_source.site_field.reference_magnetometer: no reference magnetometer named 'm0' (a DUT " \
           "cannot double as the reference)" in msg and "(line 9)" in msg
    msg = error_of(load_station, write(tmp_path, "t.yaml", base + "  site_field: {lat: 3}\n" + tail))
    assert "field_source.site_field: give one of reference_magnetometer, vector_nt" in msg


def test_yaml_syntax_error_has_a_line(tmp_path):
    msg = error_of(load_plan, write(tmp_path, "p.yaml", "name: x\ntemperatures: [1, 2\nfields: 3\n"))
    assert msg.startswith(f"{tmp_path / 'p.yaml'}: not valid YAML") and "(line 3)" in msg


def test_empty_and_missing_files(tmp_path):
    assert "the file is empty" in error_of(load_plan, write(tmp_path, "p.yaml", "\n"))
    assert "file not found" in error_of(load_plan, tmp_path / "nope.yaml")
    assert "mapping" in error_of(load_plan, write(tmp_path, "p.yaml", "- 1\n"))


def test_steps_or_range_not_both(tmp_path):
    text = PLAN.replace("BAND", "0.3").replace("  steps:", "  range: {start_c: 0, stop_c: 10, step_c: 5}\n"
                                                             "  steps:")
    assert "temperatures.steps: give either steps" in error_of(load_plan, write(tmp_path, "p.yaml", text))


def test_range_expands_inclusively_and_stability_overrides_merge(tmp_path):
    text = PLAN.replace("BAND", "0.3")
    plan = load_plan(write(tmp_path, "p.yaml", text))
    steps = plan.temperatures.step_list()
    assert [s.setpoint_c for s in steps] == [-20, 0, 25]
    merged = plan.temperatures.stability_for(steps[2])
    assert (merged.band_c, merged.dwell_s) == (0.3, 60)  # band from the step, dwell from the plan
    ranged = Plan.model_validate({
        "name": "r", "fields": {"kind": "cube24"}, "samples_per_point": 1,
        "temperatures": {"range": {"start_c": 60, "stop_c": -20, "step_c": -20}}})
    assert [s.setpoint_c for s in ranged.temperatures.step_list()] == [60, 40, 20, 0, -20]


def test_station_resolution_cli_then_plan_then_default(tmp_path):
    write(tmp_path, "station.yaml", STATION)
    plan_text = PLAN.replace("BAND", "0.3")
    (tmp_path / "plans").mkdir()
    with_station = write(tmp_path, "plans/a.yaml", plan_text + "station: ../station.yaml\n")
    without = write(tmp_path, "plans/b.yaml", plan_text)
    assert load_campaign(with_station).station.name == "s"
    assert load_campaign(without).station_path == DEFAULT_STATION
    assert load_campaign(without, DEFAULT_STATION).station.name == "sim"
    campaign = load_campaign(with_station, DEFAULT_STATION)
    assert campaign.station.name == "sim" and campaign.plan_text == with_station.read_text()
    assert campaign.station_text == DEFAULT_STATION.read_text()


def test_simulation_is_explicit_per_device(tmp_path):
    station = load_station(write(tmp_path, "station.yaml", STATION))
    assert station.simulated_devices() == {"chamber": True, "coils": True, "m0": False, "tmp0": True}
    assert isinstance(station, Station)


def test_a_key_given_twice_is_an_error(tmp_path):
    text = PLAN.replace("BAND", "0.3") + "samples_per_point: 4\n"
    msg = error_of(load_plan, write(tmp_path, "p.yaml", text))
    assert msg == f"{tmp_path / 'p.yaml'}: samples_per_point: key given twice (lines 12 and 13)"


def test_bare_off_in_yaml_means_off(tmp_path):
    plan = load_plan(write(tmp_path, "p.yaml", PLAN.replace("BAND", "0.3") + "set_reset: off\n"))
    assert plan.set_reset == "off"


def test_simulated_truths_are_seeded_per_dut_and_explicit_ones_are_kept(tmp_path):
    explicit = STATION.replace("transport: {kind: i2c, bus: 1, address: 0x30}", "transport: {kind: sim}")
    explicit += textwrap.dedent("""\
        sim:
          seed: 11
          duts:
            m0:
              truth: {S: [[1.01, 0, 0], [0, 0.99, 0], [0, 0, 1]], b_nt: [100, -50, 20]}
              noise_nt: 0
              thermal_lag_s: 120
        """)
    station = load_station(write(tmp_path, "s.yaml", explicit))
    truth = dut_truths(station)["m0"]
    assert truth.S[0, 0] == 1.01 and list(truth.b_nt) == [100, -50, 20] and truth.thermal_lag_s == 120
    assert not truth.K.any() and truth.noise_nt == 0
    sim = load_station(DEFAULT_STATION)
    a, b = dut_truths(sim), dut_truths(sim)
    assert set(a) == {"mmc0", "serial0"}
    assert (a["mmc0"].S == b["mmc0"].S).all() and not (a["mmc0"].S == a["serial0"].S).all()
    assert a["serial0"].thermal_lag_s == sim.sim.duts["serial0"].thermal_lag_s


def test_simulated_ambient_and_site_defaults(tmp_path):
    station = load_station(write(tmp_path, "s.yaml", STATION.replace("ambient_nt: [0, 0, 0]",
                                                                     "ambient_nt: [1, 2, 3]")))
    world = world_field(station)
    assert list(world["ambient_nt"]) == [1, 2, 3]  # the coils' stated ambient
    sim = load_station(DEFAULT_STATION)
    assert list(world_field(sim)["ambient_nt"]) == [15000, 500, 42000]
    data = station.model_dump()
    data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"},
                            "site_field": {"reference_magnetometer": "ref0"}}
    data["reference_magnetometers"] = [{"name": "ref0", "type": "mmc5983ma", "transport": {"kind": "sim"},
                                        "calibration": "ref0.t24.yaml"}]
    table = Station.model_validate(data)
    assert list(world_field(table)["site_field_nt"]) == list(TYPICAL_FIELD_NT)


def test_dut_options_build_their_drivers_through_the_registry():
    from drivers.clock import SimClock
    from drivers.hmc5883l import OUTPUT_RATE_HZ
    from drivers.registry import I2cLink, SerialLink

    links = {"i2c": I2cLink(object(), 0x30), "serial": SerialLink("/dev/null-not-opened", 9600, 0.5)}
    station = load_station(CONFIGS_DIR / "stations" / "lab-example.yaml")
    built = {}
    for dut in station.duts:
        for set_reset in (True, False):  # constructing does no I/O
            driver = dut.spec.build(links[dut.transport.kind], dut.options, name=dut.name, clock=SimClock(),
                                    set_reset=set_reset)
            assert driver.name == dut.name
            built[dut.name, set_reset] = driver
    assert OUTPUT_RATE_HZ[built["hmc-b", True].output_rate_code] == station.dut("hmc-b").options.rate_hz
    assert built["mmc-a", True].set_reset is True and built["mmc-a", False].set_reset is False
    assert built["ser-c", True].set_reset == "pulse" and built["ser-c", False].set_reset == "off"


def test_rates_a_device_cannot_run_at_are_refused(tmp_path):
    text = STATION.replace("    temp_source: tmp0", "    options: {bandwidth_hz: 300}\n    temp_source: tmp0")
    assert "duts[0].options.bandwidth_hz" in error_of(load_station, write(tmp_path, "s.yaml", text))
    hmc = STATION.replace("type: mmc5983ma", "type: hmc5883l").replace(
        "    temp_source: tmp0", "    options: {rate_hz: 220}\n    temp_source: tmp0")
    msg = error_of(load_station, write(tmp_path, "s.yaml", hmc))
    assert "duts[0].options.rate_hz: hmc5883l runs at one of 0.75, 1.5, 3, 7.5, 15, 30, 75 Hz" in msg
