"""TMP117: pure decoding, datasheet transcripts, and the driver against the register-level simulator."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.errors import DeviceNotFound, DeviceTimeout, OptionError, ProtocolError
from drivers.sim.devices.tmp117 import TMP117Sim
from drivers.sim.transports.i2c_bus import FakeSMBus
from drivers.sim.world import DutTruth, World
from drivers.tmp117 import TMP117, config_word, cycle_time_s, decode_temp_c
from tests.helpers.smbus_doubles import RecordingSMBus, ScriptedSMBus

LSB_C = 0.0078125

# --- literal bytes from the datasheet ---------------------------------------------------------------
ID = ("read", 0x0F, b"\x01\x17")  # DEVICE_ID
SHUTDOWN = ("write", 0x01, b"\x06\x20")  # MOD 01 shutdown, CONV 100, AVG 01 (8)
ONE_SHOT = [
    ("write", 0x01, b"\x0e\x20"),  # MOD 11 one-shot, CONV 100, AVG 01
    ("read", 0x01, b"\x0e\x20"),  # Data_Ready (bit 13) not yet
    ("read", 0x01, b"\x26\x20"),  # Data_Ready, back in shutdown
    ("read", 0x00, b"\x0c\x80"),  # 3200 x 7.8125 m degC = 25.0 degC
]


def scripted(script, **kw) -> tuple[TMP117, ScriptedSMBus, SimClock]:
    bus = ScriptedSMBus(0x48, script)
    clock = SimClock()
    return TMP117(bus, name="tmp1", clock=clock, **kw), bus, clock


# --- pure functions ---------------------------------------------------------------------------------
def test_decode_big_endian_two_complement() -> None:
    assert decode_temp_c(b"\x0c\x80") == 25.0
    assert decode_temp_c(b"\xff\x80") == -1.0
    assert decode_temp_c(b"\x00\x01") == LSB_C
    assert decode_temp_c(b"\x80\x00") == -256.0


def test_config_word_and_cycle_time() -> None:
    assert config_word(0b00, 8, 4) == b"\x02\x20"  # the power-on default: continuous, 1 s, 8 averages
    assert config_word(0b11, 1, 0) == b"\x0c\x00"
    assert config_word(0b01, 64, 7) == b"\x07\xe0"
    assert cycle_time_s(8, 4) == 1.0
    assert cycle_time_s(64, 0) == pytest.approx(0.992)  # averaging outlasts a short CONV setting


# --- transcripts ------------------------------------------------------------------------------------
def test_connect_and_one_shot_transcript() -> None:
    dev, bus, clock = scripted([ID, SHUTDOWN, *ONE_SHOT])
    dev.connect()
    start = clock.now()
    sample = dev.read()
    bus.assert_done()
    assert sample.temp_c == 25.0 and not sample.flags
    assert clock.now() - start == pytest.approx(8 * 0.0155 + 0.001, abs=1e-6)


def test_continuous_transcript() -> None:
    dev, bus, _ = scripted([
        ID,
        ("write", 0x01, b"\x02\x20"),  # MOD 00 continuous
        ("read", 0x01, b"\x22\x20"),  # Data_Ready
        ("read", 0x00, b"\xff\x80"),  # -1.0 degC
    ], mode="continuous")
    dev.connect()
    assert dev.read().temp_c == -1.0
    bus.assert_done()


def test_tmp119_id_is_refused_with_a_hint() -> None:
    dev, _, _ = scripted([("read", 0x0F, b"\x21\x17")])
    expected = r"tmp1: check device id \(register 0x0F\): read 0x2117 \(that is a TMP119\)"
    with pytest.raises(ProtocolError, match=expected):
        dev.connect()


def test_safe_state_transcript() -> None:
    dev, bus, _ = scripted([SHUTDOWN])
    dev.safe_state()
    bus.assert_done()


def test_bad_options_are_config_errors() -> None:
    with pytest.raises(OptionError, match="averaging 4: must be 1, 8, 32 or 64"):
        TMP117(FakeSMBus(), averaging=4)
    with pytest.raises(OptionError, match="mode 'fast'"):
        TMP117(FakeSMBus(), mode="fast")


# --- against the simulator --------------------------------------------------------------------------
@pytest.fixture
def world() -> World:
    world = World(SimClock(), air_c=20.0, ramp_c_per_min=5.0)
    world.add_dut("dut1", DutTruth.random(np.random.default_rng(2), thermal_lag_s=60.0), temp_c=20.0)
    return world


def make_rig(world: World, offset_c: float = 0.0, **kw):
    bus = FakeSMBus()
    sim = TMP117Sim(world, "dut1", offset_c=offset_c)
    bus.attach(0x48, sim)
    dev = TMP117(bus, name="tmp1", clock=world.clock, **kw)
    dev.connect()
    return dev, bus, sim


def test_one_shot_reads_the_dut_temperature_plus_sensor_offset(world: World) -> None:
    dev, _, _ = make_rig(world, offset_c=0.04)
    assert dev.read().temp_c == pytest.approx(20.04, abs=LSB_C)
    world.set_chamber_setpoint(40.0)
    world.clock.sleep(600)
    sample = dev.read()
    assert sample.temp_c == pytest.approx(world.dut_temp_c("dut1") + 0.04, abs=LSB_C)
    assert sample.temp_c > 35.0


def test_continuous_mode_follows_the_world(world: World) -> None:
    dev, _, _ = make_rig(world, mode="continuous", averaging=1, conversion_code=4)
    world.set_chamber_setpoint(30.0)
    readings = [dev.read() for _ in range(3)]
    assert [r.t for r in readings] == sorted(r.t for r in readings)
    assert np.diff([r.t for r in readings]) == pytest.approx([1.0, 1.0], abs=0.002)
    assert readings[-1].temp_c > readings[0].temp_c  # warming at 5 degC/min


def test_stuck_sensor_is_visible(world: World) -> None:
    dev, _, sim = make_rig(world)
    sim.stuck_c = 21.5
    world.set_chamber_setpoint(50.0)
    first = dev.read().temp_c
    world.clock.sleep(900)
    assert dev.read().temp_c == first == 21.5
    assert world.dut_temp_c("dut1") > 40.0


def test_data_ready_never_set_times_out(world: World) -> None:
    dev, _, sim = make_rig(world)
    sim.never_ready = True
    with pytest.raises(DeviceTimeout, match=r"tmp1: wait for Data_Ready .* not ready after 497\.0 ms"):
        dev.read()


def test_simulator_word_order_data_ready_and_offset_register(world: World) -> None:
    _, bus, _ = make_rig(world, mode="continuous")
    assert bus.read_word_data(0x48, 0x0F) == 0x1701  # SMBus words are little-endian: swapped
    assert bus.read_i2c_block_data(0x48, 0x00, 2) == [0x80, 0x00]  # no conversion yet: -256 degC
    world.clock.sleep(1.0)
    assert bus.read_i2c_block_data(0x48, 0x01, 2)[0] & 0x20  # Data_Ready ...
    assert not bus.read_i2c_block_data(0x48, 0x01, 2)[0] & 0x20  # ... cleared by reading the configuration
    bus.write_i2c_block_data(0x48, 0x07, [0x01, 0x00])  # TEMP_OFFSET +2.0 degC
    world.clock.sleep(1.0)
    result = decode_temp_c(bytes(bus.read_i2c_block_data(0x48, 0x00, 2)))
    assert result == pytest.approx(world.dut_temp_c("dut1") + 2.0, abs=LSB_C)


def test_nack_then_replug(world: World, caplog) -> None:
    dev, bus, sim = make_rig(world)
    bus.detach(0x48)
    with pytest.raises(DeviceNotFound) as err:
        dev.read()
    assert str(err.value) == "tmp1: write configuration register 0x01: no ACK at 0x48 (after 3 tries)"
    with caplog.at_level(logging.WARNING, logger="magrig.drivers.tmp117"):
        dev.safe_state()
    assert "tmp1: safe state not confirmed" in caplog.text
    bus.attach(0x48, sim)
    assert dev.read().temp_c == pytest.approx(20.0, abs=0.1)


def test_describe(world: World) -> None:
    info = make_rig(world)[0].describe()
    assert info["model"] == "TMP117" and info["address"] == "0x48" and info["product_id"] == "0x0117"
    assert info["resolution_c"] == LSB_C and info["range_c"] == (-55.0, 150.0)


def test_simulator_speaks_the_datasheet_bytes() -> None:
    world = World(SimClock(), air_c=25.0)
    world.add_dut("dut1", DutTruth.random(np.random.default_rng(0)))
    recorder = RecordingSMBus.with_chip(0x48, TMP117Sim(world, "dut1"))
    TMP117(recorder, name="tmp1", clock=world.clock).connect()
    assert recorder.calls[0].data == b"\x01\x17"
    recorder.calls.clear()
    TMP117(recorder, name="tmp1", clock=world.clock).read()
    assert recorder.transcript() == [
        ("write", 0x01, b"\x0e\x20"),
        ("read", 0x01, b"\x26\x20"),  # Data_Ready, and the one-shot has put the chip in shutdown
        ("read", 0x00, b"\x0c\x80"),  # 25.0 degC
    ]
