"""HMC5883L / HMC5983: pure decoding, datasheet transcripts, and the driver against the simulator."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.errors import DeviceNotFound, DeviceTimeout, OptionError, ProtocolError
from drivers.hmc5883l import HMC5883L, code_to_nt, config_a, decode_temp_c, decode_xzy
from drivers.sim.devices.hmc5883l import HMC5883LSim
from drivers.sim.transports.i2c_bus import FakeSMBus
from drivers.sim.world import DutTruth, World
from tests.helpers.smbus_doubles import RecordingSMBus, ScriptedSMBus

# --- literal bytes from the datasheet ---------------------------------------------------------------
CONNECT = [
    ("read", 0x0A, b"H43"),  # identification A, B, C
    ("write", 0x00, b"\x70"),  # CRA: 8 averages, 15 Hz, normal measurement
    ("write", 0x01, b"\x20"),  # CRB: GN = 1 (1090 LSB/Ga)
    ("write", 0x02, b"\x03"),  # MR: idle
]
DATA = bytes([0x01, 0x00, 0xFF, 0x00, 0xF0, 0x00])  # X = +256, Z = -256, Y = -4096 (overflow)
DISCARDED = [  # first measurement after a gain write: still the old gain
    ("write", 0x02, b"\x01"),
    ("read", 0x09, b"\x01"),
    ("read", 0x03, bytes(6)),
]
MEASURE = [
    ("write", 0x02, b"\x01"),  # MR: single measurement
    ("read", 0x09, b"\x00"),  # RDY not yet
    ("read", 0x09, b"\x01"),  # RDY
    ("read", 0x03, DATA),
]


def scripted(script, **kw) -> tuple[HMC5883L, ScriptedSMBus, SimClock]:
    bus = ScriptedSMBus(0x1E, script)
    clock = SimClock()
    return HMC5883L(bus, name="dut2", clock=clock, **kw), bus, clock

IDEAL = DutTruth(S=np.eye(3), K=np.zeros((3, 3)), b_nt=np.zeros(3), kb_nt_per_c=np.zeros(3))  # no noise


# --- pure functions ---------------------------------------------------------------------------------
def test_decode_xzy_order_big_endian() -> None:
    assert decode_xzy(DATA) == (256, -4096, -256)
    assert decode_xzy(bytes([0x07, 0xFF, 0xF8, 0x00, 0x00, 0x01])) == (2047, 1, -2048)


def test_code_to_nt_uses_the_gain_table_and_overflow_is_nan() -> None:
    assert code_to_nt(1090, 1) == pytest.approx(100_000.0)
    assert code_to_nt(230, 7) == pytest.approx(100_000.0)
    assert code_to_nt(-1370, 0) == pytest.approx(-100_000.0)
    assert math.isnan(code_to_nt(-4096, 1))


def test_temperature_and_config_a() -> None:
    assert decode_temp_c(b"\x01\x40") == 27.5  # 320 / 128 + 25
    assert decode_temp_c(b"\xff\x00") == 23.0  # -256 / 128 + 25
    assert config_a(8, 4, temperature=False) == 0x70
    assert config_a(1, 4, temperature=False) == 0x10
    assert config_a(8, 7, temperature=True) == 0xFC


# --- transcripts ------------------------------------------------------------------------------------
def test_connect_and_first_read_transcript_with_overflow() -> None:
    dev, bus, clock = scripted(CONNECT + DISCARDED + MEASURE)
    dev.connect()
    start = clock.now()
    sample = dev.read()
    bus.assert_done()
    assert sample.counts == (256, -4096, -256)
    assert sample.field_nt[0] == pytest.approx(256 / 1090 * 100_000)
    assert math.isnan(sample.field_nt[1])
    assert sample.field_nt[2] == pytest.approx(-256 / 1090 * 100_000)
    assert sample.flags == frozenset({"overflow"})
    assert sample.temp_c is None
    assert clock.now() - start == pytest.approx(0.006 + 0.006 + 0.001, abs=1e-6)  # two 6 ms waits, a re-poll


def test_gain_change_discards_one_measurement() -> None:
    dev, bus, _ = scripted([("write", 0x01, b"\xa0")] + DISCARDED + MEASURE + MEASURE)
    dev.set_gain(5)  # 390 LSB/Ga
    assert dev.read().field_nt[0] == pytest.approx(256 / 390 * 100_000)
    dev.read()  # no discard the second time
    bus.assert_done()
    with pytest.raises(OptionError, match="gain code 8"):
        dev.set_gain(8)


def test_wrong_id_is_a_clear_protocol_error() -> None:
    dev, _, _ = scripted([("read", 0x0A, b"H44")])
    expected = r"dut2: check id \(registers 0x0A..0x0C\): read b'H44', expected b'H43'"
    with pytest.raises(ProtocolError, match=expected):
        dev.connect()


def test_hmc5983_temperature_transcript() -> None:
    connect = [CONNECT[0], ("write", 0x00, b"\xf0"), *CONNECT[2:]]  # CRA with TS
    temperature = [("read", 0x31, b"\x01\x40")]
    dev, bus, _ = scripted(connect + DISCARDED + MEASURE + temperature, variant="HMC5983")
    dev.connect()
    assert dev.read().temp_c == 27.5
    bus.assert_done()


def test_safe_state_transcript() -> None:
    dev, bus, _ = scripted([("write", 0x02, b"\x03")])
    dev.safe_state()
    bus.assert_done()


# --- against the simulator --------------------------------------------------------------------------
@pytest.fixture
def world() -> World:
    world = World(SimClock(), ambient_nt=(21_000.0, -4_000.0, 43_000.0), air_c=35.0, seed=5)
    world.add_dut("dut2", DutTruth.random(np.random.default_rng(11), noise_nt=20.0))
    return world


def make_rig(world: World, variant: str = "HMC5883L", **kw):
    bus = FakeSMBus()
    sim = HMC5883LSim(world, "dut2", variant=variant)
    bus.attach(0x1E, sim)
    dev = HMC5883L(bus, name="dut2", clock=world.clock, variant=variant, **kw)
    dev.connect()
    return dev, bus, sim


def expected_nt(world: World) -> np.ndarray:
    return world.dut_raw_nt("dut2", 1, noisy=False)  # the part's own SET leaves the offset in


def test_reading_matches_world_within_noise_and_resolution(world: World) -> None:
    dev, _, _ = make_rig(world)
    sample = dev.read()
    assert np.asarray(sample.field_nt) == pytest.approx(expected_nt(world), abs=5 * 20 + 100_000 / 1090)
    assert not sample.flags


def test_strong_field_overflows_one_axis(world: World) -> None:
    world.ambient_nt = np.array([200_000.0, 0.0, 10_000.0])  # 2 G on X: beyond 2047 / 1370 LSB/Ga
    dev, _, _ = make_rig(world, gain=0)
    sample = dev.read()
    assert sample.flags == frozenset({"overflow"})
    assert sample.counts[0] == -4096 and math.isnan(sample.field_nt[0])
    assert not math.isnan(sample.field_nt[2])
    dev.set_gain(7)  # +-8.1 Ga: fits again
    assert not dev.read().flags


def test_simulator_applies_a_gain_change_from_the_second_measurement(world: World) -> None:
    _, bus, _ = make_rig(world, gain=1)

    def measure_x() -> int:
        bus.write_byte_data(0x1E, 0x02, 0x01)
        world.clock.sleep(0.006)
        assert bus.read_byte_data(0x1E, 0x09) & 0x01
        return decode_xzy(bytes(bus.read_i2c_block_data(0x1E, 0x03, 6)))[0]

    measure_x()
    at_gain_1 = measure_x()
    bus.write_byte_data(0x1E, 0x01, 0xE0)  # GN = 7
    still_gain_1 = measure_x()
    at_gain_7 = measure_x()
    assert still_gain_1 == pytest.approx(at_gain_1, abs=3)
    assert at_gain_7 == pytest.approx(at_gain_1 * 230 / 1090, abs=3)
    assert bus.read_byte_data(0x1E, 0x02) == 0x03  # back to idle after a single measurement


def test_driver_discards_the_stale_gain_measurement(world: World) -> None:
    dev, _, _ = make_rig(world, gain=1)
    dev.read()
    dev.set_gain(6)
    assert np.asarray(dev.read().field_nt) == pytest.approx(expected_nt(world), abs=5 * 20 + 100_000 / 330)


def test_hmc5983_temperature_from_the_world(world: World) -> None:
    dev, _, _ = make_rig(world, variant="HMC5983")
    assert dev.read().temp_c == pytest.approx(world.dut_temp_c("dut2"), abs=1 / 128)
    plain, _, _ = make_rig(world, variant="HMC5883L")
    assert plain.read().temp_c is None


def test_rdy_never_set_times_out(world: World) -> None:
    dev, _, sim = make_rig(world)
    sim.never_ready = True
    with pytest.raises(DeviceTimeout, match=r"dut2: wait for RDY \(status 0x09\): not ready after 25\.0 ms"):
        dev.read()


def test_nack_then_replug(world: World, caplog) -> None:
    dev, bus, sim = make_rig(world)
    bus.nack(0x1E)
    with pytest.raises(DeviceNotFound) as err:
        dev.read()
    assert str(err.value) == (
        "dut2: write mode (single measurement) register 0x02: no ACK at 0x1E (after 3 tries)"
    )
    with caplog.at_level(logging.WARNING, logger="magrig.drivers.hmc5883l"):
        dev.safe_state()
    assert "dut2: safe state not confirmed" in caplog.text
    bus.nack(0x1E, 0)
    assert not math.isnan(dev.read().field_nt[0])


def test_safe_state_stops_continuous_measurements(world: World) -> None:
    dev, bus, _ = make_rig(world)  # Config A: 15 Hz
    bus.write_byte_data(0x1E, 0x02, 0x00)  # MD 00: continuous
    world.clock.sleep(0.07)
    assert bus.read_byte_data(0x1E, 0x09) & 0x01 == 1  # a measurement came by itself
    first = bus.read_i2c_block_data(0x1E, 0x03, 6)
    world.ambient_nt = world.ambient_nt + 20_000.0
    world.clock.sleep(0.07)
    assert bus.read_i2c_block_data(0x1E, 0x03, 6) != first  # and the next one
    dev.safe_state()
    assert bus.read_byte_data(0x1E, 0x02) == 0x03
    stopped = bus.read_i2c_block_data(0x1E, 0x03, 6)
    world.ambient_nt = world.ambient_nt + 20_000.0
    world.clock.sleep(1.0)
    assert bus.read_i2c_block_data(0x1E, 0x03, 6) == stopped  # idle: no new data


def test_describe(world: World) -> None:
    dev, _, _ = make_rig(world, variant="HMC5983", gain=7)
    info = dev.describe()
    assert info["model"] == "HMC5983" and info["address"] == "0x1E" and info["product_id"] == "H43"
    assert info["range_nt"] == pytest.approx(810_000.0)
    assert info["resolution_nt"] == pytest.approx(434.78, abs=0.01)
    assert info["noise_rms_nt"] == 200.0


def test_bad_options_are_config_errors() -> None:
    with pytest.raises(OptionError, match="variant 'HMC5843'"):
        HMC5883L(FakeSMBus(), variant="HMC5843")
    with pytest.raises(OptionError, match="output_rate_code 7: must be 0..6"):
        HMC5883L(FakeSMBus(), output_rate_code=7)


def test_simulator_speaks_the_datasheet_bytes() -> None:
    """Ideal DUT in +1 G, -0.5 G, +0.2 G at gain 1 (1090 LSB/Ga): the simulator's bytes, literally."""
    world = World(SimClock(), ambient_nt=(100_000.0, -50_000.0, 20_000.0))
    world.add_dut("dut2", IDEAL)
    recorder = RecordingSMBus.with_chip(0x1E, HMC5883LSim(world, "dut2"))
    dev = HMC5883L(recorder, name="dut2", clock=world.clock)
    dev.connect()
    dev.read()
    recorder.calls.clear()
    sample = dev.read()
    assert recorder.transcript() == [
        ("write", 0x02, b"\x01"),
        ("read", 0x09, b"\x01"),
        ("read", 0x03, bytes([0x04, 0x42, 0x00, 0xDA, 0xFD, 0xDF])),  # X 1090, Z 218, Y -545
    ]
    assert sample.counts == (1090, -545, 218)


@pytest.mark.parametrize("gain", [0, 1, 7])
def test_describe_states_how_a_reading_is_made(gain) -> None:
    """One measurement per reading, no pulse from the driver; the stated conversion is the driver's own
    decoding at the gain set."""
    from tests.helpers.conversion import stated_nt

    reading = HMC5883L(FakeSMBus(), gain=gain).describe()["reading"]
    assert reading["mode"] == "single" and reading["raw_unit"] == "nT"
    for code in (-2048, -1, 0, 1000, 2047):
        assert stated_nt(reading["conversion"], code) == pytest.approx(code_to_nt(code, gain), abs=1e-9)
