"""Protocol-level MCP2221A (USB HID 04D8:00DD): its 64-byte HID commands decoded as the chip does
(hardware-notes 8.1, DS20005292/DS20005565), its I2C engine's state machine on the simulated clock, and
behind it the I2C wire (drivers/sim/transports/i2c_wire.py) with the FakeSMBus chips and switches.

    chip = MCP2221ASim(I2CWire(bus), clock, serial="0001234567")
    usb = FakeHid(clock); usb.plug(chip)           # the transport opens it through usb (a `hid` stand-in)

Commands: 0x10 status / set parameters (cancel with [2]=0x10, speed with [3]=0x20 and [4]=divider),
0x90 / 0x92 / 0x94 write (STOP / repeated START / no STOP; [1..2] total length LE, [3] 8-bit address,
up to 60 data bytes per report, longer writes in further reports repeating the header), 0x91 / 0x93 read,
0x40 get the read data (up to 60 bytes per reply), 0x70 reset. Every reply echoes the command in byte 0.

The engine, as the notes give it: a transfer command is answered at once ([1]=0x00 accepted, or 0x01
busy while a transfer is under way; [2] = the engine state when the command arrived); the bus transfer
then takes its time at f = 12 MHz / (divider + 2), so failures show in later replies: an address NACK
as state 0x25 and status byte 20 bit 6, a stuck bus (SDA held low) as state 0x12 (START timeout) with
status byte 23 (SDA) = 0. After 0x94 the engine sits in 0x45 and takes only a repeated-START command
next (otherwise [1]=0x01 with state 0x45). Read data is fetched with 0x40: [1]=0x41 while the next
chunk is not on the chip yet, else [2]=0x54 (more to come) or 0x55 (last), [3]=count, [4..] data; after
the last chunk the engine is idle (0x40 then answers state 0, count 0). A timed-out engine refuses
transfers (busy) until Cancel. The quirk the notes report is kept: a Cancel while the engine is idle
wedges it in 0x62 (STOP timeout) until reset.

Not in the notes, and so chosen here (said where used): the power-up divider (118, 100 kHz), a short
read (the wire delivers fewer bytes: the engine ends with what it has, last chunk 0x55, then idle), a
zero-length transfer (accepted, nothing on the bus, as EasyMCP2221 reports), the descriptor strings and
revision characters. Other commands (GPIO, flash, ADC...) are not modelled and raise ValueError.

Fault hooks: the wire's `sda_stuck_low` and `short_read`, FakeSMBus NACKs, `FakeHid.unplug(chip)`.
"""

from __future__ import annotations

from drivers.clock import Clock
from drivers.sim.transports.i2c_wire import I2CWire, Message, WireNack, WireStuck

VENDOR_ID = 0x04D8
PRODUCT_ID = 0x00DD
REPORT_LENGTH = 64
CHUNK_BYTES = 60  # data bytes per write report and per 0x40 reply
ENGINE_CLOCK_HZ = 12e6  # f_SCL = 12 MHz / (divider + 2), the nominal form (notes 8.1)
POWER_UP_DIVIDER = 118  # not in the notes: 100 kHz assumed at power-up

STATUS, GET_DATA, RESET = 0x10, 0x40, 0x70
WRITE, READ, WRITE_RS, READ_RS, WRITE_NO_STOP = 0x90, 0x91, 0x92, 0x93, 0x94
CANCEL_REQUEST, SPEED_REQUEST = 0x10, 0x20
RESET_KEY = bytes([0xAB, 0xCD, 0xEF])

OK, BUSY, DATA_NOT_READY = 0x00, 0x01, 0x41
IDLE, START_TIMEOUT, ADDRESS_NACK = 0x00, 0x12, 0x25
WRITING, NO_STOP_DONE, READING, READ_MORE, READ_LAST, STOP_TIMEOUT = 0x40, 0x45, 0x50, 0x54, 0x55, 0x62
TIMEOUT_STATES = (START_TIMEOUT, 0x17, 0x23, 0x44, 0x52, STOP_TIMEOUT)
NACK_FLAG = 0x40  # status byte 20 bit 6: the target did not ACK its address


class MCP2221ASim:
    vendor_id = VENDOR_ID
    product_id = PRODUCT_ID
    numbered_reports = False
    report_length = REPORT_LENGTH
    release_number = 0x0100  # not in the notes
    manufacturer = "Microchip Technology Inc."  # descriptor strings: not in the notes
    product = "MCP2221 USB-I2C/UART Combo"
    hid_interface = 2  # after the CDC pair (0, 1); not in the notes

    def __init__(self, wire: I2CWire, clock: Clock, serial: str = "0001234567"):
        self.wire = wire
        self.clock = clock
        self.serial_number = serial
        self.path = b""
        self.commands: list[bytes] = []  # every report received, for tests
        self.power_on()

    def power_on(self) -> None:
        self.divider = POWER_UP_DIVIDER
        self.state = IDLE
        self.nack = False
        self.busy_until = 0.0  # the bus transfer in progress ends then
        self.after = IDLE  # the state once it has ended
        self.pending: tuple[int, int, int] | None = None  # a multi-report write: (command, length, address)
        self.written = bytearray()
        self.open_message: Message | None = None  # after 0x94: the write waiting for its repeated START
        self.read_data = b""
        self.read_start = 0.0
        self.fetched = 0
        self.requested = 0
        self.transferred = 0
        self.address8 = 0

    def on_open(self) -> list[bytes]:
        return []

    # --- time -----------------------------------------------------------------------------------------
    @property
    def speed_hz(self) -> float:
        return ENGINE_CLOCK_HZ / (self.divider + 2)

    def _now(self) -> float:
        return self.clock.now()

    def _run(self, bits: int, during: int, after: int) -> None:
        self.busy_until = self._now() + bits / self.speed_hz
        self.state, self.after = during, after

    def _settle(self) -> None:
        if self.state in (WRITING, READING) and self._now() >= self.busy_until:
            self.state = self.after

    # --- reports ----------------------------------------------------------------------------------------
    def on_report(self, report: bytes) -> list[bytes]:
        self.commands.append(report)
        self._settle()
        command = report[0]
        if command == RESET:
            if report[1:4] == RESET_KEY:
                self.power_on()  # no reply; the device enumerates again
            return []
        handlers = {STATUS: self._status, GET_DATA: self._get_data, WRITE: self._write, WRITE_RS: self._write,
                    WRITE_NO_STOP: self._write, READ: self._read, READ_RS: self._read}
        if command not in handlers:
            raise ValueError(f"MCP2221A command 0x{command:02X} is not modelled")
        reply = bytearray(REPORT_LENGTH)
        reply[0] = command
        handlers[command](report, reply)
        return [bytes(reply)]

    def on_set_feature(self, report: bytes) -> bool:
        return False  # the MCP2221A has no feature reports in the notes

    def on_get_feature(self, report_id: int) -> bytes | None:
        return None

    def _status(self, report: bytes, reply: bytearray) -> None:
        if report[2] == CANCEL_REQUEST:
            reply[2] = self._cancel()
        if report[3] == SPEED_REQUEST:
            if self.state in (WRITING, READING):
                reply[3] = 0x21  # not set: a transfer is in progress
            else:
                self.divider = report[4]
                reply[3], reply[4] = 0x20, self.divider
        reply[8] = self.state
        reply[9:11] = self.requested.to_bytes(2, "little")
        reply[11:13] = self.transferred.to_bytes(2, "little")
        reply[13] = len(self.read_data) - self.fetched
        reply[14] = self.divider
        reply[16:18] = self.address8.to_bytes(2, "little")
        reply[20] = NACK_FLAG if self.nack else 0
        reply[22] = 1  # SCL as read from the pin
        reply[23] = 0 if self.wire.sda_stuck_low else 1  # SDA
        reply[46:48] = b"A6"  # hardware / firmware revision characters: not in the notes
        reply[48:50] = b"12"

    def _cancel(self) -> int:
        if self.state == IDLE and self.open_message is None:
            self.state = STOP_TIMEOUT  # the notes' quirk: cancelling an idle engine wedges it
            return 0x11  # the engine was already idle
        if self.open_message is not None:
            self.open_message.end()  # the STOP the cancel sends ends the held write
        self.state = IDLE
        self.nack = False
        self.pending, self.open_message = None, None
        self.read_data, self.fetched = b"", 0
        return 0x10  # marked for cancellation

    def _refuse(self, command: int) -> bool:
        """Whether a transfer command must be answered busy now."""
        if self.state in (WRITING, READING) or self.state in TIMEOUT_STATES:
            return True  # a transfer under way, or an engine that timed out and waits for Cancel
        if self.open_message is not None and command not in (WRITE_RS, READ_RS):
            return True  # after 0x94 only a repeated START may follow
        return self.state in (READ_MORE, READ_LAST)  # read data not fetched yet

    def _write(self, report: bytes, reply: bytearray) -> None:
        command, length, address8 = report[0], int.from_bytes(report[1:3], "little"), report[3]
        reply[2] = self.state
        if self.pending != (command, length, address8) and self._refuse(command):
            reply[1] = BUSY
            return
        if self.pending != (command, length, address8):
            self.pending, self.written = (command, length, address8), bytearray()
        self.written += report[4:4 + min(CHUNK_BYTES, length - len(self.written))]
        if len(self.written) < length:
            return  # more reports of this write follow
        self.pending = None
        self._begin(address8, length)
        try:
            message = self._address(address8, read=False)
        except (WireNack, WireStuck):
            return
        for byte in self.written:
            message.take(byte)
        bits = I2CWire.bits(length, 0)
        if command == WRITE_NO_STOP:
            self.open_message = message  # ended by the repeated START of the next command
            self._run(bits - 1, WRITING, NO_STOP_DONE)
        else:
            message.end()
            self._run(bits, WRITING, IDLE)
        self.transferred = length

    def _read(self, report: bytes, reply: bytearray) -> None:
        command, length, address8 = report[0], int.from_bytes(report[1:3], "little"), report[3]
        reply[2] = self.state
        if self._refuse(command):
            reply[1] = BUSY
            return
        self._begin(address8, length)
        try:
            message = self._address(address8, read=True)
        except (WireNack, WireStuck):
            return
        self.read_data, self.fetched, self.read_start = message.give(length), 0, self._now()
        message.end()
        self._run(I2CWire.bits(0, length), READING, READ_LAST if self.read_data else IDLE)
        self.transferred = len(self.read_data)

    def _begin(self, address8: int, length: int) -> None:
        """A new transfer: its bookkeeping, and the repeated START ending a 0x94 write."""
        if self.open_message is not None:
            self.open_message.end()
            self.open_message = None
        self.address8, self.requested, self.transferred, self.nack = address8, length, 0, False
        self.read_data, self.fetched = b"", 0

    def _address(self, address8: int, read: bool) -> Message:
        """The address phase; a NACK or a stuck bus sets the engine's state and is raised on."""
        try:
            return self.wire.start(address8 >> 1, read)  # the command, not bit 0, sets the direction
        except WireNack:
            self.nack = True
            self._run(I2CWire.bits(0, 0), WRITING, ADDRESS_NACK)
            raise
        except WireStuck:
            self.state = START_TIMEOUT
            raise

    def _get_data(self, report: bytes, reply: bytearray) -> None:
        reply[2] = self.state
        if self.state == ADDRESS_NACK or not self.read_data:
            return  # [1]=0: state 0x25 says NACK; state 0 with count 0 says there is nothing
        end = min(self.fetched + CHUNK_BYTES, len(self.read_data))
        on_chip = self._bytes_clocked_in()
        if on_chip < end:
            reply[1] = DATA_NOT_READY
            return
        chunk = self.read_data[self.fetched:end]
        self.fetched = end
        last = end == len(self.read_data) and on_chip >= len(self.read_data)
        reply[2] = READ_LAST if last else READ_MORE
        reply[3] = len(chunk)
        reply[4:4 + len(chunk)] = chunk
        if last:
            self.state, self.read_data, self.fetched = IDLE, b"", 0
        else:
            self.state = READ_MORE

    def _bytes_clocked_in(self) -> int:
        """Read bytes already on the chip: the address byte first, then 9 clocks per data byte."""
        clocks = (self._now() - self.read_start) * self.speed_hz
        return max(0, min(len(self.read_data), int((clocks - 10) // 9)))
