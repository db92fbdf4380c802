"""Protocol-level CP2112 (USB HID 10C4:EA90, AN495): its numbered HID reports decoded as the chip does
(hardware-notes 8.2), its transfer status on the simulated clock, and behind it the I2C wire
(drivers/sim/transports/i2c_wire.py) with the FakeSMBus chips and switches.

    chip = CP2112Sim(I2CWire(bus), clock, serial="0001")
    usb = FakeHid(clock); usb.plug(chip)           # the transport opens it through usb (a `hid` stand-in)

Feature reports (control endpoint): 0x06 SMBus configuration (14 bytes, big-endian fields: SCL clock Hz,
own address, auto-send-read, write timeout ms, read timeout ms, SCL-low timeout enable, retry count),
0x05 get version ([0x05, part number 0x0C, device version]), 0x01 reset. Interrupt reports: 0x10 data
read request ([1] address, [2-3] length), 0x11 write-read request ([1] address, [2-3] read length, [4] n,
[5..] n bytes), 0x12 force read ([1-2] length) answered by 0x13 read responses ([1] status, [2] length,
[3..] up to 61 bytes), 0x14 write ([1] address, [2] length, [3..] data), 0x15 transfer status request
answered by 0x16 ([1] status0, [2] status1, [3-4] retries BE16, [5-6] bytes read BE16), 0x17 cancel.

The transfer, as the notes give it: while the bus transfer runs (its bits at the configured clock),
status0 = 1 busy with status1 2 (read) or 3 (write); then 2 complete with status1 5 (succeeded after
status2 retries), or 3 error with status1 0 (address NACKed: every try of the retry count failed), 1 (bus
not free: SDA or SCL held low, reported when the write or read timeout runs out) or 3 (read incomplete:
fewer bytes than asked). A retry count of 0 retries an unanswered address without end and a timeout of
0 waits without end: the transfer then stays busy until Cancel, as the notes warn. Read data waits on
the chip until a force read asks for it. Right after attach one spurious 0x16 report is queued (the notes
report spurious reports there; a host must drain them).

Not in the notes, and so chosen here (said where used): the power-up configuration (100 kHz, no
timeouts, retry count 0, auto-send-read off), the device version (2), the status byte of 0x13 reports
(1 while more follow, 2 on the last), what a request does while a transfer runs, with an odd address
byte, or with lengths outside the notes' limits (not described: ValueError), and auto-send-read (not
modelled: the notes advise leaving it off).

Fault hooks: the wire's `sda_stuck_low` and `short_read`, FakeSMBus NACKs, `FakeHid.unplug(chip)`.
"""

from __future__ import annotations

import math

from drivers.clock import Clock
from drivers.sim.transports.i2c_wire import I2CWire, WireNack, WireStuck

VENDOR_ID = 0x10C4
PRODUCT_ID = 0xEA90
REPORT_LENGTH = 64
PART_NUMBER = 0x0C
DEVICE_VERSION = 2  # not in the notes; >= 2 carries write-read with a repeated START (erratum CP2112_E10)
READ_CHUNK = 61

RESET, VERSION, SMBUS_CONFIG = 0x01, 0x05, 0x06
READ_REQUEST, WRITE_READ_REQUEST, FORCE_READ, READ_RESPONSE = 0x10, 0x11, 0x12, 0x13
WRITE, STATUS_REQUEST, STATUS_RESPONSE, CANCEL = 0x14, 0x15, 0x16, 0x17
IDLE, BUSY, COMPLETE, ERROR = 0, 1, 2, 3
NACKED, BUS_NOT_FREE, READ_INCOMPLETE, SUCCEEDED = 0x00, 0x01, 0x03, 0x05
BUSY_READING, BUSY_WRITING = 2, 3


def power_up_config() -> bytes:
    """100 kHz, own address 0x02, no auto-send-read, no timeouts, SCL-low timeout off, retry count 0:
    not in the notes (AN495's PROM defaults were not read)."""
    return bytes([SMBUS_CONFIG]) + (100_000).to_bytes(4, "big") + bytes([0x02, 0, 0, 0, 0, 0, 0, 0, 0])


class CP2112Sim:
    vendor_id = VENDOR_ID
    product_id = PRODUCT_ID
    numbered_reports = True
    report_length = REPORT_LENGTH
    release_number = 0x0100  # descriptor values and strings: not in the notes
    manufacturer = "Silicon Labs"
    product = "CP2112 HID USB-to-SMBus Bridge"
    hid_interface = 0

    def __init__(self, wire: I2CWire, clock: Clock, serial: str = "0001"):
        self.wire = wire
        self.clock = clock
        self.serial_number = serial
        self.path = b""
        self.reports: list[bytes] = []  # every interrupt OUT report received, for tests
        self.version = DEVICE_VERSION  # a test may play a version-1 chip (no repeated START)
        self.power_on()

    def power_on(self) -> None:
        self.config = power_up_config()
        self.status = (IDLE, 0, 0, 0)  # status0, status1, retries, bytes read
        self.busy_until = 0.0
        self.finished = self.status  # the status once busy_until has passed (busy_until inf: never)
        self.read_data = b""
        self.attached = True  # the first open after attach finds a spurious status report

    def on_open(self) -> list[bytes]:
        if not self.attached:
            return []
        self.attached = False
        return [self._pad(bytes([STATUS_RESPONSE, IDLE, 0, 0, 0, 0, 0]))]

    # --- configuration ------------------------------------------------------------------------------
    @property
    def clock_hz(self) -> int:
        return int.from_bytes(self.config[1:5], "big")

    def _field(self, start: int) -> int:
        return int.from_bytes(self.config[start:start + 2], "big")

    def on_set_feature(self, report: bytes) -> bool:
        if report[0] == SMBUS_CONFIG and len(report) >= 14:
            if report[6]:
                raise ValueError("CP2112 auto-send-read is not modelled (the notes advise leaving it off)")
            self.config = bytes(report[:14])
            return True
        if report[0] == RESET and report[1:2] == b"\x01":
            self.power_on()  # the device enumerates again
            return True
        return False

    def on_get_feature(self, report_id: int) -> bytes | None:
        if report_id == SMBUS_CONFIG:
            return self.config
        if report_id == VERSION:
            return bytes([VERSION, PART_NUMBER, self.version])
        return None

    # --- interrupt reports --------------------------------------------------------------------------
    def on_report(self, report: bytes) -> list[bytes]:
        self.reports.append(report)
        now = self.clock.now()
        if now >= self.busy_until:
            self.status = self.finished
        kind = report[0]
        if kind == STATUS_REQUEST:
            s0, s1, retries, count = self.status
            return [self._pad(bytes([STATUS_RESPONSE, s0, s1]) + retries.to_bytes(2, "big")
                              + count.to_bytes(2, "big"))]
        if kind == CANCEL:
            self.status = self.finished = (IDLE, 0, 0, 0)
            self.busy_until, self.read_data = 0.0, b""
            return []
        if kind == FORCE_READ:
            return self._force_read(int.from_bytes(report[1:3], "big"))
        if kind not in (READ_REQUEST, WRITE_READ_REQUEST, WRITE):
            raise ValueError(f"CP2112 report 0x{kind:02X} is not modelled")
        if self.status[0] == BUSY:
            raise ValueError("CP2112: a request while a transfer runs is not described in the notes")
        self._request(kind, report)
        return []

    def _request(self, kind: int, report: bytes) -> None:
        address8 = report[1]
        if address8 & 1:
            raise ValueError(f"CP2112: address byte 0x{address8:02X} has bit 0 set: not described")
        write, read_length = b"", 0
        if kind == WRITE:
            write = report[3:3 + report[2]]
            _check(1 <= report[2] <= 61, "write length", report[2])
        else:
            read_length = int.from_bytes(report[2:4], "big")
            _check(1 <= read_length <= 512, "read length", read_length)
        if kind == WRITE_READ_REQUEST:
            if self.version < 2:
                raise ValueError("CP2112 version 1: write-read with a repeated START is erratum CP2112_E10")
            write = report[5:5 + report[4]]
            _check(1 <= report[4] <= 16, "write-read target length", report[4])
        self._run(address8 >> 1, bytes(write), read_length)

    def _run(self, address: int, write: bytes, read_length: int) -> None:
        now = self.clock.now()
        busy = (BUSY, BUSY_READING if read_length else BUSY_WRITING, 0, 0)
        retry_count = self._field(12)
        tries = 0
        while True:
            tries += 1
            try:
                self.read_data = self.wire.transfer(address, write, read_length)
                break
            except WireStuck:
                self._finish(now, busy, self._timeout_s(read_length), (ERROR, BUS_NOT_FREE, 0, 0))
                return
            except WireNack:
                spent_s = tries * I2CWire.bits(0, 0) / self.clock_hz
                if retry_count and tries >= retry_count:
                    self._finish(now, busy, spent_s, (ERROR, NACKED, tries, 0))
                    return
                timeout_s = self._timeout_s(read_length)
                if not retry_count and (math.isinf(timeout_s) or spent_s >= timeout_s):
                    self._finish(now, busy, timeout_s, (ERROR, NACKED, tries, 0))  # inf: busy until Cancel
                    return
        seconds = I2CWire.bits(len(write), read_length) / self.clock_hz
        got = len(self.read_data)
        result = (COMPLETE, SUCCEEDED, tries - 1, got) if got == read_length else \
            (ERROR, READ_INCOMPLETE, tries - 1, got)
        self._finish(now, busy, seconds, result)

    def _timeout_s(self, read_length: int) -> float:
        """The write or read timeout (ms; 0 = none: wait without end)."""
        ms = self._field(9) if read_length else self._field(7)
        return ms / 1000 if ms else math.inf

    def _finish(self, now: float, busy: tuple, seconds: float, result: tuple) -> None:
        self.status, self.busy_until, self.finished = busy, now + seconds, result

    def _force_read(self, length: int) -> list[bytes]:
        data, self.read_data = self.read_data[:length], self.read_data[length:]
        chunks = [data[i:i + READ_CHUNK] for i in range(0, len(data), READ_CHUNK)] or [b""]
        last = len(chunks) - 1
        return [self._pad(bytes([READ_RESPONSE, COMPLETE if i == last else BUSY, len(chunk)]) + chunk)
                for i, chunk in enumerate(chunks)]

    @staticmethod
    def _pad(report: bytes) -> bytes:
        return report.ljust(REPORT_LENGTH, b"\x00")


def _check(ok: bool, what: str, value: int) -> None:
    if not ok:
        raise ValueError(f"CP2112: {what} {value} outside the notes' limits: not described")
