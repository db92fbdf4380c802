"""Reference magnetometers in the station: refused without one where 'measure' needs it, their calibration
files checked with located errors, the shipped simulated reference's file matching its simulated truth,
the plan's currents re-checked with a measured ambient, and the simulated world's ambient drift."""

from __future__ import annotations

import copy
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from calib.io import calfile
from drivers.clock import SimClock
from drivers.sim.world import World
from rig.config import CONFIGS_DIR, Station, load_station
from rig.config.loading import load_campaign
from rig.core.errors import ConfigError, LimitError
from rig.devices.simulated.world import reference_truths
from rig.devices.simulated.world import world_field as bench_world_field
from rig.reference.sitefield import load_reference_calibrations
from rig.schedules.compile import compile_plan

STATION = CONFIGS_DIR / "stations" / "sim-measured-ambient.yaml"
REFERENCE_CAL = CONFIGS_DIR / "stations" / "sim-reference-cal.yaml"
DEMO = CONFIGS_DIR / "plans" / "demo.yaml"


def station_text(change=None) -> str:
    data = yaml.safe_load(STATION.read_text())
    if change is not None:
        change(data)
    return yaml.safe_dump(data, sort_keys=False)


def load_error(tmp_path: Path, change) -> str:
    path = tmp_path / "station.yaml"
    path.write_text(station_text(change))
    with pytest.raises(ConfigError) as info:
        load_station(path)
    return str(info.value)


def test_measure_without_a_reference_magnetometer_is_refused_naming_the_key_and_line(tmp_path):
    def no_reference(data):
        del data["reference_magnetometers"]
        del data["sim"]["duts"]["sitefield"]

    msg = load_error(tmp_path, no_reference)
    assert msg.startswith(f"{tmp_path / 'station.yaml'}: field_source.ambient_nt: 'measure' needs a "
                          "reference magnetometer")
    assert "add one under reference_magnetometers" in msg and "(line " in msg


def test_the_reference_must_be_named_when_there_are_several_and_must_exist(tmp_path):
    def two(data):
        second = copy.deepcopy(data["reference_magnetometers"][0]) | {"name": "sitefield2"}
        data["reference_magnetometers"].append(second)

    assert "field_source.reference_magnetometer: the station has several reference magnetometers" in \
        load_error(tmp_path, two)

    def unknown(data):
        data["field_source"]["reference_magnetometer"] = "mmc0"

    msg = load_error(tmp_path, unknown)
    assert "field_source.reference_magnetometer: no reference magnetometer named 'mmc0'" in msg


def test_a_reference_truth_cannot_be_drawn_at_random(tmp_path):
    def random_truth(data):
        data["sim"]["duts"]["sitefield"]["truth"] = "random"

    assert "sim.duts.sitefield.truth: a reference magnetometer's truth is its calibration file" in \
        load_error(tmp_path, random_truth)


def test_the_shipped_reference_calibration_is_the_simulated_truth():
    station = load_station(STATION)
    cal = load_reference_calibrations(station, STATION, STATION.read_text())["sitefield"]
    truth = reference_truths(station)["sitefield"]
    assert cal.model == "t24" and cal.source["device_type"] == station.reference_magnetometers[0].type
    for key in ("S", "K", "b_nt", "kb_nt_per_c"):
        assert np.allclose(cal.params[key], getattr(truth, key), rtol=0, atol=1e-12), key
    assert not np.allclose(truth.S, np.eye(3))  # a calibration that is not applied would show


@pytest.fixture
def station_dir(tmp_path) -> Path:
    shutil.copy(REFERENCE_CAL, tmp_path / "sim-reference-cal.yaml")
    return tmp_path


def calibration_error(station_dir: Path, change=None, cal_change=None) -> str:
    if cal_change is not None:
        cal = calfile.load(REFERENCE_CAL)
        cal_change(cal)
        calfile.save(cal, station_dir / "sim-reference-cal.yaml")
    path = station_dir / "station.yaml"
    text = station_text(change)
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_reference_calibrations(load_station(path), path, text)
    return str(info.value)


def test_a_missing_calibration_file_is_a_located_error(station_dir):
    def elsewhere(data):
        data["reference_magnetometers"][0]["calibration"] = "cals/ref.yaml"

    msg = calibration_error(station_dir, elsewhere)
    assert msg.startswith(f"{station_dir / 'station.yaml'}: reference_magnetometers[0].calibration: "
                          f"{station_dir / 'cals' / 'ref.yaml'}: calibration file not found (line ")


def test_a_calibration_of_the_wrong_model_or_device_is_refused(station_dir):
    def scalar(cal):
        cal.model = "scalar"
        cal.params = {"A": np.eye(3), "c_nt": np.zeros(3)}
        cal.std_errors = {"A": np.zeros((3, 3)), "c_nt": np.zeros(3)}
        cal.uncertainty = {**cal.uncertainty, "expanded": {"A": np.zeros((3, 3)), "c_nt": np.zeros(3)}}

    msg = calibration_error(station_dir, cal_change=scalar)
    assert "reference_magnetometers[0].calibration:" in msg and "a scalar calibration" in msg
    assert "needs a vector model (t24, p12, t36)" in msg

    def other_device(cal):
        cal.source["device_type"] = "serialmag"

    msg = calibration_error(station_dir, cal_change=other_device)
    assert "made for a serialmag, not this mmc5983ma" in msg


def test_a_temperature_dependent_calibration_needs_a_temperature_source(station_dir):
    def no_temperature(data):
        del data["reference_magnetometers"][0]["temp_source"]

    msg = calibration_error(station_dir, no_temperature)
    assert "reference_magnetometers[0].temp_source: its t24 calibration has temperature terms" in msg


def test_the_plan_currents_are_checked_again_with_the_measured_ambient():
    campaign = load_campaign(DEMO, STATION)
    source = campaign.station.field_source
    points = compile_plan(campaign.plan, campaign.station)
    source.check_measured("demo", points, [16_000.0, -300.0, 43_000.0])  # the simulated ambient: fine
    with pytest.raises(LimitError) as info:
        source.check_measured("demo", points, [0.0, 0.0, 62_000.0])
    msg = str(info.value)
    assert "point T01-F06 field (0, 0, -50000) nT needs 2.240 A in coil z with the measured ambient " \
           "(0, 0, 62000) nT, above field_source.max_current_a 2 A" in msg


def test_the_field_source_interface_says_what_to_measure():
    station = load_station(STATION)
    coils = station.field_source
    assert coils.needs_measurement() and coils.measuring_magnetometer(["sitefield"]) == "sitefield"
    assert coils.measurement_setting() == (0.0, 0.0, 0.0) and coils.drift_max_nt() == 200
    data = station.model_dump()
    data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"},
                            "site_field": {"reference_magnetometer": "sitefield", "drift_max_nt": 50}}
    table = Station.model_validate(data).field_source
    assert table.needs_measurement() and table.measurement_setting() == (0.0, 0.0)
    assert table.drift_max_nt() == 50 and table.measured_name == "site field"
    data["field_source"]["site_field"] = {"vector_nt": [1, 2, 3]}
    assert not Station.model_validate(data).field_source.needs_measurement()


def test_the_simulated_ambient_drifts_steadily():
    clock = SimClock()
    world = World(clock, ambient_nt=(100.0, 0.0, 0.0), ambient_drift_nt_per_s=(0.5, 0.0, -0.25))
    assert np.allclose(world.lab_field_nt(), [100.0, 0.0, 0.0])
    clock.sleep(400.0)
    assert np.allclose(world.lab_field_nt(), [300.0, 0.0, -100.0])
    station = load_station(STATION)
    data = station.model_dump()
    data["sim"]["ambient_drift_nt_per_h"] = [360.0, 0.0, 0.0]
    world_field = bench_world_field(Station.model_validate(data))
    assert np.allclose(world_field["ambient_drift_nt_per_s"], [0.1, 0.0, 0.0])
