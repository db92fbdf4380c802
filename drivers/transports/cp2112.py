"""Silicon Labs CP2112 USB-to-SMBus bridge through hidapi: its numbered HID reports (AN495,
hardware-notes 8.2), under the smbus2 methods the drivers use (drivers/transports/bridge.py).

    bus = CP2112Bus("0001", speed_hz=100_000, clock=clock)     # hid_module: a stand-in (tests)

At open: the version (feature report 0x05), then the SMBus configuration (feature 0x06: the clock, no
auto-send-read (erratum CP2112_E101), write and read timeouts, the SCL-low timeout on, retry count 1, as
Linux and FreeBSD set it: 0 would retry an absent chip without end), read back to check; stale IN
reports (the notes: spurious ones arrive right after attach) are drained. A transfer is one request
(0x14 write, 0x11 write-read with a repeated START, or 0x10 read), then 0x15 status requests until the
0x16 status is no longer busy; read data is fetched with 0x12 force read and its 0x13 responses.
Status error with status1 0 (address NACKed) is raised as OSError 121 (Linux reports ETIMEDOUT there;
the status itself says NACK); 1 (bus not free) is a stuck bus; a transfer still busy at the deadline is
cancelled (0x17). A chip of version 1 has no repeated START (erratum CP2112_E10): a register read is
then a write and a separate read. The CP2112 has no SMBus quick command, so this bus offers no
`write_quick` (the bus scan reads instead).
"""

from __future__ import annotations

from drivers.clock import Clock
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError
from drivers.transports.bridge import TRIES, BridgeBus, check_speed, nack_error
from drivers.transports.hidbridge import HidLink, import_hid, open_hid

VENDOR_ID = 0x10C4
PRODUCT_ID = 0xEA90
REPORT_LENGTH = 64
RESET, VERSION, SMBUS_CONFIG = 0x01, 0x05, 0x06
READ_REQUEST, WRITE_READ_REQUEST, FORCE_READ, READ_RESPONSE = 0x10, 0x11, 0x12, 0x13
WRITE, STATUS_REQUEST, STATUS_RESPONSE, CANCEL = 0x14, 0x15, 0x16, 0x17
IDLE, BUSY, COMPLETE, ERROR = 0, 1, 2, 3
NACKED, BUS_NOT_FREE, ARBITRATION_LOST, READ_INCOMPLETE, WRITE_INCOMPLETE = 0, 1, 2, 3, 4
WRITE_MAX, WRITE_READ_MAX, READ_MAX = 61, 16, 512
OWN_ADDRESS = 0x02  # the CP2112's own slave address (upper 7 bits, as Linux stores it)
TIMEOUT_MS = 25  # the write and read timeouts the chip is given (a transfer here takes < 5 ms)
RETRY_COUNT = 1
REPLY_TIMEOUT_MS = 50  # Linux waits 50 ms for each status reply
DEADLINE_S = 0.2  # status polls on one transfer, then Cancel
DRAIN_TIMEOUT_MS = 5
DRAIN_MAX = 16


def config_report(speed_hz: int) -> bytes:
    return (bytes([SMBUS_CONFIG]) + int(speed_hz).to_bytes(4, "big") + bytes([OWN_ADDRESS, 0])
            + TIMEOUT_MS.to_bytes(2, "big") + TIMEOUT_MS.to_bytes(2, "big") + bytes([1])
            + RETRY_COUNT.to_bytes(2, "big"))


class CP2112Bus(BridgeBus):
    kind = "cp2112"

    def __init__(self, serial: str | None = None, *, speed_hz: float = 100_000, clock: Clock | None = None,
                 tries: int = TRIES, hid_module=None):
        super().__init__(f"cp2112 {serial or '(the only one)'}", clock=clock, tries=tries)
        check_speed(self.kind, speed_hz)
        self.serial = serial
        self.speed_hz = int(speed_hz)
        self.hid = hid_module
        self.link: HidLink | None = None
        self.version = 0
        self._open()

    # --- opening ------------------------------------------------------------------------------------
    def _open(self) -> None:
        hid = self.hid or import_hid(self.name)
        dev, self.info = open_hid(hid, VENDOR_ID, PRODUCT_ID, self.serial, name=self.name, model="CP2112")
        self.link = HidLink(dev, self)
        version = self._get_feature(VERSION, 3)
        self.version = version[2]
        report = config_report(self.speed_hz)
        self.log_frame("feature tx", report)
        if dev.send_feature_report(report) < 0:
            raise DeviceError(self.name, "configure", "the SMBus configuration report was refused")
        got = self._get_feature(SMBUS_CONFIG, len(report))
        if (got[1:5], got[6], got[12:14]) != (report[1:5], report[6], report[12:14]):
            raise DeviceError(self.name, "configure", f"the SMBus configuration did not take "
                                                      f"(read back {got.hex(' ')})")
        self._drain()

    def _get_feature(self, report_id: int, length: int) -> bytes:
        try:
            report = bytes(self.link.dev.get_feature_report(report_id, length))
        except (OSError, ValueError) as exc:
            raise DeviceError(self.name, f"read feature report 0x{report_id:02X}", str(exc)) from exc
        self.log_frame("feature rx", report)
        if len(report) < length or report[0] != report_id:
            raise ProtocolError(self.name, f"read feature report 0x{report_id:02X}", f"got {report.hex(' ')}")
        return report

    def _drain(self) -> None:
        """Throw away IN reports nobody asked for (no report carries a transaction id)."""
        for _ in range(DRAIN_MAX):
            try:
                stale = self.link.dev.read(REPORT_LENGTH, DRAIN_TIMEOUT_MS)
            except (OSError, ValueError):
                return
            if not stale:
                return
            self.log_frame("rx (stale, dropped)", bytes(stale))

    def close(self) -> None:
        if self.link is not None:
            self.link.close()
            self.link = None

    def _recover(self) -> None:
        if self.link is None or self.link.gone:
            self.close()
            self._open()
        else:
            self._cancel()
            self._drain()

    # --- reports ------------------------------------------------------------------------------------
    def _send(self, report: bytes) -> None:
        if self.link is None:
            self._open()  # closed after a USB failure: it must be back to go on
        self.link.write(report.ljust(REPORT_LENGTH, b"\x00"))

    def _cancel(self) -> None:
        self._send(bytes([CANCEL, 0x01]))

    def _status(self) -> tuple[int, int, int, int]:
        self._send(bytes([STATUS_REQUEST, 0x01]))
        for _ in range(DRAIN_MAX):
            r = self.link.read(REPORT_LENGTH, REPLY_TIMEOUT_MS, expect=(STATUS_RESPONSE, READ_RESPONSE))
            if r[0] == STATUS_RESPONSE:
                return r[1], r[2], int.from_bytes(r[3:5], "big"), int.from_bytes(r[5:7], "big")
            # the notes: a force read tends to end with an empty 0x13 report; it is not an answer
            self.log_frame("rx (stale read response, dropped)", r)
        raise ProtocolError(self.name, "transfer status", "no status among the reports")

    # --- transfers ----------------------------------------------------------------------------------
    def _transfer(self, address: int, write: bytes, read_length: int) -> bytes:
        address8 = address << 1
        if read_length > READ_MAX or len(write) > WRITE_MAX or not (write or read_length):
            raise ValueError(f"cp2112: write {len(write)} / read {read_length} bytes: the CP2112 takes "
                             f"writes of 1..{WRITE_MAX} and reads of 1..{READ_MAX}")
        if write and read_length and self.version >= 2 and len(write) <= WRITE_READ_MAX:
            self._send(bytes([WRITE_READ_REQUEST, address8]) + read_length.to_bytes(2, "big")
                       + bytes([len(write)]) + write)
        else:
            if write:
                self._send(bytes([WRITE, address8, len(write)]) + write)
                self._wait(0)
            if not read_length:
                return b""
            self._send(bytes([READ_REQUEST, address8]) + read_length.to_bytes(2, "big"))
        count = self._wait(read_length)
        return self._fetch(count)

    def _wait(self, read_length: int) -> int:
        """Status polls until the transfer is no longer busy: the bytes read, or the error raised."""
        deadline = self.clock.now() + DEADLINE_S
        while True:
            s0, s1, _, count = self._status()
            if s0 == COMPLETE:
                return count
            if s0 == ERROR:
                self._error(s1, count, read_length)
            if s0 == IDLE:
                raise ProtocolError(self.name, "I2C transfer", "the bridge reports no transfer (idle)")
            if self.clock.now() >= deadline:
                self._cancel()
                raise DeviceTimeout(self.name, "I2C transfer", f"still busy after {DEADLINE_S * 1e3:.0f} ms "
                                                               f"(status1 {s1}); cancelled")

    def _error(self, status1: int, count: int, read_length: int) -> None:
        if status1 == NACKED:
            raise nack_error()
        if status1 == BUS_NOT_FREE:
            self._cancel()
            raise DeviceTimeout(self.name, "I2C transfer", "bus stuck: not free within "
                                                           f"{TIMEOUT_MS} ms (SDA or SCL held low)")
        if status1 == READ_INCOMPLETE:
            self._fetch(count)  # what did arrive, so no stale response is left behind
            raise DeviceError(self.name, "I2C read", f"short read: {count} of {read_length} bytes")
        what = {ARBITRATION_LOST: "arbitration lost", WRITE_INCOMPLETE: "write incomplete"}
        raise DeviceError(self.name, "I2C transfer", what.get(status1, f"error status1 {status1}"))

    def _fetch(self, count: int) -> bytes:
        """Force read `count` bytes and gather the 0x13 responses (up to 61 bytes each)."""
        if not count:
            return b""
        self._send(bytes([FORCE_READ]) + count.to_bytes(2, "big"))
        data = bytearray()
        while len(data) < count:
            r = self.link.read(REPORT_LENGTH, REPLY_TIMEOUT_MS, expect=READ_RESPONSE)
            data += r[3:3 + r[2]]
            if r[1] != BUSY and r[2] == 0:
                break  # a complete response with nothing in it: no more is coming
        return bytes(data)
