"""The CP2112 transport against its HID-level simulator: every report it sends, byte for byte as
hardware-notes 8.2 (AN495) lays them out, the simulator's transfer status, and each fault as its error."""

from __future__ import annotations

import errno

import pytest

from drivers import busscan
from drivers.errors import DeviceError, DeviceNotFound, DeviceTimeout
from drivers.mmc5983ma import MMC5983MA
from drivers.sim.transports.cp2112 import CP2112Sim
from drivers.sim.transports.hidbus import FakeHid
from drivers.transports.cp2112 import CP2112Bus
from tests.unit.drivers.bridge_bench import bench, trimmed

SERIAL = "0001"
CONFIG_100K = bytes.fromhex("06 000186a0 02 00 0019 0019 01 0001")  # 100 kHz, 25 ms timeouts, 1 retry


@pytest.fixture
def rig():
    b = bench()
    usb = FakeHid(b.clock)
    chip = CP2112Sim(b.wire, b.clock, serial=SERIAL)
    usb.plug(chip)
    return b, usb, chip


def test_open_configures_the_chip_and_drains_the_spurious_status(rig):
    b, usb, chip = rig
    CP2112Bus(SERIAL, speed_hz=100_000, clock=b.clock, hid_module=usb)
    assert chip.config == CONFIG_100K  # SCL clock BE32, own address, no auto-send-read, timeouts BE16...
    assert chip.on_open() == []  # the 0x16 queued at attach was read and dropped


def test_a_register_read_is_write_read_status_and_force_read(rig):
    b, usb, chip = rig
    bus = CP2112Bus(SERIAL, clock=b.clock, hid_module=usb)
    chip.reports.clear()
    assert bus.read_byte_data(0x30, 0x2F) == 0x30
    assert [trimmed(r) for r in chip.reports] == [
        bytes.fromhex("11 60 0001 01 2f"),  # write-read: address 0x30<<1, read length 1 BE, 1 byte: 0x2F
        bytes.fromhex("15 01"),             # transfer status request
        bytes.fromhex("12 0001"),           # force read 1 byte
    ]
    bus.write_byte_data(0x30, 0x09, 0x01)
    assert trimmed(chip.reports[3]) == bytes.fromhex("14 60 02 09 01")  # write: address, length 2, data


def test_the_simulator_reports_busy_then_complete_with_the_bytes_read(rig):
    b, usb, chip = rig
    chip.on_report(bytes.fromhex("11 60 0007 01 00").ljust(64, b"\x00"))
    (busy,) = chip.on_report(bytes.fromhex("1501").ljust(64, b"\x00"))
    assert busy[:3] == bytes([0x16, 1, 2])  # busy, reading (7 bytes at 100 kHz take ~0.9 ms)
    b.clock.sleep(0.002)
    (done,) = chip.on_report(bytes.fromhex("1501").ljust(64, b"\x00"))
    assert done[:7] == bytes([0x16, 2, 5, 0, 0, 0, 7])  # complete, succeeded after 0 retries, 7 bytes
    (response,) = chip.on_report(bytes.fromhex("12 0007").ljust(64, b"\x00"))
    assert response[0] == 0x13 and response[2] == 7 and len(response) == 64


def test_a_nack_is_oserror_121(rig):
    b, usb, chip = rig
    bus = CP2112Bus(SERIAL, clock=b.clock, hid_module=usb)
    with pytest.raises(OSError) as caught:
        bus.read_byte_data(0x31, 0x00)
    assert caught.value.errno == errno.EREMOTEIO
    assert chip.status[:2] == (3, 0)  # error: timeout, address NACKed
    assert bus.read_byte_data(0x30, 0x2F) == 0x30


def test_retry_count_zero_retries_an_absent_chip_until_cancel(rig):
    b, _, chip = rig  # the power-up configuration: retry count 0, no timeouts
    chip.on_report(bytes.fromhex("10 62 0001").ljust(64, b"\x00"))
    b.clock.sleep(1.0)
    (status,) = chip.on_report(bytes.fromhex("1501").ljust(64, b"\x00"))
    assert status[1] == 1  # still busy a second later
    chip.on_report(bytes.fromhex("1701").ljust(64, b"\x00"))
    (status,) = chip.on_report(bytes.fromhex("1501").ljust(64, b"\x00"))
    assert status[1] == 0  # idle after Cancel


def test_a_stuck_bus_is_bus_not_free_after_the_timeout(rig):
    b, usb, _ = rig
    bus = CP2112Bus(SERIAL, clock=b.clock, hid_module=usb, tries=1)
    b.wire.sda_stuck_low = True
    start = b.clock.now()
    with pytest.raises(DeviceTimeout) as caught:
        bus.read_byte_data(0x30, 0x2F)
    assert str(caught.value) == (f"cp2112 {SERIAL}: read register at 0x30: bus stuck: not free within 25 ms "
                                 "(SDA or SCL held low) (after 1 tries)")
    assert b.clock.now() - start >= 0.025


def test_a_short_read_is_read_incomplete(rig):
    b, usb, _ = rig
    bus = CP2112Bus(SERIAL, clock=b.clock, hid_module=usb, tries=1)
    b.wire.short_read = 3
    with pytest.raises(DeviceError, match="short read: 3 of 7 bytes"):
        bus.read_i2c_block_data(0x30, 0x00, 7)
    assert len(bus.read_i2c_block_data(0x30, 0x00, 7)) == 7  # nothing stale left behind


def test_a_version_1_chip_reads_a_register_as_write_then_read(rig):
    b, usb, chip = rig
    chip.version = 1
    bus = CP2112Bus(SERIAL, clock=b.clock, hid_module=usb)
    chip.reports.clear()
    assert bus.read_byte_data(0x30, 0x2F) == 0x30
    assert [r[0] for r in chip.reports] == [0x14, 0x15, 0x10, 0x15, 0x12]


def test_missing_and_unplugged(rig):
    b, usb, chip = rig
    with pytest.raises(DeviceNotFound, match="cp2112 0002: open: no CP2112 .USB 10c4:ea90. with serial"):
        CP2112Bus("0002", clock=b.clock, hid_module=usb)
    bus = CP2112Bus(SERIAL, clock=b.clock, hid_module=usb)
    usb.unplug(chip)
    with pytest.raises(DeviceNotFound, match="cp2112 0001: read register at 0x30"):
        bus.read_byte_data(0x30, 0x2F)
    usb.replug(chip)
    assert bus.read_byte_data(0x30, 0x2F) == 0x30


def test_no_quick_command_so_the_scan_reads_and_finds_everything(rig):
    b, usb, _ = rig
    bus = CP2112Bus(SERIAL, clock=b.clock, hid_module=usb)
    assert not hasattr(bus, "write_quick")
    scan = busscan.scan_i2c(bus)
    assert {(f.address, f.switch, f.channel) for f in scan.found} == {(0x70, None, None), (0x30, None, None),
                                                                        (0x48, 0x70, 3)}
    dut = MMC5983MA(bus, 0x30, name="dut", clock=b.clock)
    dut.connect()
    assert dut.read().field_nt is not None
