"""Many DUTs: I2C switches and a shared serial line in a simulated station, wiring refused at load,
switch faults named as the switch's, and acceptance verdicts with their exit code and summary CSV."""

from __future__ import annotations

import csv

import pytest
import yaml

from drivers.errors import DeviceNotFound, ProtocolError
from rig import config as cfg
from rig.core.errors import ConfigError
from rig.devices.build import open_rig
from tests.system.campaign_helpers import REPO, run_rig, small_plan

SWITCH = "sim i2c-1 switch 0x70"


def station_text(duts: list[dict], sensors: list[dict]) -> str:
    base = yaml.safe_load((REPO / "configs" / "stations" / "sim.yaml").read_text())
    base["sim"] = {"seed": 7}
    base["duts"], base["temperature_sensors"] = duts, sensors
    return yaml.safe_dump(base, sort_keys=False)


def muxed_mmc(name: str, channel: int, address: int = 0x30) -> dict:
    mux = {"address": 0x70, "channel": channel}
    return {"name": name, "type": "mmc5983ma", "temp_source": "self",
            "transport": {"kind": "sim", "bus": 1, "address": address, "mux": mux}}


def load(tmp_path, duts, sensors=()) -> cfg.Station:
    path = tmp_path / "station.yaml"
    path.write_text(station_text(list(duts), list(sensors)))
    return cfg.load_station(path)


def test_three_chips_at_0x30_behind_one_switch_each_read_their_own_field(tmp_path):
    station = load(tmp_path, [muxed_mmc(f"mmc{c}", c) for c in range(3)])
    rig = open_rig(station)
    try:
        bus = rig.built.devices["sim i2c-1 switches"].bus
        switch_sim = bus.chips[0x70]
        readings = {}
        for channel, (name, dut) in enumerate(rig.duts.items()):
            readings[name] = dut.read().field_nt
            assert switch_sim.control == 1 << channel  # only this chip's channel is on
            truth = rig.world.dut_raw_nt(name, 1) - rig.world.dut_raw_nt(name, -1)
            assert readings[name] == pytest.approx(tuple(truth / 2), abs=300)
        assert len({tuple(round(x) for x in r) for r in readings.values()}) == 3
    finally:
        rig.close()
    assert switch_sim.control == 0  # safe state: every channel off


def test_an_absent_switch_is_the_switchs_fault_not_the_dut(tmp_path):
    rig = open_rig(load(tmp_path, [muxed_mmc("mmc0", 0), muxed_mmc("mmc1", 1)]))
    try:
        bus = rig.built.devices["sim i2c-1 switches"].bus
        bus.nack(0x70)
        with pytest.raises(DeviceNotFound) as err:
            rig.duts["mmc1"].read()
        assert err.value.device == SWITCH and "mmc1" not in err.value.device
        assert "fault of the I2C switch" in str(err.value)
    finally:
        bus.nack(0x70, 0)
        rig.close()


def test_a_switch_reading_back_the_wrong_byte_is_the_switchs_fault(tmp_path):
    rig = open_rig(load(tmp_path, [muxed_mmc("mmc0", 0), muxed_mmc("mmc1", 1)]))
    try:
        switch_sim = rig.built.devices["sim i2c-1 switches"].bus.chips[0x70]
        switch_sim.readback = 0x05
        with pytest.raises(ProtocolError) as err:
            rig.duts["mmc0"].read()
        assert err.value.device == SWITCH
        assert "read back 0x05" in str(err.value)
    finally:
        switch_sim.readback = None
        rig.close()


def test_two_chips_at_one_address_on_one_channel_are_refused_at_load_naming_both(tmp_path):
    with pytest.raises(ConfigError) as err:
        load(tmp_path, [muxed_mmc("mmc0", 2), muxed_mmc("mmc1", 2)])
    message = str(err.value)
    assert "station.yaml: duts[1].transport.address:" in message and "(line " in message
    assert "taken twice: mmc1 and mmc0 (duts[0])" in message


def test_a_chip_at_a_switch_address_is_refused(tmp_path):
    with pytest.raises(ConfigError, match="address of an I2C switch"):
        load(tmp_path, [muxed_mmc("mmc0", 0), muxed_mmc("mmc1", 1, address=0x70)])


def serialmag(name: str, device_id: int) -> dict:
    return {"name": name, "type": "serialmag", "temp_source": f"t_{name}",
            "transport": {"kind": "sim", "line": "rs485"}, "options": {"device_id": device_id, "rate_hz": 50}}


def tmp117_beside(dut: str) -> dict:
    return {"name": f"t_{dut}", "type": "tmp117", "transport": {"kind": "sim"}, "beside": dut}


def test_three_serial_magnetometers_share_one_line_by_device_id(tmp_path):
    names = ["s1", "s2", "s3"]
    station = load(tmp_path, [serialmag(n, i + 1) for i, n in enumerate(names)],
                   [tmp117_beside(n) for n in names])
    rig = open_rig(station)
    try:
        ports = {rig.duts[n].transport.port for n in names}
        assert len(ports) == 1  # one pty for the three
        assert all(rig.duts[n].describe()["shared_line"] for n in names)
        readings = {n: rig.duts[n].read().field_nt for n in names}
        for n in names:
            truth = (rig.world.dut_raw_nt(n, 1) - rig.world.dut_raw_nt(n, -1)) / 2
            assert readings[n] == pytest.approx(tuple(truth), abs=300)
    finally:
        rig.close()


def test_two_serial_devices_with_one_id_on_a_line_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="device id 2 on line rs485 is taken twice: s2 and s1"):
        load(tmp_path, [serialmag("s1", 2), serialmag("s2", 2)], [tmp117_beside("s1"), tmp117_beside("s2")])


def _plan_with_acceptance(tmp_path, name: str, acceptance: dict):
    path = small_plan(tmp_path, name=name, steps=(20, 30), samples=2, dwell_s=30)
    plan = yaml.safe_load(path.read_text())
    plan["fields"] = {"kind": "fibonacci", "n": 24, "magnitude_nt": 50000}
    # stable as the plan's defaults judge it: a looser wait leaves a DUT short of an end, which
    # acceptance fails (its data would not cover the plan's range)
    plan["temperatures"]["stability"] = {"band_c": 0.5, "rate_c_per_min": 0.1, "dwell_s": 120}
    plan["acceptance"] = acceptance
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return path


@pytest.mark.parametrize(("acceptance", "code", "verdicts"), [
    ({"max_heldout_rms_nt": 500, "bounds": {"b_nt": [-5000, 5000]}}, 0, {"PASS"}),
    ({"max_heldout_rms_nt": 1.0}, 3, {"FAIL"}),
])
def test_acceptance_exit_code_and_summary_csv(tmp_path, acceptance, code, verdicts):
    plan = _plan_with_acceptance(tmp_path, "acc", acceptance)
    out = tmp_path / "out"
    result = run_rig("run", str(plan), "--out", str(out), "--no-live", timeout=240)
    assert result.returncode == code, result.stderr
    (summary,) = out.glob("*.acceptance.csv")
    rows = list(csv.DictReader(summary.open()))
    assert {r["dut"] for r in rows} == {"mmc0", "serial0"}
    assert {r["verdict"] for r in rows} == verdicts
    for r in rows:
        assert float(r["heldout_rms_nt"]) > 0 and r["session"].endswith(".session")
        assert ("heldout_rms" in r["failed"]) == (r["verdict"] == "FAIL")
    if code:
        assert "FAIL" in result.stderr and "mmc0" in result.stderr
    listing = run_rig("sessions", str(out))
    assert ("PASS 2/2" if code == 0 else "FAIL 2/2") in listing.stdout


def test_the_shipped_16_dut_station_loads_and_interleaves(tmp_path):
    """sim-16: 16 DUTs; one interleaved round of readings costs about one DUT's simulated time."""
    from rig.devices.interleave import read_all

    station = cfg.load_station(REPO / "configs" / "stations" / "sim-16.yaml")
    assert len(station.duts) == 16
    rig = open_rig(station)
    try:
        one = next(d for d in rig.duts.values() if hasattr(d, "read_steps"))
        t0 = rig.clock.now()
        one.read()
        single_s = rig.clock.now() - t0
        t0 = rig.clock.now()
        samples = read_all(rig.duts, rig.clock)
        all_s = rig.clock.now() - t0
    finally:
        rig.close()
    assert set(samples) == {d.name for d in station.duts}
    assert all_s < 2 * single_s
