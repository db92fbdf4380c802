"""MMC5983MA: pure decoding, datasheet transcripts, and the driver against the register-level simulator."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.errors import DeviceNotFound, DeviceTimeout, OptionError, ProtocolError
from drivers.mmc5983ma import MMC5983MA, code_to_nt, decode_field_codes, decode_temp_c, status_timeout_s
from drivers.sim.devices.mmc5983ma import MMC5983MASim
from drivers.sim.transports.i2c_bus import FakeSMBus
from drivers.sim.world import DutTruth, World
from tests.helpers.smbus_doubles import RecordingSMBus, ScriptedSMBus

NT_PER_COUNT = 100_000 / 16384  # 18-bit mode: 16384 counts per gauss

# --- literal bytes from the datasheet ---------------------------------------------------------------
CONNECT = [
    ("read", 0x2F, b"\x30"),  # Product ID1 reads 0x30
    ("write", 0x0A, b"\x80"),  # Internal Control 1: SW_RST
    ("write", 0x0A, b"\x00"),  # BW = 00 (100 Hz, 8 ms)
    ("write", 0x0B, b"\x00"),  # Internal Control 2: continuous mode off
]
# X = 147457 (+1 G + 1 LSB), Y = 122880 (-0.5 G), Z = 131075 (+3 LSB): low bits in byte 6 (01, 00, 11)
BURST = bytes([0x90, 0x00, 0x78, 0x00, 0x80, 0x00, 0x4C])
SINGLE = [
    ("write", 0x09, b"\x01"),  # TM_M
    ("read", 0x08, b"\x00"),  # Meas_M_Done not yet
    ("read", 0x08, b"\x01"),  # Meas_M_Done
    ("read", 0x00, BURST),
]
SET_RESET = [
    ("write", 0x09, b"\x08"),  # SET
    ("write", 0x09, b"\x01"),
    ("read", 0x08, b"\x01"),
    ("read", 0x00, bytes([0x80, 0xFA, 0x80, 0x00, 0x80, 0x00, 0x00])),  # X = 131072 + 1000
    ("write", 0x09, b"\x10"),  # RESET
    ("write", 0x09, b"\x01"),
    ("read", 0x08, b"\x01"),
    ("read", 0x00, bytes([0x7F, 0x6A, 0x80, 0x00, 0x80, 0x00, 0x00])),  # X = 131072 - 600
]
TEMPERATURE = [
    ("write", 0x09, b"\x02"),  # TM_T
    ("read", 0x08, b"\x02"),  # Meas_T_Done
    ("read", 0x07, b"\x80"),  # Tout = 128
]
SAFE = [("write", 0x0B, b"\x00"), ("write", 0x09, b"\x00")]


def scripted(script, **kw) -> tuple[MMC5983MA, ScriptedSMBus, SimClock]:
    bus = ScriptedSMBus(0x30, script)
    clock = SimClock()
    kw.setdefault("set_reset", False)
    kw.setdefault("read_temperature", False)
    return MMC5983MA(bus, name="dut1", clock=clock, **kw), bus, clock

IDEAL = DutTruth(S=np.eye(3), K=np.zeros((3, 3)), b_nt=np.zeros(3), kb_nt_per_c=np.zeros(3))  # no noise


# --- pure functions ---------------------------------------------------------------------------------
def test_decode_burst_to_codes_and_field() -> None:
    assert decode_field_codes(BURST) == (147457, 122880, 131075)
    assert code_to_nt(131072) == 0.0
    assert code_to_nt(131072 + 16384) == 100_000.0  # 1 G
    assert code_to_nt(0) == -800_000.0  # -8 G rail
    with pytest.raises(ValueError, match="7 bytes"):
        decode_field_codes(BURST[:6])


def test_decode_temperature() -> None:
    assert decode_temp_c(0) == -75.0
    assert decode_temp_c(255) == pytest.approx(125.0)
    assert decode_temp_c(128) == pytest.approx(25.392, abs=1e-3)


def test_status_timeout_is_four_measurement_times_plus_1ms() -> None:
    assert [status_timeout_s(bw) for bw in range(4)] == pytest.approx([0.033, 0.017, 0.009, 0.003])


# --- transcripts ------------------------------------------------------------------------------------
def test_connect_transcript() -> None:
    dev, bus, _ = scripted(CONNECT)
    dev.connect()
    bus.assert_done()
    assert dev.describe()["product_id"] == "0x30"


def test_wrong_product_id_is_a_clear_protocol_error() -> None:
    dev, _, _ = scripted([("read", 0x2F, b"\x31")])
    expected = r"dut1: check product id \(register 0x2F\): read 0x31, expected 0x30"
    with pytest.raises(ProtocolError, match=expected):
        dev.connect()


def test_single_measurement_transcript_and_timing() -> None:
    dev, bus, clock = scripted(SINGLE)
    start = clock.now()
    sample = dev.read()
    bus.assert_done()
    assert sample.counts == (147457, 122880, 131075)
    assert sample.field_nt == pytest.approx((100_000 + NT_PER_COUNT, -50_000.0, 3 * NT_PER_COUNT))
    assert sample.offset_nt is None and sample.temp_c is None and not sample.flags
    assert clock.now() - start == pytest.approx(0.009, abs=1e-6)  # 8 ms measurement, one 1 ms re-poll


def test_set_reset_transcript_gives_h_and_offset() -> None:
    dev, bus, _ = scripted(SET_RESET, set_reset=True)
    sample = dev.read()
    bus.assert_done()
    assert sample.field_nt == pytest.approx((800 * NT_PER_COUNT, 0.0, 0.0))  # (1000 - -600) / 2
    assert sample.offset_nt == pytest.approx((200 * NT_PER_COUNT, 0.0, 0.0))  # (1000 + -600) / 2
    assert sample.counts == (132072, 131072, 131072)


def test_temperature_transcript() -> None:
    dev, bus, _ = scripted(SINGLE + TEMPERATURE, read_temperature=True)
    assert dev.read().temp_c == pytest.approx(-75 + 128 * 200 / 255)
    bus.assert_done()


def test_set_reset_with_temperature_measures_it_between_the_halves_while_the_reset_settles() -> None:
    script = SET_RESET[:5] + TEMPERATURE + SET_RESET[5:]  # SET, TM_M, ..., RESET, TM_T, ..., TM_M, ...
    dev, bus, clock = scripted(script, set_reset=True, read_temperature=True)
    start = clock.now()
    sample = dev.read()
    bus.assert_done()
    assert sample.temp_c == pytest.approx(-75 + 128 * 200 / 255)
    assert sample.field_nt[0] == pytest.approx(code_to_nt(131072 + 800))
    # SET 1 ms, field 8 ms, then the temperature's 8 ms cover the RESET's 1 ms, field 8 ms: 25 ms, not 26
    assert clock.now() - start == pytest.approx(0.025, abs=1e-6)


def test_at_the_fastest_bandwidth_the_reset_still_settles_its_millisecond() -> None:
    fast = [("write", 0x0A, b"\x03")] + SET_RESET[:5] + TEMPERATURE + SET_RESET[5:]
    dev, bus, clock = scripted(fast, set_reset=True, read_temperature=True)
    dev.set_bandwidth(3)  # 0.5 ms conversions
    start = clock.now()
    dev.read()
    bus.assert_done()
    assert clock.now() - start == pytest.approx(0.001 + 0.0005 + 0.001 + 0.0005, abs=1e-6)


def test_bandwidth_transcript_and_shorter_wait() -> None:
    dev, bus, clock = scripted([("write", 0x0A, b"\x03"), ("write", 0x09, b"\x01"), ("read", 0x08, b"\x01"),
                                ("read", 0x00, BURST)])
    dev.set_bandwidth(3)
    start = clock.now()
    dev.read()
    bus.assert_done()
    assert clock.now() - start == pytest.approx(0.0005, abs=1e-6)
    with pytest.raises(OptionError, match="bandwidth code 4"):
        dev.set_bandwidth(4)


def test_continuous_mode_transcript() -> None:
    dev, bus, _ = scripted([
        ("write", 0x09, b"\x08"),  # one SET so the bridge sign is +H
        ("write", 0x0B, b"\x0D"),  # Cmm_en | CM_Freq 101 (100 Hz)
        ("read", 0x08, b"\x01"),
        ("read", 0x00, BURST),
        ("write", 0x08, b"\x01"),  # clear Meas_M_Done
        ("write", 0x0B, b"\x00"),
    ])
    dev.start_continuous(100)
    assert dev.read().counts == (147457, 122880, 131075)
    dev.stop_continuous()
    bus.assert_done()


def test_continuous_rate_checks() -> None:
    dev, _, _ = scripted([])
    with pytest.raises(OptionError, match="continuous rate 30 Hz"):
        dev.start_continuous(30)
    with pytest.raises(OptionError, match="1000 Hz needs bandwidth code >= 3"):
        dev.start_continuous(1000)


def test_safe_state_transcript() -> None:
    dev, bus, _ = scripted(SAFE)
    dev.safe_state()
    bus.assert_done()


# --- against the simulator --------------------------------------------------------------------------
@pytest.fixture
def world() -> World:
    world = World(SimClock(), ambient_nt=(21_000.0, -4_000.0, 43_000.0), air_c=30.0, seed=3)
    world.add_dut("dut1", DutTruth.random(np.random.default_rng(7), noise_nt=20.0))
    return world


@pytest.fixture
def rig(world: World) -> tuple[MMC5983MA, FakeSMBus, MMC5983MASim]:
    bus = FakeSMBus()
    sim = MMC5983MASim(world, "dut1")
    bus.attach(0x30, sim)
    dev = MMC5983MA(bus, name="dut1", clock=world.clock)
    dev.connect()
    return dev, bus, sim


def truth(world: World) -> tuple[np.ndarray, np.ndarray]:
    plus = world.dut_raw_nt("dut1", 1, noisy=False)
    minus = world.dut_raw_nt("dut1", -1, noisy=False)
    return (plus - minus) / 2, (plus + minus) / 2


def test_set_reset_returns_world_h_and_offset_within_noise(world: World, rig) -> None:
    dev, _, _ = rig
    h_nt, offset_nt = truth(world)
    assert np.max(np.abs(offset_nt)) > 500  # the offset is big enough that a missed sign flip would show
    samples = [dev.read() for _ in range(5)]
    tol_nt = 5 * 20.0 / np.sqrt(2) + NT_PER_COUNT
    for s in samples:
        assert np.asarray(s.field_nt) == pytest.approx(h_nt, abs=tol_nt)
        assert np.asarray(s.offset_nt) == pytest.approx(offset_nt, abs=tol_nt)
    assert len({s.field_nt for s in samples}) == 5  # noise reaches the reading


def test_without_set_reset_the_offset_stays_in(world: World, rig) -> None:
    dev, _, _ = rig
    dev.set_reset = False
    h_nt, offset_nt = truth(world)
    assert np.asarray(dev.read().field_nt) == pytest.approx(h_nt + offset_nt, abs=100 + NT_PER_COUNT)


def test_temperature_from_the_world(world: World, rig) -> None:
    dev, _, _ = rig
    assert dev.read().temp_c == pytest.approx(world.dut_temp_c("dut1"), abs=0.4)


def test_write_only_registers_read_back_zero_and_done_bit_follows_the_clock(world: World, rig) -> None:
    _, bus, _ = rig
    bus.write_byte_data(0x30, 0x0A, 0x01)  # BW 01: 4 ms
    bus.write_byte_data(0x30, 0x0B, 0x00)
    assert bus.read_i2c_block_data(0x30, 0x09, 4) == [0, 0, 0, 0]
    bus.write_byte_data(0x30, 0x09, 0x01)
    assert bus.read_byte_data(0x30, 0x08) & 0x01 == 0
    world.clock.sleep(0.0039)
    assert bus.read_byte_data(0x30, 0x08) & 0x01 == 0
    world.clock.sleep(0.0002)
    assert bus.read_byte_data(0x30, 0x08) & 0x01 == 1
    assert bus.read_byte_data(0x30, 0x08) & 0x01 == 1  # stays set until the next command
    bus.write_byte_data(0x30, 0x09, 0x01)
    assert bus.read_byte_data(0x30, 0x08) & 0x01 == 0


def test_beyond_8_gauss_is_flagged_saturated(world: World, rig) -> None:
    dev, _, _ = rig
    world.ambient_nt = np.array([1_500_000.0, 0.0, 0.0])  # 15 G
    sample = dev.read()
    assert "saturated" in sample.flags


def test_continuous_mode_delivers_new_samples_at_the_rate(world: World, rig) -> None:
    dev, _, _ = rig
    h_nt, offset_nt = truth(world)
    dev.start_continuous(50)
    first, second = dev.read(), dev.read()
    assert second.t - first.t == pytest.approx(0.02, abs=0.002)
    assert np.asarray(second.field_nt) == pytest.approx(h_nt + offset_nt, abs=100 + NT_PER_COUNT)
    dev.safe_state()
    assert dev.continuous_hz is None


def test_nack_retries_then_device_not_found(rig, caplog) -> None:
    dev, bus, _ = rig
    bus.nack(0x30)
    with caplog.at_level(logging.WARNING), pytest.raises(DeviceNotFound) as err:
        dev.read()
    assert str(err.value) == "dut1: write control 0 (SET/RESET) register 0x09: no ACK at 0x30 (after 3 tries)"
    assert sum(r.levelno == logging.WARNING for r in caplog.records) == 2


def test_replug_recovers(world: World, rig) -> None:
    dev, bus, sim = rig
    bus.detach(0x30)
    with pytest.raises(DeviceNotFound):
        dev.read()
    dev.safe_state()  # on a dead bus: logs, never raises
    bus.attach(0x30, sim)
    h_nt, _ = truth(world)
    assert np.asarray(dev.read().field_nt) == pytest.approx(h_nt, abs=100)


def test_safe_state_on_a_failed_bus_logs_instead_of_raising(rig, caplog) -> None:
    dev, bus, _ = rig
    bus.nack(0x30)
    with caplog.at_level(logging.WARNING, logger="magrig.drivers.mmc5983ma"):
        dev.safe_state()
    assert "dut1: safe state not confirmed" in caplog.text


def test_measurement_that_never_completes_times_out(rig) -> None:
    dev, _, sim = rig
    sim.never_done = True
    expected = r"dut1: wait for Meas_M_Done \(status 0x08\): not ready after 33\.0 ms"
    with pytest.raises(DeviceTimeout, match=expected):
        dev.read()


def test_describe(rig) -> None:
    info = rig[0].describe()
    assert info["model"] == "MMC5983MA" and info["address"] == "0x30" and info["product_id"] == "0x30"
    assert info["range_nt"] == 800_000.0
    assert info["noise_rms_nt"] == pytest.approx(40.0)
    assert info["resolution_nt"] == pytest.approx(6.1035, abs=1e-4)


def test_simulator_speaks_the_datasheet_bytes() -> None:
    """Ideal DUT in +1 G, -0.5 G, 0 at 22 degC: the simulator's own bytes, checked literally."""
    world = World(SimClock(), ambient_nt=(100_000.0, -50_000.0, 0.0), air_c=22.0)
    world.add_dut("dut1", IDEAL)
    recorder = RecordingSMBus.with_chip(0x30, MMC5983MASim(world, "dut1"))
    dev = MMC5983MA(recorder, name="dut1", clock=world.clock)
    dev.connect()
    recorder.calls.clear()
    sample = dev.read()
    assert recorder.transcript() == [
        ("write", 0x09, b"\x08"),
        ("write", 0x09, b"\x01"),
        ("read", 0x08, b"\x11"),  # OTP_Read_Done (since power-on) | Meas_M_Done
        ("read", 0x00, bytes([0x90, 0x00, 0x78, 0x00, 0x80, 0x00, 0x00])),  # +H after SET
        ("write", 0x09, b"\x10"),  # RESET, and the die temperature measured while it settles
        ("write", 0x09, b"\x02"),
        ("read", 0x08, b"\x13"),  # Meas_T_Done too
        ("read", 0x07, b"\x7c"),  # 124: (22 + 75) * 255 / 200 rounded
        ("write", 0x09, b"\x01"),
        ("read", 0x08, b"\x13"),
        ("read", 0x00, bytes([0x70, 0x00, 0x88, 0x00, 0x80, 0x00, 0x00])),  # -H after RESET
    ]
    assert sample.field_nt == (100_000.0, -50_000.0, 0.0)
    assert sample.offset_nt == (0.0, 0.0, 0.0)


def test_connect_on_an_empty_bus_names_the_operation() -> None:
    with pytest.raises(DeviceNotFound) as err:
        MMC5983MA(FakeSMBus(), name="dut1", clock=SimClock()).connect()
    assert str(err.value) == "dut1: read product id register 0x2F: no ACK at 0x30 (after 3 tries)"


@pytest.mark.parametrize("set_reset, mode", [(True, "set_reset_pair"), (False, "single")])
def test_describe_states_how_a_reading_is_made(set_reset, mode) -> None:
    """The reading's mode follows the SET/RESET setting, and the stated conversion is the driver's own
    decoding at the null, at +-1 G and at both rails."""
    from tests.helpers.conversion import stated_nt

    reading = MMC5983MA(FakeSMBus(), name="dut1", set_reset=set_reset).describe()["reading"]
    assert reading["mode"] == mode and reading["raw_unit"] == "nT"
    assert ("H_SET - H_RESET" in reading["mode_text"]) == set_reset
    for code in (0, 131072 - 16384, 131072, 131072 + 16384, 262143):
        assert stated_nt(reading["conversion"], code) == pytest.approx(code_to_nt(code), abs=1e-9)
