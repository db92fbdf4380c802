"""`transport: {kind: sim, faults: ...}`: strict, located, and only what the device's protocol can do;
the frozen-reading rule the campaign applies to temperature sources."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from rig.config import Station
from rig.core.errors import ConfigError
from rig.core.yamlload import load_model
from rig.engine.frozen import FrozenReadings

REPO = Path(__file__).resolve().parents[3]
SIM = yaml.safe_load((REPO / "configs" / "stations" / "sim.yaml").read_text())


def load_with(path: tuple, faults) -> Station:
    station = copy.deepcopy(SIM)
    node = station
    for key in path:
        node = node[key]
    node["transport"]["faults"] = faults
    return load_model(Station, "station.yaml", yaml.safe_dump(station, sort_keys=False))


def test_the_shipped_fault_station_loads_with_faults_on_every_device():
    station = load_model(Station, "sim-faults.yaml", (REPO / "configs/stations/sim-faults.yaml").read_text())
    assert all(dev.transport.faults is not None for dev in station.devices())


@pytest.mark.parametrize(("path", "faults", "message"), [
    (("duts", 0), {"no_reply": 100}, "duts[0].transport.faults.no_reply: a mmc5983ma (i2c) cannot have "
                                     "no_reply faults (its protocol allows: nack, unplug)"),
    (("duts", 1), {"nack": 100}, "duts[1].transport.faults.nack: a serialmag (serial) cannot have nack"),
    (("chamber",), {"nack": 100}, "chamber.transport.faults.nack: a watlow_f4t (modbus) cannot have nack"),
    (("duts", 1), {"stuck_temperature": True}, "stuck_temperature: a serialmag measures no temperature"),
    (("field_source",), {"alarm": {"after_s": 10}}, "alarm: only a chamber has an alarm, not a coils"),
    (("chamber",), {"garbled": 1}, "chamber.transport.faults.garbled: must be >= 2"),
    (("chamber",), {"unplug": {"after_s": -1}}, "unplug.after_s: must be >= 0"),
    (("temperature_sensors", 0), {"nack": 100, "smoke": 3}, "faults.smoke: unknown key"),
])
def test_a_fault_the_device_cannot_have_is_refused_where_it_is(path, faults, message):
    with pytest.raises(ConfigError, match=r"^station\.yaml: .*\(line \d+\)$") as err:
        load_with(path, faults)
    assert message in str(err.value)


def test_an_alarm_needs_the_chamber_alarm_register():
    station = copy.deepcopy(SIM)
    del station["chamber"]["alarm"]
    station["chamber"]["transport"]["faults"] = {"alarm": {"after_s": 5, "for_s": 5}}
    with pytest.raises(ConfigError, match="watlow_f4t has no alarm register"):
        load_model(Station, "station.yaml", yaml.safe_dump(station, sort_keys=False))


def test_faults_a_device_can_have_are_kept():
    station = load_with(("temperature_sensors", 0), {"nack": 50, "stuck_temperature": {"after_s": 60}})
    faults = station.temperature_sensors[0].transport.faults
    assert faults.nack == 50
    assert faults.stuck_temperature.after_s == 60 and faults.stuck_temperature.for_s is None


def test_a_reading_frozen_while_the_air_moves_is_reported_once_long_enough():
    watch = FrozenReadings(air_move_c=2.0, min_s=600)
    assert watch.add("tmp0", 0, 22.5, 22.0) is None
    assert watch.add("tmp0", 300, 22.5, 30.0) is None  # not long enough yet
    problem = watch.add("tmp0", 600, 22.5, 35.0)
    assert problem is not None and problem.startswith("tmp0: temperature frozen at 22.5000 degC for 600 s")


def test_a_steady_reading_in_steady_air_or_a_moving_one_is_no_fault():
    watch = FrozenReadings(air_move_c=2.0, min_s=600)
    for t in range(0, 7200, 60):
        assert watch.add("tmp0", t, 40.0, 40.0 + (t % 120) / 100) is None  # air within a degree
        assert watch.add("tmp1", t, 20.0 + t / 1000, 20.0 + t / 100) is None  # follows the air
