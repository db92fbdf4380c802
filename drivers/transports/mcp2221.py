"""Microchip MCP2221 / MCP2221A USB-to-I2C bridge through hidapi: its 64-byte HID commands
(hardware-notes 8.1), under the smbus2 methods the drivers use (drivers/transports/bridge.py).

    bus = MCP2221Bus("0001234567", speed_hz=100_000, clock=clock)     # hid_module: a stand-in (tests)
    MMC5983MA(I2CTransport(bus, 0x30, name="dut1"), ...)

Every command is one 64-byte OUT report (hidapi: a leading report number 0) answered by one 64-byte IN
report echoing the command. A register read is the sequence the notes give: 0x94 write without STOP,
status polls until the engine shows 0x45, 0x93 read with a repeated START, then 0x40 until the bytes are
in (0x41: not on the chip yet, ask again about 1 ms later). A write is 0x90 and status polls until the
engine is idle; a plain read 0x91 and the 0x40 loop. A busy reply ([1]=0x01) is sent again, up to 50
times. An address NACK (state 0x25, or status byte 20 bit 6) is cancelled and raised as OSError 121.
A timeout state (0x12, 0x17, 0x23, 0x44, 0x52, 0x62) is cancelled and judged by the pin levels the
status gives: SDA low is a stuck bus. Cancel is sent only when the engine is not idle (a cancel of an
idle engine can wedge it until reset).

Speed: divider = round(12 MHz / f) - 2 (MCP2221A datasheet DS20005565 Table 3-1 note 1, as quoted by
two libraries; Linux and Blinka subtract 3: the notes record both).
"""

from __future__ import annotations

from drivers.clock import Clock
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError
from drivers.transports.bridge import TRIES, BridgeBus, check_speed, nack_error
from drivers.transports.hidbridge import HidLink, import_hid, open_hid

VENDOR_ID = 0x04D8
PRODUCT_ID = 0x00DD
REPORT_LENGTH = 64
CHUNK_BYTES = 60
STATUS, GET_DATA = 0x10, 0x40
WRITE, READ, READ_RS, WRITE_NO_STOP = 0x90, 0x91, 0x93, 0x94
CANCEL, SET_SPEED = 0x10, 0x20
OK, BUSY, DATA_NOT_READY, READ_ERROR_COUNT = 0x00, 0x01, 0x41, 127
IDLE, ADDRESS_NACK, NO_STOP_DONE, READ_LAST = 0x00, 0x25, 0x45, 0x55
TIMEOUT_STATES = (0x12, 0x17, 0x23, 0x44, 0x52, 0x62)
NACK_FLAG = 0x40  # status byte 20 bit 6
REPLY_TIMEOUT_MS = 100  # a reply comes within a frame or two; Linux waits up to 4 s
BUSY_TRIES = 50  # Blinka's MCP2221_RETRY_MAX
MAX_POLLS = 200  # status or 0x40 polls per transfer (each a USB round trip of about 2 ms)
POLL_S = 0.001  # the notes: ask again about 1-2 ms later


def divider_for(speed_hz: float) -> int:
    divider = round(12e6 / speed_hz) - 2
    if not 0 <= divider <= 255:
        raise ValueError(f"mcp2221: I2C speed {speed_hz:g} Hz needs divider {divider}, outside 0..255")
    return divider


class MCP2221Bus(BridgeBus):
    kind = "mcp2221"

    def __init__(self, serial: str | None = None, *, speed_hz: float = 100_000, clock: Clock | None = None,
                 tries: int = TRIES, hid_module=None):
        super().__init__(f"mcp2221 {serial or '(the only one)'}", clock=clock, tries=tries)
        check_speed(self.kind, speed_hz)
        self.serial = serial
        self.divider = divider_for(speed_hz)
        self.hid = hid_module
        self.link: HidLink | None = None
        self._open()

    # --- opening ------------------------------------------------------------------------------------
    def _open(self) -> None:
        hid = self.hid or import_hid(self.name)
        dev, self.info = open_hid(hid, VENDOR_ID, PRODUCT_ID, self.serial, name=self.name, model="MCP2221A")
        self.link = HidLink(dev, self)
        status = self._status()
        if status[8] != IDLE:
            self._cancel()  # a transfer left over from an earlier run
        status = self._status(bytes([0, 0, SET_SPEED, self.divider]))
        if status[3] != SET_SPEED:
            raise DeviceError(self.name, "set I2C speed",
                              f"divider {self.divider} refused (reply 0x{status[3]:02X})")

    def close(self) -> None:
        if self.link is not None:
            self.link.close()
            self.link = None

    def _recover(self) -> None:
        if self.link is None or self.link.gone:
            self.close()
            self._open()
        elif self._status()[8] != IDLE:
            self._cancel()

    # --- commands -----------------------------------------------------------------------------------
    def _command(self, report: bytes) -> bytes:
        if self.link is None:
            self._open()  # closed after a USB failure: it must be back to go on
        link = self.link
        link.write(b"\x00" + report.ljust(REPORT_LENGTH, b"\x00"))
        return link.read(REPORT_LENGTH, REPLY_TIMEOUT_MS, expect=report[0])

    def _status(self, parameters: bytes = b"") -> bytes:
        return self._command(bytes([STATUS]) + parameters)

    def _cancel(self) -> bytes:
        self._command(bytes([STATUS, 0, CANCEL]))
        self.clock.sleep(POLL_S)  # the bus is freed a few hundred microseconds later
        return self._status()

    def _send(self, report: bytes) -> None:
        """A transfer command, sent again while the engine answers busy."""
        for _ in range(BUSY_TRIES):
            reply = self._command(report)
            if reply[1] == OK:
                return
            if reply[1] != BUSY:
                raise ProtocolError(self.name, f"command 0x{report[0]:02X}", f"status 0x{reply[1]:02X}")
            if reply[2] in TIMEOUT_STATES:
                self._bus_fault(reply[2])
            self.clock.sleep(POLL_S)
        raise DeviceTimeout(self.name, f"command 0x{report[0]:02X}",
                            f"I2C engine busy after {BUSY_TRIES} tries (state 0x{reply[2]:02X})")

    # --- transfers ----------------------------------------------------------------------------------
    def _transfer(self, address: int, write: bytes, read_length: int) -> bytes:
        address8 = address << 1
        if not read_length:
            self._write(WRITE, address8, write)
            self._wait_for(IDLE)
            return b""
        command = READ
        if write:
            self._write(WRITE_NO_STOP, address8, write)
            self._wait_for(NO_STOP_DONE, IDLE)  # the notes expect 0x45; an idle engine is as good
            command = READ_RS
        self._send(bytes([command]) + read_length.to_bytes(2, "little") + bytes([address8 | 1]))
        return self._fetch(read_length)

    def _write(self, command: int, address8: int, data: bytes) -> None:
        header = bytes([command]) + len(data).to_bytes(2, "little") + bytes([address8])
        for start in range(0, len(data), CHUNK_BYTES):
            self._send(header + data[start:start + CHUNK_BYTES])

    def _wait_for(self, *done: int) -> None:
        """Status polls until the engine shows a `done` state; a NACK or a timeout state ends it early."""
        for _ in range(MAX_POLLS):
            status = self._status()
            state = status[8]
            if state == ADDRESS_NACK or status[20] & NACK_FLAG:
                if state != IDLE:
                    self._cancel()  # never an idle engine: that can wedge it
                raise nack_error()
            if state in TIMEOUT_STATES:
                self._bus_fault(state)
            if state in done:
                return
        raise DeviceTimeout(self.name, "I2C transfer", f"engine still in state 0x{state:02X} after "
                                                       f"{MAX_POLLS} status polls")

    def _fetch(self, length: int) -> bytes:
        """0x40 until `length` bytes are in, or the engine says it has no more (a short read)."""
        data = bytearray()
        for _ in range(MAX_POLLS):
            reply = self._command(bytes([GET_DATA]))
            state = reply[2]
            if reply[1] == DATA_NOT_READY:
                self.clock.sleep(POLL_S)
                continue
            if state == ADDRESS_NACK:
                self._cancel()
                raise nack_error()
            if state in TIMEOUT_STATES:
                self._bus_fault(state)
            if reply[3] == READ_ERROR_COUNT:
                if state != IDLE:
                    self._cancel()
                raise DeviceError(self.name, "I2C read", "the engine reports a read error (count 127)")
            data += reply[4:4 + min(reply[3], CHUNK_BYTES)]
            if state == READ_LAST or len(data) >= length or (state == IDLE and reply[3] == 0):
                return bytes(data)
        raise DeviceTimeout(self.name, "I2C read", f"{len(data)} of {length} bytes after {MAX_POLLS} polls")

    def _bus_fault(self, state: int) -> None:
        """Cancel, then say what the pins show: SDA or SCL held low is a stuck bus."""
        status = self._cancel()
        scl, sda = status[22], status[23]
        if not (scl and sda):
            held = " and ".join(n for n, level in (("SCL", scl), ("SDA", sda)) if not level)
            detail = f"bus stuck: {held} held low (state 0x{state:02X})"
            raise DeviceTimeout(self.name, "I2C transfer", detail)
        raise DeviceTimeout(self.name, "I2C transfer", f"I2C engine timeout (state 0x{state:02X})")
