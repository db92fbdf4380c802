"""The MCP2221A transport against its HID-level simulator: every command it sends, byte for byte as
hardware-notes 8.1 lays them out, the simulator's decoding of them, and each fault as its one-line error."""

from __future__ import annotations

import errno

import pytest

from drivers import busscan
from drivers.errors import DeviceError, DeviceNotFound, DeviceTimeout
from drivers.mmc5983ma import MMC5983MA
from drivers.sim.transports.hidbus import FakeHid
from drivers.sim.transports.mcp2221 import MCP2221ASim
from drivers.tca9548a import MuxedBus
from drivers.transports.mcp2221 import MCP2221Bus, divider_for
from tests.unit.drivers.bridge_bench import bench, trimmed

SERIAL = "0001234567"


@pytest.fixture
def rig():
    b = bench()
    usb = FakeHid(b.clock)
    chip = MCP2221ASim(b.wire, b.clock, serial=SERIAL)
    usb.plug(chip)
    return b, usb, chip


def command(chip, report: bytes) -> bytes:
    """One 64-byte report straight into the simulator, its one reply back."""
    (reply,) = chip.on_report(report.ljust(64, b"\x00"))
    return reply


def test_speed_divider_is_the_datasheets_12_mhz_over_f_minus_2():
    assert divider_for(100_000) == 118  # notes 8.1: 100 kHz -> 118, 400 kHz -> 28
    assert divider_for(400_000) == 28


def test_open_and_a_register_read_send_the_notes_commands(rig):
    b, usb, chip = rig
    bus = MCP2221Bus(SERIAL, speed_hz=100_000, clock=b.clock, hid_module=usb)
    assert bus.read_byte_data(0x30, 0x2F) == 0x30  # the MMC5983MA's product id
    assert [trimmed(c) for c in chip.commands] == [
        bytes.fromhex("1000"),            # status
        bytes.fromhex("10000020 76"),     # set speed: [3]=0x20, [4]=divider 118
        bytes.fromhex("94010060 2f"),     # write no STOP: length 1 LE, address 0x30<<1, register 0x2F
        bytes.fromhex("1000"),            # status: the engine shows 0x45
        bytes.fromhex("93010061"),        # read with repeated START: length 1, address (0x30<<1)|1
        bytes.fromhex("4000"),            # get the data
    ]
    assert 0x10 not in [c[2] for c in chip.commands if c[0] == 0x10]  # no cancel of an idle engine


def test_the_simulator_decodes_the_commands_as_the_datasheet_lays_them_out(rig):
    b, _, chip = rig
    assert command(chip, bytes.fromhex("94010060 2f"))[:3] == bytes([0x94, 0x00, 0x00])  # accepted, was idle
    b.clock.sleep(0.001)
    status = command(chip, bytes([0x10]))
    assert status[8] == 0x45 and status[20] & 0x40 == 0  # no-STOP write finished, address ACKed
    assert command(chip, bytes.fromhex("93010061"))[1] == 0x00
    b.clock.sleep(0.001)
    data = command(chip, bytes([0x40]))
    assert (data[1], data[2], data[3], data[4]) == (0x00, 0x55, 1, 0x30)  # last chunk, 1 byte: 0x30
    assert command(chip, bytes([0x40]))[2:4] == bytes([0x00, 0x00])  # idle, nothing more


def test_a_command_while_the_engine_is_busy_is_answered_busy(rig):
    b, _, chip = rig
    command(chip, bytes([0x10, 0, 0, 0x20, 255]))  # the slowest clock: 12 MHz / 257
    assert command(chip, bytes.fromhex("91200061"))[1] == 0x00  # a 32-byte read takes about 6 ms
    reply = command(chip, bytes.fromhex("90010060 00"))
    assert reply[1] == 0x01 and reply[2] == 0x50  # busy: reading


def test_after_a_no_stop_write_only_a_repeated_start_command_is_taken(rig):
    b, _, chip = rig
    command(chip, bytes.fromhex("94010060 2f"))
    b.clock.sleep(0.001)
    reply = command(chip, bytes.fromhex("91010061"))  # a plain read instead of 0x93
    assert reply[1] == 0x01 and reply[2] == 0x45


def test_cancelling_an_idle_engine_wedges_it_as_the_notes_warn(rig):
    _, _, chip = rig
    assert command(chip, bytes([0x10, 0, 0x10]))[2] == 0x11  # already idle...
    assert command(chip, bytes([0x10]))[8] == 0x62  # ...and now stuck in STOP timeout


def test_a_long_write_goes_in_60_byte_reports_repeating_the_header(rig):
    b, _, chip = rig
    payload = bytes(range(1, 66))  # register 1, then 64 bytes: 65 in all
    first = bytes([0x90]) + (65).to_bytes(2, "little") + bytes([0x60]) + bytes([0x00]) + payload[:59]
    assert command(chip, first)[1] == 0x00
    second = bytes([0x90]) + (65).to_bytes(2, "little") + bytes([0x60]) + payload[59:]
    assert command(chip, second)[1] == 0x00
    b.clock.sleep(0.01)
    assert command(chip, bytes([0x10]))[11:13] == (65).to_bytes(2, "little")  # all transferred


def test_a_nack_is_oserror_121_and_the_engine_is_cancelled(rig):
    b, usb, chip = rig
    bus = MCP2221Bus(SERIAL, clock=b.clock, hid_module=usb)
    with pytest.raises(OSError) as caught:
        bus.read_byte_data(0x31, 0x00)
    assert caught.value.errno == errno.EREMOTEIO
    assert trimmed(chip.commands[-1]) == bytes.fromhex("1000")  # status after the cancel
    assert trimmed(chip.commands[-2]) == bytes.fromhex("100010")  # cancel: the engine was in 0x25
    assert bus.read_byte_data(0x30, 0x2F) == 0x30  # and the bus goes on


def test_a_stuck_bus_is_named_by_the_status_pins(rig):
    b, usb, _ = rig
    bus = MCP2221Bus(SERIAL, clock=b.clock, hid_module=usb)
    b.wire.sda_stuck_low = True
    with pytest.raises(DeviceTimeout) as caught:
        bus.read_byte_data(0x30, 0x2F)
    assert str(caught.value) == (f"mcp2221 {SERIAL}: read register at 0x30: bus stuck: SDA held low "
                                 "(state 0x12) (after 3 tries)")
    b.wire.sda_stuck_low = False
    assert bus.read_byte_data(0x30, 0x2F) == 0x30


def test_a_short_read_is_an_error_then_retried(rig):
    b, usb, _ = rig
    bus = MCP2221Bus(SERIAL, clock=b.clock, hid_module=usb, tries=1)
    b.wire.short_read = 3
    with pytest.raises(DeviceError, match="short read: 3 of 7 bytes"):
        bus.read_i2c_block_data(0x30, 0x00, 7)
    bus.tries = 3
    b.wire.short_read = 3
    assert len(bus.read_i2c_block_data(0x30, 0x00, 7)) == 7  # the second try gets them all


def test_a_missing_bridge_names_kind_and_serial(rig):
    b, usb, _ = rig
    with pytest.raises(DeviceNotFound) as caught:
        MCP2221Bus("9999", clock=b.clock, hid_module=usb)
    assert str(caught.value) == ("mcp2221 9999: open: no MCP2221A (USB 04d8:00dd) with serial number 9999 "
                                 f"is plugged in (plugged in: serial numbers {SERIAL})")


def test_unplugged_then_plugged_back(rig):
    b, usb, chip = rig
    bus = MCP2221Bus(SERIAL, clock=b.clock, hid_module=usb)
    usb.unplug(chip)
    with pytest.raises(DeviceNotFound, match=f"mcp2221 {SERIAL}: read register at 0x30: no MCP2221A"):
        bus.read_byte_data(0x30, 0x2F)
    usb.replug(chip)
    assert bus.read_byte_data(0x30, 0x2F) == 0x30  # reopened on the way


def test_time_is_usb_frames_and_bus_time(rig):
    b, usb, _ = rig
    bus = MCP2221Bus(SERIAL, clock=b.clock, hid_module=usb)
    start = b.clock.now()
    bus.read_byte_data(0x30, 0x2F)
    assert b.clock.now() - start == pytest.approx(0.008, abs=1e-5)  # 4 commands, each an OUT and an IN frame
    start = b.clock.now()
    bus.read_i2c_block_data(0x30, 0x00, 32)  # 32 bytes at 100 kHz: ~3 ms on the bus, so 0x40 waits
    assert b.clock.now() - start > 0.008


def test_the_drivers_and_the_switch_work_unchanged_and_the_scan_finds_everything(rig):
    b, usb, _ = rig
    bus = MCP2221Bus(SERIAL, clock=b.clock, hid_module=usb)
    dut = MMC5983MA(bus, 0x30, name="dut", clock=b.clock)
    dut.connect()
    assert dut.read().field_nt is not None
    tmp_bus = MuxedBus(bus, 0x70, 3, name="switch")
    assert tmp_bus.read_i2c_block_data(0x48, 0x0F, 2) == [0x01, 0x17]  # TMP117 device id
    assert b.switch.control == 1 << 3
    scan = busscan.scan_i2c(bus)
    assert {(f.address, f.switch, f.channel) for f in scan.found} == {(0x70, None, None), (0x30, None, None),
                                                                        (0x48, 0x70, 3)}
    assert b.switch.control == 0


def test_bridges_present_lists_every_kind_by_usb_id_and_serial(rig):
    from drivers.sim.transports.cp2112 import CP2112Sim
    from drivers.sim.transports.ft232h import FT232HSim
    from drivers.sim.transports.usbfake import FakeUsbBackend
    from drivers.transports.usb_bridges import bridges_present

    b, usb, _ = rig
    usb.plug(CP2112Sim(b.wire, b.clock, serial="0042"))
    backend = FakeUsbBackend()
    backend.plug(FT232HSim(b.wire, b.clock, serial="FT0FMF6V"))
    found, notes = bridges_present(hid_module=usb, usb_backend=backend)
    assert [(f["kind"], f["usb_id"], f["serial_number"]) for f in found] == [
        ("mcp2221", "04d8:00dd", SERIAL), ("cp2112", "10c4:ea90", "0042"),
        ("ft232h", "0403:6014", "FT0FMF6V")]
    assert notes == []
