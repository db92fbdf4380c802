"""The shipped 64-DUT station (configs/stations/sim-64.yaml): every address on it reachable and each DUT
answering with its own field; a 64-DUT file with a clash refused with a located message."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rig import config as cfg
from rig.core.errors import ConfigError
from rig.devices.build import open_rig
from rig.devices.interleave import read_all
from tests.system.campaign_helpers import REPO

STATION = REPO / "configs" / "stations" / "sim-64.yaml"
ROUNDS = 4  # readings of every DUT, averaged against the noise


def test_sim64_uses_every_channel_of_eight_switches_on_one_bus():
    station = cfg.load_station(STATION)
    assert len(station.duts) == 64 and len(station.temperature_sensors) == 64
    muxed = [d.transport for d in station.devices() if getattr(d.transport, "mux", None) is not None]
    assert {t.bus for t in muxed} == {1}
    channels = {(t.mux.address, t.mux.channel) for t in muxed}
    assert channels == {(a, c) for a in range(0x70, 0x78) for c in range(8)}
    lines = {}
    for d in station.duts:
        if getattr(d.transport, "line", None):
            lines.setdefault(d.transport.line, []).append(d.device_options.device_id)
    assert len(lines) == 2 and all(len(ids) == len(set(ids)) == 2 for ids in lines.values())


def test_every_device_of_sim64_answers_at_its_address_with_its_own_reading():
    station = cfg.load_station(STATION)
    rig = open_rig(station)
    try:
        switches = rig.built.devices["sim i2c-1 switches"].bus
        temps = read_all(rig.temp_sensors, rig.clock)
        t0 = rig.clock.now()
        rounds = [read_all(rig.duts, rig.clock) for _ in range(ROUNDS)]
        all_s = (rig.clock.now() - t0) / ROUNDS
        one = rig.duts["mmc00"]
        t0 = rig.clock.now()
        one.read()
        single_s = rig.clock.now() - t0
        world = rig.world
        truths = {name: (world.dut_raw_nt(name, 1, noisy=False) - world.dut_raw_nt(name, -1, noisy=False)) / 2
                  for name in rig.duts}
    finally:
        rig.close()
    assert set(temps) == {s.name for s in station.temperature_sensors}
    assert all(abs(r.temp_c - station.sim.air_c) < 2.0 for r in temps.values())
    names = [d.name for d in station.duts]
    assert all(set(r) == set(names) for r in rounds)
    mean = np.array([np.mean([r[n].field_nt for r in rounds], axis=0) for n in names])
    truth = np.array([truths[n] for n in names])
    # each reads its own chip: nearest to its own truth of all 64 (the closest two differ by ~80 nT, the
    # mean of ROUNDS readings is within ~25 nT of its truth), so a crossed channel would show
    nearest = np.argmin(np.linalg.norm(mean[:, None] - truth[None], axis=2), axis=1)
    assert [names[k] for k in nearest] == names
    assert all_s < 2 * single_s  # 64 DUTs read in about one DUT's (simulated) time
    assert all(switches.chips[a].control == 0 for a in range(0x70, 0x78))  # safe state: all off


def _load_changed(tmp_path, change) -> cfg.Station:
    data = yaml.safe_load(STATION.read_text())
    change(data)
    path = tmp_path / "sim-64.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return cfg.load_station(path)


def _dut(data, name):
    return next(d for d in data["duts"] if d["name"] == name)


def _sensor(data, name):
    return next(s for s in data["temperature_sensors"] if s["name"] == name)


def _same_channel(data):  # mmc59 moved onto mmc58's channel of switch 0x77
    _dut(data, "mmc59")["transport"]["mux"] = dict(_dut(data, "mmc58")["transport"]["mux"])


def _sensor_on_a_dut_address(data):  # a TMP117 strapped to 0x30 beside the MMC5983MA on its channel
    _sensor(data, "tmp17")["transport"]["address"] = 0x30


def _chip_at_a_switch_address(data):  # a chip behind a channel answering at switch 0x75's address
    _sensor(data, "tmp05")["transport"]["address"] = 0x75


def _ninth_switch(data):
    _dut(data, "mmc10")["transport"]["mux"]["address"] = 0x78


def _channel_eight(data):
    _dut(data, "mmc10")["transport"]["mux"]["channel"] = 8


def _one_id_twice_on_a_line(data):
    _dut(data, "ser1")["options"]["device_id"] = _dut(data, "ser0")["options"]["device_id"]


@pytest.mark.parametrize(("change", "where", "what"), [
    (_same_channel, "duts[59].transport.address", "0x30 on i2c-1 switch 0x77 channel 2 is taken twice: "
                                                  "mmc59 and mmc58 (duts[58])"),
    (_sensor_on_a_dut_address, "temperature_sensors[17].transport.address", "0x30 on i2c-1 switch 0x72 "
                                                                            "channel 1 is taken twice"),
    (_chip_at_a_switch_address, "temperature_sensors[5].transport.address", "address of an I2C switch"),
    (_ninth_switch, "duts[10].transport.mux.address", ""),
    (_channel_eight, "duts[10].transport.mux.channel", ""),
    (_one_id_twice_on_a_line, "duts[61].options.device_id", "device id 1 on line rs485-a is taken twice"),
])
def test_a_clash_on_the_64_dut_station_is_refused_naming_key_and_line(tmp_path, change, where, what):
    with pytest.raises(ConfigError) as err:
        _load_changed(tmp_path, change)
    message = str(err.value)
    assert f"sim-64.yaml: {where}" in message and "(line " in message, message
    assert what in message, message


def test_a_stability_poll_reads_the_64_probes_in_about_one_conversion():
    """rig/run/runner.py's poll reads every DUT's temperature source once, their one-shot conversions
    overlapped (in turn, 64 x 124 ms of simulated time); each value is its DUT's probe's."""
    from types import SimpleNamespace

    from drivers.tmp117 import DEFAULT_AVERAGING, active_time_s
    from rig.run.runner import CampaignRunner, poll_interval_s

    station = cfg.load_station(STATION)
    rig = open_rig(station)
    try:
        t0 = rig.clock.now()
        temps = CampaignRunner._dut_temps(SimpleNamespace(rig=rig))
        poll_s = rig.clock.now() - t0
        truth = {dut: rig.world.dut_temp_c(dut) for dut in rig.duts}
    finally:
        rig.close()
    one_s = active_time_s(DEFAULT_AVERAGING)
    assert set(temps) == {d.name for d in station.duts}
    assert one_s <= poll_s < 2 * one_s
    assert all(abs(temps[dut] - truth[dut]) < 0.01 for dut in temps)  # 7.8 mdegC steps, no lag set
    demo = cfg.load_plan(REPO / "configs" / "plans" / "demo.yaml").temperatures.stability
    assert poll_interval_s(SimpleNamespace(dwell_s=demo.dwell_s)) == demo.dwell_s / 4
