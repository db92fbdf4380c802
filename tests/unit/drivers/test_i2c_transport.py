"""I2C transport and the fake bus: transfers, NACK handling, retries, raw log, bus doubles."""

from __future__ import annotations

import errno
import logging

import pytest

from drivers.clock import SimClock
from drivers.errors import DeviceError, DeviceNotFound, DeviceTimeout
from drivers.sim.transports.i2c_bus import FakeSMBus, RegisterChip
from drivers.transports.i2c import I2CTransport, open_smbus
from tests.helpers.smbus_doubles import RecordingSMBus, ScriptedSMBus

ADDR = 0x30


@pytest.fixture
def chip() -> RegisterChip:
    chip = RegisterChip()
    chip.registers[0x00:0x08] = bytes([0x80, 0x01, 0x7F, 0xFE, 0x12, 0x34, 0xC0, 0x55])
    return chip


@pytest.fixture
def bus(chip: RegisterChip) -> FakeSMBus:
    bus = FakeSMBus()
    bus.attach(ADDR, chip)
    return bus


def link_on(bus, **kw) -> I2CTransport:
    return I2CTransport(bus, ADDR, name="dut1", clock=kw.pop("clock", SimClock()), **kw)


def test_reads_and_writes_reach_the_chip(bus: FakeSMBus, chip: RegisterChip) -> None:
    link = link_on(bus)
    assert link.read_byte(0x07, "temperature") == 0x55
    assert link.read_block(0x00, 7, "field data") == bytes([0x80, 0x01, 0x7F, 0xFE, 0x12, 0x34, 0xC0])
    link.write_byte(0x09, 0x01, "control 0")
    link.write_block(0x20, b"\x0a\x0b\x0c", "block")
    assert chip.registers[0x09] == 0x01
    assert chip.registers[0x20:0x23] == b"\x0a\x0b\x0c"


def test_nack_ends_in_device_not_found_naming_device_operation_and_address(bus: FakeSMBus) -> None:
    recorder = RecordingSMBus(bus)
    clock = SimClock()
    link = link_on(recorder, clock=clock)
    bus.nack(ADDR)  # every transfer
    with pytest.raises(DeviceNotFound) as err:
        link.read_byte(0x08, "status")
    assert str(err.value) == "dut1: read status register 0x08: no ACK at 0x30 (after 3 tries)"
    assert [c.op for c in recorder.calls] == ["nack", "nack", "nack"]
    backoff_s = clock.now() - SimClock().now()
    assert backoff_s == pytest.approx(0.002 + 0.004, abs=1e-6)  # doubling, on the injected clock


def test_retry_recovers_after_transient_nacks_and_warns(bus: FakeSMBus, caplog) -> None:
    link = link_on(bus)
    bus.nack(ADDR, count=2)
    with caplog.at_level(logging.WARNING, logger="magrig.transport"):
        assert link.read_byte(0x07, "temperature") == 0x55
    retries = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(retries) == 2
    assert all(r.device == "dut1" for r in retries)
    assert "no ACK at 0x30" in retries[0].getMessage()


def test_unplug_and_replug(bus: FakeSMBus, chip: RegisterChip) -> None:
    link = link_on(bus, tries=2)
    unplugged = bus.detach(ADDR)
    expected = r"write control 0 register 0x09: no ACK at 0x30 \(after 2 tries\)"
    with pytest.raises(DeviceNotFound, match=expected):
        link.write_byte(0x09, 0x01, "control 0")
    bus.attach(ADDR, unplugged)
    assert link.read_byte(0x07, "temperature") == 0x55


def test_other_bus_errors_are_device_errors_not_not_found(bus: FakeSMBus) -> None:
    class FailingBus(FakeSMBus):
        def __init__(self, err: int):
            super().__init__()
            self.err = err

        def read_byte_data(self, i2c_addr, register, force=None):
            raise OSError(self.err, "bus trouble")

    with pytest.raises(DeviceTimeout, match=r"bus timeout \(or no ACK\) at 0x30"):  # a CP2112's NACK too
        link_on(FailingBus(errno.ETIMEDOUT)).read_byte(0x08, "status")
    with pytest.raises(DeviceError, match=r"I2C error at 0x30: \[Errno 5\] bus trouble") as err:
        link_on(FailingBus(errno.EIO)).read_byte(0x08, "status")
    assert not isinstance(err.value, DeviceNotFound)
    with pytest.raises(DeviceNotFound, match="no ACK at 0x30"):  # how an MCP2221 bridge reports a NACK
        link_on(FailingBus(errno.ENXIO)).read_byte(0x08, "status")


def test_raw_transfers_logged_at_debug(bus: FakeSMBus, caplog) -> None:
    link = link_on(bus)
    with caplog.at_level(logging.DEBUG, logger="magrig.transport.i2c"):
        link.read_block(0x00, 2, "field data")
        link.write_byte(0x09, 0x02, "control 0")
    lines = [r.getMessage() for r in caplog.records if r.name == "magrig.transport.i2c"]
    assert lines == ["dut1: 0x30 read 0x00 -> 80 01", "dut1: 0x30 write 0x09 <- 02"]


def test_burst_limit_is_32_bytes(bus: FakeSMBus) -> None:
    link = link_on(bus)
    assert len(link.read_block(0x00, 32, "block")) == 32
    with pytest.raises(ValueError, match="33 bytes"):
        link.read_block(0x00, 33, "block")
    with pytest.raises(ValueError, match="Data length cannot exceed 32 bytes"):
        bus.read_i2c_block_data(ADDR, 0x00, 33)


def test_wait_until_times_out_on_the_clock_with_a_clear_message(bus: FakeSMBus) -> None:
    clock = SimClock()
    link = link_on(bus, clock=clock)
    start = clock.now()
    with pytest.raises(DeviceTimeout, match=r"dut1: wait for Meas_M_Done: not ready after 33\.0 ms"):
        link.wait_until(lambda: False, what="Meas_M_Done", first_wait_s=0.008, timeout_s=0.033)
    assert clock.now() - start == pytest.approx(0.033, abs=1e-6)
    polls = []
    link.wait_until(lambda: polls.append(1) or len(polls) == 3, what="x", first_wait_s=0.0, timeout_s=1.0)
    assert len(polls) == 3


def test_fake_bus_absent_address_is_errno_121() -> None:
    with pytest.raises(OSError) as err:
        FakeSMBus().read_byte_data(0x77, 0x00)
    assert err.value.errno == 121
    assert err.value.strerror == "Remote I/O error"


def test_fake_bus_word_access_is_little_endian_like_smbus(bus: FakeSMBus, chip: RegisterChip) -> None:
    assert bus.read_word_data(ADDR, 0x00) == 0x0180  # wire order 0x80, 0x01
    bus.write_word_data(ADDR, 0x10, 0xBEEF)
    assert chip.registers[0x10:0x12] == b"\xef\xbe"


def test_nack_count_then_heal(bus: FakeSMBus) -> None:
    bus.nack(ADDR, count=1)
    with pytest.raises(OSError):
        bus.read_byte_data(ADDR, 0x07)
    assert bus.read_byte_data(ADDR, 0x07) == 0x55
    bus.nack(ADDR)
    bus.nack(ADDR, 0)
    assert bus.read_byte_data(ADDR, 0x07) == 0x55


def test_scripted_bus_rejects_wrong_bytes_and_unfinished_transcripts() -> None:
    bus = ScriptedSMBus(ADDR, [("write", 0x09, b"\x01"), ("read", 0x08, b"\x01")])
    with pytest.raises(AssertionError, match="step 0: expected write 0x09"):
        bus.write_byte_data(ADDR, 0x09, 0x02)
    bus.write_byte_data(ADDR, 0x09, 0x01)
    with pytest.raises(AssertionError, match="not finished"):
        bus.assert_done()
    assert bus.read_byte_data(ADDR, 0x08) == 0x01
    bus.assert_done()


def test_open_smbus_missing_bus_is_a_clear_error() -> None:
    with pytest.raises(DeviceNotFound, match=r"i2c-97: open bus: /dev/i2c-97 does not exist"):
        open_smbus(97)
