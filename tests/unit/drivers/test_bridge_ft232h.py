"""The FT232H transport (pyftdi's I2cController) against the FT232H simulator behind a pyusb backend:
the MPSSE bytes pyftdi writes, as hardware-notes 8.3 records them, decoded to SCL/SDA by the simulator,
and each fault as its one-line error."""

from __future__ import annotations

import errno

import pytest

from drivers import busscan
from drivers.errors import DeviceError, DeviceNotFound, DeviceTimeout
from drivers.mmc5983ma import MMC5983MA
from drivers.sim.transports.ft232h import FT232HSim
from drivers.sim.transports.usbfake import FakeUsbBackend
from drivers.transports.ft232h import FT232HBus, list_devices, parse_url
from tests.unit.drivers.bridge_bench import bench

SERIAL = "FT0FMF6V"
URL = f"ftdi://ftdi:232h:{SERIAL}/1"
IDLE, DATA_LOW, BOTH_LOW, SDA_RELEASED = (bytes.fromhex(x) for x in ("800303", "800103", "800003", "800203"))


@pytest.fixture
def rig():
    b = bench()
    backend = FakeUsbBackend()
    chip = FT232HSim(b.wire, b.clock, serial=SERIAL)
    backend.plug(chip)
    return b, backend, chip


def test_urls_as_pyftdi_writes_them():
    assert parse_url("ftdi://ftdi:232h/1") == (0x0403, 0x6014, None, 0, 1)
    assert parse_url("ftdi://::FT0FMF6V/1") == (0x0403, 0x6014, "FT0FMF6V", 0, 1)
    assert parse_url("ftdi://ftdi:ft232h:1/1") == (0x0403, 0x6014, None, 1, 1)
    with pytest.raises(ValueError, match="not an ftdi://"):
        parse_url("usb://ftdi/1")


def test_listing_gives_usb_id_and_serial(rig):
    _, backend, _ = rig
    (found,) = list_devices(backend)
    assert (found["vendor_id"], found["product_id"], found["serial_number"]) == (0x0403, 0x6014, SERIAL)


@pytest.mark.parametrize("speed_hz, divisor", [(100_000, "862700"), (400_000, "860900")])
def test_configure_writes_the_notes_setup_stream(rig, speed_hz, divisor):
    b, backend, chip = rig
    FT232HBus(URL, speed_hz=speed_hz, clock=b.clock, usb_backend=backend)
    assert chip.batches[:5] == [bytes.fromhex("8b" + divisor), bytes.fromhex("80ff03 820000"),
                                bytes.fromhex("85"), bytes.fromhex("8c"), bytes.fromhex("9e0700")]
    assert chip.three_phase and chip.drive_zero == 0x07  # decoded: 3-phase clocking, AD0-AD2 open drain


def test_a_register_read_is_start_address_ack_then_repeated_start_and_read(rig):
    b, backend, chip = rig
    bus = FT232HBus(URL, clock=b.clock, usb_backend=backend)
    first = len(chip.batches)
    assert bus.read_byte_data(0x30, 0x2F) == 0x30
    batches = chip.batches[first:]
    start = IDLE * 10 + DATA_LOW * 9 + BOTH_LOW * 9  # at 100 kHz: idle 10, t_HD;STA 9
    ack = SDA_RELEASED + bytes.fromhex("220087")
    assert batches[0] == start + bytes.fromhex("110000 60") + ack  # START, 0x30 + W
    assert batches[1] == bytes.fromhex("110000 2f") + ack  # the register
    assert batches[2] == start + bytes.fromhex("110000 61") + ack  # repeated START, 0x30 + R
    read_last = bytes.fromhex("200000 1300ff")  # one byte in, then the master's NACK
    assert batches[3] == read_last + SDA_RELEASED * 10 + bytes.fromhex("87")
    assert batches[4] == SDA_RELEASED * 9 + BOTH_LOW * 9 + DATA_LOW * 9 + IDLE * 10  # STOP
    assert b.wire.address_phases >= 2 and chip.target.state == "idle"  # decoded as two messages, stopped


def test_a_nack_is_oserror_121_after_one_address_try(rig):
    b, backend, _ = rig
    bus = FT232HBus(URL, clock=b.clock, usb_backend=backend)
    phases = b.wire.address_phases
    with pytest.raises(OSError) as caught:
        bus.read_byte_data(0x31, 0x00)
    assert caught.value.errno == errno.EREMOTEIO
    assert b.wire.address_phases == phases + 1  # pyftdi's own retries are off: the project's policy rules


def test_a_stuck_bus_reads_as_acks_and_zeros_so_the_pins_are_checked(rig):
    b, backend, _ = rig
    bus = FT232HBus(URL, clock=b.clock, usb_backend=backend, tries=1)
    b.wire.sda_stuck_low = True
    with pytest.raises(DeviceTimeout) as caught:
        bus.read_byte_data(0x30, 0x2F)
    assert str(caught.value) == f"ft232h {URL}: read register at 0x30: bus stuck: SDA held low " \
                                "(after 1 tries)"
    with pytest.raises(DeviceTimeout, match="bus stuck"):
        bus.write_byte_data(0x30, 0x09, 0x01)  # a write "succeeds" on the wire: the pins tell
    b.wire.sda_stuck_low = False
    assert bus.read_byte_data(0x30, 0x2F) == 0x30


def test_a_short_read_is_an_error(rig):
    b, backend, _ = rig
    bus = FT232HBus(URL, clock=b.clock, usb_backend=backend, tries=1)
    b.wire.short_read = 3
    with pytest.raises(DeviceError, match="short read: 3 of 7 bytes"):
        bus.read_i2c_block_data(0x30, 0x00, 7)


def test_missing_and_unplugged(rig):
    b, backend, chip = rig
    with pytest.raises(DeviceNotFound, match="ft232h ftdi://::OTHER/1: open: no FT232H .USB 0403:6014. "
                                             "matches ftdi://::OTHER/1 .plugged in: serial numbers FT0"):
        FT232HBus("ftdi://::OTHER/1", clock=b.clock, usb_backend=backend)
    bus = FT232HBus(URL, clock=b.clock, usb_backend=backend)
    backend.unplug(chip)
    with pytest.raises(DeviceNotFound, match=f"ft232h {URL}: read register at 0x30: no FT232H"):
        bus.read_byte_data(0x30, 0x2F)
    backend.plug(chip)
    assert bus.read_byte_data(0x30, 0x2F) == 0x30


def test_the_latency_timer_sets_the_pace(rig):
    b, backend, _ = rig
    times = {}
    for latency_ms in (16, 2):
        bus = FT232HBus(URL, clock=b.clock, usb_backend=backend, latency_ms=latency_ms)
        start = b.clock.now()
        bus.read_byte_data(0x30, 0x2F)
        times[latency_ms] = b.clock.now() - start
        bus.close()
    assert 0.016 < times[16] < 0.020  # the STOP's purge read waits for the latency timer
    assert 0.002 < times[2] < 0.006


def test_quick_writes_scan_and_the_driver_works_unchanged(rig):
    b, backend, _ = rig
    bus = FT232HBus(URL, clock=b.clock, usb_backend=backend)
    scan = busscan.scan_i2c(bus)
    assert {(f.address, f.switch, f.channel) for f in scan.found} == {(0x70, None, None), (0x30, None, None),
                                                                        (0x48, 0x70, 3)}
    dut = MMC5983MA(bus, 0x30, name="dut", clock=b.clock)
    dut.connect()
    truth = b.world.dut_raw_nt("dut", 1, noisy=False) - b.world.dut_raw_nt("dut", -1, noisy=False)
    assert dut.read().field_nt == pytest.approx(tuple(truth / 2), abs=20)
