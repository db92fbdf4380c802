"""Protocol-level FT232H (USB 0403:6014) in MPSSE mode, for pyftdi's I2cController: the vendor requests
and the bulk byte streams the chip sees, its MPSSE commands decoded down to the SCL/SDA levels they make
(hardware-notes 8.3), and an I2C target state machine reading those levels bit by bit onto the I2C wire
(drivers/sim/transports/i2c_wire.py) with the FakeSMBus chips and switches. It plugs into
drivers/sim/transports/usbfake.py.

    chip = FT232HSim(I2CWire(bus), clock, serial="FT0SIM01")
    backend = FakeUsbBackend(); backend.plug(chip)      # the transport finds it through pyusb

Pins (pyftdi's wiring): SCL = AD0, SDA driven on AD1 and read on AD2, open-drain through drive-zero mode
(0x9E): a pin in that mode pulls low for 0 and lets the pull-up win for 1. A START is SDA falling while
SCL stays high (0x80 commands), a STOP SDA rising while SCL stays high; bits are clocked by 0x11 (bytes
out), 0x13 (bits out: the master's ACK or NACK), 0x20 (bytes in), 0x22 (bits in: the target's ACK). The
target drives SDA low to ACK its address and each written byte, and drives its data bits on reads; a
master NACK ends the read. The line is the AND of every driver (open drain). So with SDA held low
(`wire.sda_stuck_low`) no START is ever seen, every ACK reads as given and every byte as 0x00: the chip
cannot tell, only its pins (0x81) show it.

Commands kept (the notes' list): 0x80/0x82 set, 0x81/0x83 read the low/high byte, 0x11, 0x13, 0x20,
0x22, 0x84/0x85 loopback, 0x86 divisor, 0x87 send immediate, 0x8A/0x8B divide-by-5 off/on, 0x8C/0x8D
3-phase clocking on/off, 0x96/0x97 adaptive clocking, 0x9E drive-zero mask. Others raise ValueError
(not modelled: the notes list no more). Results wait in the chip's buffer; a bulk IN hands them over at
once after 0x87 (or a full packet), else when the latency timer runs out; with nothing to send the chip
sends its two modem status bytes when the latency timer runs out (FTDI AN232B-04; the notes give the 16 ms
default). Every packet starts with those two bytes.

Time on the clock: a high-speed bulk transfer takes a 125 us microframe; each GPIO command about 0.5 us
(what pyftdi assumes); each clocked bit 1.5 MPSSE clock periods with 3-phase clocking, else one; the
MPSSE clock is 6 MHz (divide-by-5 on) or 30 MHz over (divisor + 1).

Not in the notes, and so chosen here: the vendor request codes (as libftdi and pyftdi number them: 0x00
reset/purge, 0x05 modem status, 0x06/0x07 event/error character, 0x09/0x0A latency timer, 0x0B bit mode,
0x0C read pins; others stall), the modem status bytes (0x32 0x60: transmitter empty), the power-up MPSSE
state (divide-by-5 on, divisor 0, no 3-phase, no drive-zero), the descriptor strings, and pins that are
inputs reading high (internal pull-ups). A read the target cannot serve in full (the wire's `short_read`)
leaves the missing bytes out of the chip's buffer: the host gets fewer bytes than it asked for.

Fault hooks: the wire's `sda_stuck_low` and `short_read`, FakeSMBus NACKs, FakeUsbBackend.unplug(chip).
"""

from __future__ import annotations

from usb.core import USBError

from drivers.clock import Clock
from drivers.sim.transports.i2c_wire import I2CWire, Message, WireNack

VENDOR_ID = 0x0403
PRODUCT_ID = 0x6014
BCD_DEVICE = 0x0900  # FT232H
MAX_PACKET = 512  # high-speed bulk endpoints
MICROFRAME_S = 125e-6
GPIO_COMMAND_S = 0.5e-6
MODEM_STATUS = bytes([0x32, 0x60])
RESET_SIO, PURGE_RX, PURGE_TX = 0, 1, 2
MODE_RESET, MODE_MPSSE = 0x00, 0x02
SCL, SDA_OUT, SDA_IN = 0x01, 0x02, 0x04
FIXED_LENGTHS = {0x80: 3, 0x82: 3, 0x81: 1, 0x83: 1, 0x84: 1, 0x85: 1, 0x86: 3, 0x87: 1, 0x8A: 1, 0x8B: 1,
                 0x8C: 1, 0x8D: 1, 0x96: 1, 0x97: 1, 0x9E: 3, 0x13: 3, 0x20: 3, 0x22: 2}


def _length(buf: bytearray, i: int) -> int | None:
    """Bytes of the command at buf[i] (None: not all of it has arrived yet)."""
    op = buf[i]
    if op == 0x11:
        if i + 3 > len(buf):
            return None
        n = 3 + (buf[i + 1] | buf[i + 2] << 8) + 1
    elif op in FIXED_LENGTHS:
        n = FIXED_LENGTHS[op]
    else:
        raise ValueError(f"MPSSE command 0x{op:02X} is not modelled")
    return n if i + n <= len(buf) else None


class _Target:
    """The chips' side of the bus, bit by bit: address, ACKs, written and read bytes."""

    def __init__(self, chip: FT232HSim):
        self.chip = chip
        self.state = "idle"
        self.message: Message | None = None
        self.shift = 0
        self.bits = 0
        self.queue = bytearray()  # read bytes fetched from the chip, not clocked out yet
        self.byte: int | None = None  # the read byte being clocked out (None: nothing to give)
        self.need = False  # the next read byte is fetched at its first clock, when the batch is known
        self.exhausted = False
        self.empty_reads = 0  # read bytes the target had nothing for (short read)

    def start(self) -> None:
        self._end()
        self.state, self.shift, self.bits = "address", 0, 0

    def stop(self) -> None:
        self._end()
        self.state = "idle"

    def _end(self) -> None:
        if self.message is not None:
            self.message.end()
        self.message, self.queue, self.byte, self.need = None, bytearray(), None, False
        self.exhausted = False

    def clock(self, master: int) -> int:
        """One SCL pulse: the SDA line as everyone sees it (wired-AND), and what the target makes of it."""
        line = master & self._drive() & (0 if self.chip.wire.sda_stuck_low else 1)
        self._sample(line)
        return line

    def _drive(self) -> int:
        if self.state == "ack":
            return 0
        if self.state == "read":
            if self.need:
                self.need = False
                self._load()
            return 1 if self.byte is None else self.byte >> (7 - self.bits) & 1
        return 1

    def _sample(self, line: int) -> None:
        state = self.state
        if state in ("address", "write"):
            self.shift, self.bits = (self.shift << 1 | line) & 0xFF, self.bits + 1
            if self.bits == 8:
                self._byte_in()
        elif state == "ack":
            self.state, self.shift, self.bits = ("read" if self.message.read else "write"), 0, 0
            self.need = self.message.read
        elif state == "nack":
            self.state = "ignore"
        elif state == "read":
            self.bits += 1
            if self.bits == 8:
                self.state = "master_ack"
        elif state == "master_ack":
            if line == 0:
                self.state, self.bits, self.need = "read", 0, True
            else:
                self.state = "ignore"  # the master's NACK: the read is over

    def _byte_in(self) -> None:
        if self.state == "write":
            self.message.take(self.shift)
            self.state = "ack"
            return
        try:
            self.message = self.chip.wire.start(self.shift >> 1, read=bool(self.shift & 1))
            self.state = "ack"
        except WireNack:
            self.state = "nack"

    def _load(self) -> None:
        if not self.queue and not self.exhausted:
            wanted = self.chip.reads_ahead()
            self.queue = bytearray(self.message.give(wanted))
            self.exhausted = len(self.queue) < wanted  # a short read: this message gives no more
        self.byte = self.queue.pop(0) if self.queue else None
        self.empty_reads += self.byte is None


class FT232HSim:
    vendor_id = VENDOR_ID
    product_id = PRODUCT_ID
    bcd_device = BCD_DEVICE
    usb_speed = 3  # high speed (pyusb's SPEED_HIGH)

    def __init__(self, wire: I2CWire, clock: Clock, serial: str = "FT0SIM01"):
        self.wire = wire
        self.clock = clock
        self.serial_number = serial
        self.address = 0
        self.batches: list[bytes] = []  # every bulk OUT transfer in MPSSE mode, for tests
        self.power_on()

    def strings(self) -> tuple[str, str, str]:
        return ("FTDI", "Single RS232-HS", self.serial_number)  # not in the notes

    def interfaces(self) -> list[list[tuple[int, int]]]:
        return [[(0x81, MAX_PACKET), (0x02, MAX_PACKET)]]  # bulk IN, bulk OUT

    def power_on(self) -> None:
        self.mode = MODE_RESET
        self.latency_ms = 16
        self.low = [0x00, 0x00]  # value, direction
        self.high = [0x00, 0x00]
        self.divisor, self.div5, self.three_phase, self.drive_zero = 0, True, False, 0
        self.pending = bytearray()  # OUT bytes not yet a whole command
        self.out = bytearray()  # results waiting for the host
        self.flush = False
        self.last_sent = self.clock.now()
        self.target = _Target(self)
        self.ops: list[bytes] = []
        self.at = 0  # the command being run, in self.ops
        self.read_left = 0  # bytes the running 0x20 has still to clock in

    # --- vendor requests ------------------------------------------------------------------------------
    def control_out(self, request: int, value: int, index: int, data: bytes) -> None:
        if request == 0x00:
            if value in (RESET_SIO, PURGE_RX):
                self.pending = bytearray()
            if value in (RESET_SIO, PURGE_TX):
                self.out, self.flush = bytearray(), False
        elif request == 0x09:
            self.latency_ms = value & 0xFF
        elif request == 0x0B:
            self.mode = value >> 8
            self.pending, self.target = bytearray(), _Target(self)
        elif request not in (0x01, 0x02, 0x03, 0x04, 0x06, 0x07):  # UART settings: no effect in MPSSE
            raise USBError("vendor request not modelled (stall)", errno=32)

    def control_in(self, request: int, value: int, index: int, length: int) -> bytes:
        if request == 0x0A:
            return bytes([self.latency_ms])
        if request == 0x0C:
            return bytes([self._pins_low()])
        if request == 0x05:
            return MODEM_STATUS
        raise USBError("vendor request not modelled (stall)", errno=32)

    # --- bulk -----------------------------------------------------------------------------------------
    def bulk_out(self, ep: int, data: bytes) -> int:
        self.clock.sleep(MICROFRAME_S)
        if self.mode != MODE_MPSSE:
            return len(data)  # UART or bit-bang bytes: not modelled, dropped
        self.batches.append(data)
        self.pending += data
        self.ops, i = [], 0
        while i < len(self.pending):
            n = _length(self.pending, i)
            if n is None:
                break
            self.ops.append(bytes(self.pending[i:i + n]))
            i += n
        del self.pending[:i]
        seconds = 0.0
        for at, command in enumerate(self.ops):
            self.at = at
            seconds += self._run(command)
        self.clock.sleep(seconds)
        return len(data)

    def bulk_in(self, ep: int, size: int) -> bytes:
        room = min(size, MAX_PACKET) - len(MODEM_STATUS)
        if (self.out and self.flush) or len(self.out) >= room:
            self.clock.sleep(MICROFRAME_S)
        else:  # held until the latency timer runs out (also a packet of status bytes alone)
            self.clock.sleep(max(MICROFRAME_S, self.last_sent + self.latency_ms / 1000 - self.clock.now()))
        packet = MODEM_STATUS + bytes(self.out[:room])
        del self.out[:room]
        if not self.out:
            self.flush = False
        self.last_sent = self.clock.now()
        return packet

    # --- MPSSE ----------------------------------------------------------------------------------------
    @property
    def bit_s(self) -> float:
        clock_hz = (6e6 if self.div5 else 30e6) / (self.divisor + 1)
        return (1.5 if self.three_phase else 1.0) / clock_hz

    def _run(self, c: bytes) -> float:
        op = c[0]
        if op == 0x80:
            self._set_low(c[1], c[2])
        elif op == 0x82:
            self.high = [c[1], c[2]]
        elif op == 0x81:
            self.out.append(self._pins_low())
        elif op == 0x83:
            self.out.append(self._pins(self.high, 0xFF))
        elif op == 0x11:
            bits = [byte >> (7 - k) & 1 for byte in c[3:] for k in range(8)]
            self._clock(bits)
            return len(bits) * self.bit_s
        elif op == 0x13:
            bits = [c[2] >> (7 - k) & 1 for k in range(c[1] + 1)]
            self._clock(bits)
            return len(bits) * self.bit_s
        elif op == 0x20:
            return self._read_bytes((c[1] | c[2] << 8) + 1)
        elif op == 0x22:
            value = 0
            for line in self._clock([None] * (c[1] + 1)):
                value = (value << 1 | line) & 0xFF
            self.out.append(value)
            return (c[1] + 1) * self.bit_s
        elif op == 0x87:
            self.flush = True
        elif op == 0x86:
            self.divisor = c[1] | c[2] << 8
        elif op in (0x8A, 0x8B):
            self.div5 = op == 0x8B
        elif op in (0x8C, 0x8D):
            self.three_phase = op == 0x8C
        elif op == 0x9E:
            self.drive_zero = c[1] | c[2] << 8
        return GPIO_COMMAND_S if op in (0x80, 0x81, 0x82, 0x83) else 0.0  # 0x84/85, 0x96/97: no effect here

    def _read_bytes(self, count: int) -> float:
        for left in range(count, 0, -1):
            self.read_left = left
            empty = self.target.empty_reads
            value = 0
            for line in self._clock([None] * 8):
                value = (value << 1 | line) & 0xFF
            if self.target.empty_reads == empty:
                self.out.append(value)  # a byte the target had nothing for never reaches the buffer
        self.read_left = 0
        return count * 8 * self.bit_s

    def reads_ahead(self) -> int:
        """Bytes the master will read before its NACK, from the running 0x20 on (in this batch)."""
        count = self.read_left
        for c in self.ops[self.at + 1:]:
            if c[0] == 0x20:
                count += (c[1] | c[2] << 8) + 1
            elif c[0] == 0x13 and c[2] & 0x80:
                break
        return max(1, count)

    # --- pins -----------------------------------------------------------------------------------------
    def _released(self, mask: int, value: int, direction: int) -> int:
        """1 when the pin lets the line go high: an input, or an output at 1 (drive-zero or not)."""
        return 0 if direction & mask and not value & mask else 1

    def _scl(self) -> int:
        return self._released(SCL, *self.low)

    def _sda(self) -> int:
        return self._released(SDA_OUT, *self.low) & (0 if self.wire.sda_stuck_low else 1)

    def _set_low(self, value: int, direction: int) -> None:
        scl, sda = self._scl(), self._sda()
        self.low = [value, direction]
        if scl and self._scl():
            if sda and not self._sda():
                self.target.start()
            elif not sda and self._sda():
                self.target.stop()

    def _clock(self, bits: list[int | None]) -> list[int]:
        """SCL pulses with the master's DO levels (None: DO keeps its level); the lines sampled."""
        value, direction = self.low
        lines = []
        for bit in bits:
            if bit is not None:
                value = value & ~SDA_OUT | (SDA_OUT if bit else 0)
            lines.append(self.target.clock(self._released(SDA_OUT, value, direction)))
        self.low = [value, direction]
        return lines

    def _pins(self, pair: list[int], mask: int) -> int:
        value, direction = pair
        return (value & direction | ~direction) & mask

    def _pins_low(self) -> int:
        line_sda = self._sda()
        pins = self._pins(self.low, 0xF8)
        return pins | self._scl() * SCL | line_sda * SDA_OUT | line_sda * SDA_IN
