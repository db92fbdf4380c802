"""TCA9548A I2C switch: datasheet transcripts, the fake's switch model, and MuxedBus with real drivers."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.errors import DeviceNotFound, OptionError, ProtocolError
from drivers.mmc5983ma import MMC5983MA
from drivers.sim.devices.mmc5983ma import MMC5983MASim
from drivers.sim.transports.i2c_bus import FakeSMBus, I2CSwitchSim, RegisterChip
from drivers.sim.world import DutTruth, World
from drivers.tca9548a import TCA9548A, MuxedBus, disable_all, switch_on
from tests.helpers.smbus_doubles import RecordingSMBus, ScriptedSMBus

# --- literal bytes from hardware-notes 1.5: one control byte, bit n enables channel n, 0x00 at power-up
SELECT_3 = [("write", None, b"\x08"), ("read", None, b"\x08")]  # write the byte, read it back
SELECT_0 = [("write", None, b"\x01"), ("read", None, b"\x01")]
SELECT_7 = [("write", None, b"\x80"), ("read", None, b"\x80")]
ALL_OFF = [("write", None, b"\x00"), ("read", None, b"\x00")]


def test_select_writes_one_byte_and_reads_it_back_once():
    bus = ScriptedSMBus(0x70, SELECT_3 + SELECT_0 + SELECT_7 + ALL_OFF)
    switch = TCA9548A(bus, 0x70, name="mux0")
    switch.select(3)
    switch.select(3)  # already selected: nothing on the wire
    switch.select(0)
    switch.select(7)
    switch.disable()
    switch.disable()
    bus.assert_done()


def test_wrong_read_back_names_the_switch_and_forgets_the_state():
    bus = ScriptedSMBus(0x70, [("write", None, b"\x08"), ("read", None, b"\x00")] + SELECT_3)
    switch = TCA9548A(bus, 0x70, name="mux0")
    with pytest.raises(ProtocolError) as err:
        switch.select(3)
    assert err.value.device == "mux0"
    assert "read back 0x00" in str(err.value) and "not of the device behind it" in str(err.value)
    switch.select(3)  # state unknown after the fault: written and verified again
    bus.assert_done()


def test_options_are_checked():
    with pytest.raises(OptionError, match="0x70..0x77"):
        TCA9548A(FakeSMBus(), 0x6F)
    with pytest.raises(OptionError, match="channel 8"):
        MuxedBus(FakeSMBus(), 0x70, 8)


# --- the fake's switch model ----------------------------------------------------------------------------
def chip_with(register: int, value: int) -> RegisterChip:
    chip = RegisterChip()
    chip.registers[register] = value
    return chip


def test_fake_switch_powers_up_off_and_shows_only_enabled_channels():
    bus = FakeSMBus()
    mux = bus.add_switch(0x70)
    mux.attach(3, 0x30, chip_with(0x2F, 0x30))
    assert bus.read_byte(0x70) == 0x00
    with pytest.raises(OSError) as err:
        bus.read_byte_data(0x30, 0x2F)
    assert err.value.errno == 121
    bus.write_byte(0x70, 0x08)
    assert bus.read_byte(0x70) == 0x08
    assert bus.read_byte_data(0x30, 0x2F) == 0x30
    mux.reset()  # RESET pin
    with pytest.raises(OSError):
        bus.read_byte_data(0x30, 0x2F)


def test_fake_collision_reads_the_wired_and_and_writes_reach_both():
    bus = FakeSMBus()
    mux = bus.add_switch(0x70)
    a, b = chip_with(0x10, 0xF0), chip_with(0x10, 0x3C)
    mux.attach(1, 0x30, a)
    mux.attach(2, 0x30, b)
    bus.write_byte(0x70, 0x06)  # channels 1 and 2 together
    assert bus.read_byte_data(0x30, 0x10) == 0x30  # 0xF0 & 0x3C: garbled, and no NACK
    bus.write_byte_data(0x30, 0x11, 0x5A)
    assert a.registers[0x11] == b.registers[0x11] == 0x5A


def test_fake_switch_unplugged_with_a_channel_on_hides_it_and_shows_it_again_when_plugged_back():
    bus = FakeSMBus()
    mux = bus.add_switch(0x70)
    other = bus.add_switch(0x71)
    mux.attach(3, 0x30, chip_with(0x2F, 0x30))
    other.attach(0, 0x30, chip_with(0x2F, 0x0F))
    bus.write_byte(0x70, 0x08)
    assert bus.read_byte_data(0x30, 0x2F) == 0x30
    unplugged = bus.detach(0x70)
    with pytest.raises(OSError):
        bus.read_byte_data(0x30, 0x2F)
    unplugged.control = 0x00  # what it holds meanwhile is its own
    unplugged.control = 0x08
    bus.write_byte(0x71, 0x01)
    assert bus.read_byte_data(0x30, 0x2F) == 0x0F  # the other switch's chip alone
    bus.attach(0x70, unplugged)  # plugged back with channel 3 still on: both answer
    assert bus.read_byte_data(0x30, 0x2F) == 0x30 & 0x0F
    bus.write_byte(0x71, 0x00)
    assert bus.read_byte_data(0x30, 0x2F) == 0x30


def test_fake_switch_faults():
    bus = FakeSMBus()
    mux = bus.add_switch(0x70)
    mux.readback = 0xFF
    bus.write_byte(0x70, 0x01)
    assert bus.read_byte(0x70) == 0xFF
    bus.nack(0x70)
    with pytest.raises(OSError):
        bus.write_byte(0x70, 0x01)
    with pytest.raises(ValueError, match="not described"):
        I2CSwitchSim().on_read(0, 1)  # the notes give no register-style access


# --- MuxedBus with real drivers --------------------------------------------------------------------------
def two_duts(channels=((0x70, 0), (0x70, 5))):
    clock = SimClock()
    world = World(clock, ambient_nt=(20_000.0, -3_000.0, 42_000.0))
    fake = FakeSMBus()
    switches: dict[int, I2CSwitchSim] = {}
    duts = []
    for i, (address, channel) in enumerate(channels):
        name = f"dut{i + 1}"
        truth = DutTruth.random(np.random.default_rng(i), noise_nt=0.0)
        world.add_dut(name, truth)
        if address not in switches:
            switches[address] = fake.add_switch(address)
        switches[address].attach(channel, 0x30, MMC5983MASim(world, name))
        duts.append((name, address, channel))
    rec = RecordingSMBus(fake)
    drivers = [
        MMC5983MA(MuxedBus(rec, address, channel, name=f"mux 0x{address:02X}"), name=name, clock=clock,
                  read_temperature=False)
        for name, address, channel in duts
    ]
    return world, fake, switches, rec, drivers


def calls(rec: RecordingSMBus) -> list[tuple[str, int, int | None, bytes]]:
    return [(c.op, c.address, c.register, c.data) for c in rec.calls]


def test_two_mmc5983ma_at_0x30_interleave_on_their_own_channels():
    world, _, switches, rec, (d1, d2) = two_duts()
    d1.connect()
    assert calls(rec)[:3] == [
        ("write", 0x70, None, b"\x01"),  # channel 0
        ("read", 0x70, None, b"\x01"),
        ("read", 0x30, 0x2F, b"\x30"),  # product id of the DUT behind it
    ]
    switch_writes = sum(1 for op, addr, _, _ in calls(rec) if addr == 0x70 and op == "write")
    assert switch_writes == 1  # the rest of connect() needs no new selection
    d2.connect()
    for _ in range(3):
        for dut in (d1, d2):
            rec.calls.clear()
            sample = dut.read()
            truth = world.duts[dut.name].truth
            expected = truth.raw_from_field(truth.mount @ world.lab_field_nt(), world.dut_temp_c(dut.name))
            np.testing.assert_allclose(sample.field_nt, expected, atol=7.0)  # one 18-bit LSB is 6.25 nT
            mask = b"\x01" if dut is d1 else b"\x20"
            assert calls(rec)[:2] == [("write", 0x70, None, mask), ("read", 0x70, None, mask)]
            assert all(addr == 0x30 for _, addr, _, _ in calls(rec)[2:])  # selected once per read()
    assert switches[0x70].control == 0x20


def test_two_switches_never_enable_two_channels_at_once():
    _, _, switches, rec, (d1, d2) = two_duts(((0x70, 2), (0x71, 2)))
    d1.connect()
    assert calls(rec)[:5] == [
        ("write", 0x71, None, b"\x00"),  # the other switch's state is unknown: off first
        ("read", 0x71, None, b"\x00"),
        ("write", 0x70, None, b"\x04"),
        ("read", 0x70, None, b"\x04"),
        ("read", 0x30, 0x2F, b"\x30"),
    ]
    rec.calls.clear()
    d2.connect()
    assert calls(rec)[:5] == [
        ("write", 0x70, None, b"\x00"),
        ("read", 0x70, None, b"\x00"),
        ("write", 0x71, None, b"\x04"),
        ("read", 0x71, None, b"\x04"),
        ("read", 0x30, 0x2F, b"\x30"),
    ]
    disable_all(rec)
    assert switches[0x70].control == switches[0x71].control == 0


def test_a_selection_is_trusted_only_until_some_control_byte_changes():
    """Transfers on the channel already selected write nothing; once any switch's byte is written (all
    off at a safe state) or lost (a failed transfer), the next transfer selects again, every other
    switch off first."""
    _, fake, switches, rec, (d1, d2) = two_duts(((0x70, 2), (0x71, 2)))
    d1.connect()
    rec.calls.clear()
    d1.measure_codes()
    assert {c[1] for c in calls(rec)} == {0x30}  # the channel stays: nothing to the switches
    disable_all(rec)
    rec.calls.clear()
    d1.measure_codes()
    assert calls(rec)[:2] == [("write", 0x70, None, b"\x04"), ("read", 0x70, None, b"\x04")]
    d2.connect()
    fake.nack(0x71, count=1)
    with pytest.raises(DeviceNotFound):
        switch_on(rec, 0x71).read_control()  # a lost transfer: 0x71's byte unknown
    rec.calls.clear()
    d2.measure_codes()
    assert calls(rec)[:2] == [("write", 0x71, None, b"\x04"), ("read", 0x71, None, b"\x04")]


class OneChannelProbe(RegisterChip):
    """Holds its id at register 0x10 and checks, at every transfer, that exactly one channel is on."""

    def __init__(self, ident: int, switches: list[I2CSwitchSim]):
        super().__init__()
        self.registers[0x10] = ident
        self.switches = switches

    def update(self) -> None:
        enabled = sum(bin(s.control).count("1") for s in self.switches)
        assert enabled == 1, f"{enabled} channels enabled during a transfer"


def sixteen_on_two_switches() -> tuple[FakeSMBus, list[MuxedBus], list[I2CSwitchSim]]:
    fake = FakeSMBus()
    switches = [fake.add_switch(0x70), fake.add_switch(0x71)]
    buses = []
    for ident in range(16):
        switch, channel = divmod(ident, 8)
        switches[switch].attach(channel, 0x30, OneChannelProbe(ident, switches))
        buses.append(MuxedBus(fake, 0x70 + switch, channel))
    return fake, buses, switches


def test_sixteen_duts_behind_two_switches_each_answer_alone():
    _, buses, switches = sixteen_on_two_switches()
    for _ in range(2):
        assert [bus.read_byte_data(0x30, 0x10) for bus in buses] == list(range(16))
    # 16 selections per round, plus one "off" each time the other switch takes over (twice a round;
    # the very first is the never-written 0x71)
    assert switches[0].writes + switches[1].writes == 2 * 16 + 2 * 2


def test_threads_sharing_the_bus_interleave_without_collisions():
    _, buses, _ = sixteen_on_two_switches()
    wrong: list[tuple[int, int]] = []

    def reader(ident: int) -> None:
        for _ in range(200):
            got = buses[ident].read_byte_data(0x30, 0x10)
            if got != ident:
                wrong.append((ident, got))

    threads = [threading.Thread(target=reader, args=(i,)) for i in (0, 5, 9, 15)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert wrong == []


def test_absent_switch_is_reported_as_the_switch_not_the_dut():
    _, fake, _, _, (d1, _) = two_duts()
    fake.nack(0x70)  # the switch never answers
    with pytest.raises(DeviceNotFound) as err:
        d1.link.bus.read_byte_data(0x30, 0x2F)
    assert err.value.device == "mux 0x70"
    with pytest.raises(DeviceNotFound) as err:
        d1.connect()  # through the driver's retries: the DUT's operation, the switch's fault
    assert "switch at 0x70" in str(err.value) and "not of the device behind it" in str(err.value)


def test_wrong_read_back_through_the_driver_names_the_switch():
    _, _, switches, _, (d1, _) = two_duts()
    switches[0x70].readback = 0x00
    with pytest.raises(ProtocolError) as err:
        d1.connect()
    assert "switch at 0x70 read back 0x00" in str(err.value)


def test_one_lost_switch_transfer_is_retried_and_reselected():
    _, fake, switches, rec, (d1, _) = two_duts()
    fake.nack(0x70, count=1)
    d1.connect()
    assert d1.product_id == 0x30
    assert switches[0x70].control == 0x01
    assert calls(rec)[0] == ("nack", 0x70, None, b"")
