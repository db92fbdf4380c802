"""The I2C bus as a USB bridge's engine drives it: addressed messages (START or repeated START, address +
R/W, bytes, STOP) played onto the SAME register-level chips a FakeSMBus holds.

    wire = I2CWire(bus)                        # bus: drivers.sim.transports.i2c_bus.FakeSMBus, its chips and
                                               # switches
    wire.transfer(0x30, b"\\x2f", 1)            # write the register pointer, Sr, read one byte -> b"\\x30"
    wire.transfer(0x30, b"\\x09\\x01", 0)        # a register write
    wire.transfer(0x70, b"", 1)                # a plain read (a switch's control byte)
    message = wire.start(0x30, read=False)     # bit by bit (an FT232H): the address phase...
    message.take(0x2F); message.end()          # ...a written byte, then STOP or a repeated START
    I2CWire.bits(1, 1)                         # clock periods that write-then-read takes (timing)

What a chip does with the bytes is what its datasheet gives every register chip here: the first byte
written is the register pointer, the rest are written from it on (auto-increment); a read reads at the
pointer. A chip without a pointer (the TCA9548A switch: `on_send`/`on_receive`) takes one written byte
as its control byte and answers a one-byte read with it (hardware-notes 1.5; longer transfers are not
described, so they raise ValueError). The bus's own NACK and fault hooks (FakeSMBus.nack, set_faults,
detach) apply to every address phase, so a write-then-read meets them twice.

Fault hooks of the wire: `sda_stuck_low = True` (a chip holds SDA low: the bus is never free, no START
can be made); `short_read = n` (the next read message ends after n bytes: the bridge delivers fewer bytes
than asked).
"""

from __future__ import annotations

from drivers.sim.transports.i2c_bus import FakeSMBus

BITS_PER_BYTE = 9  # 8 data bits and the ACK bit
CONDITION_BITS = 1  # a START, a repeated START or a STOP each take about one clock period


class WireNack(Exception):
    """Nothing acknowledged the address; the master ends the transfer with STOP."""

    def __init__(self, address: int):
        super().__init__(f"no ACK at 0x{address:02X}")
        self.address = address


class WireStuck(Exception):
    """SDA is held low: the bus is never free, no START can be made."""


def _pointerless(chip: object) -> bool:
    """A chip without a register pointer (a switch) has `on_send`. Several chips answering at one address
    (FakeSMBus's collision) are judged by the first of them."""
    inner = getattr(chip, "chips", None)
    return hasattr(inner[0] if inner else chip, "on_send")


class Message:
    """One addressed message, from its START (or Sr) to the next Sr or STOP."""

    def __init__(self, wire: I2CWire, chip, address: int, read: bool):
        self.wire = wire
        self.chip = chip
        self.address = address
        self.read = read
        self.written = bytearray()
        self.given = 0

    def take(self, byte: int) -> None:
        """A byte the master writes (the chip ACKs it)."""
        self.written.append(byte)

    def give(self, length: int) -> bytes:
        """The next `length` bytes the chip sends (fewer under a short-read fault)."""
        if _pointerless(self.chip):
            if self.given + length > 1:
                raise ValueError("I2C switch: reads of more than one byte are not described (notes 1.5)")
            data = bytes([self.chip.on_receive()])
        else:
            data = self.chip.on_read(self.chip.pointer, length)
        self.given += length
        cut = self.wire.short_read
        if cut is not None:
            self.wire.short_read = None
            data = data[:cut]
        return data

    def end(self) -> None:
        """STOP or a repeated START: a write message reaches the chip now."""
        if self.read or not self.written:
            return  # a read, or an address alone (SMBus quick write): nothing to store
        if _pointerless(self.chip):
            if len(self.written) > 1:
                raise ValueError("I2C switch: writes of more than one byte are not described (notes 1.5)")
            self.chip.on_send(self.written[0])
        else:
            self.chip.on_write(self.written[0], bytes(self.written[1:]))


class I2CWire:
    def __init__(self, bus: FakeSMBus):
        self.bus = bus
        self.sda_stuck_low = False
        self.short_read: int | None = None
        self.address_phases = 0  # for tests and benches

    @staticmethod
    def bits(write_length: int, read_length: int) -> int:
        """Clock periods of one transfer: START, the address byte, the written bytes, (Sr, the address byte
        again,) the read bytes, STOP; every byte with its ACK bit."""
        bits = CONDITION_BITS + BITS_PER_BYTE * (1 + write_length) + CONDITION_BITS
        if read_length:
            if write_length:
                bits += CONDITION_BITS + BITS_PER_BYTE
            bits += BITS_PER_BYTE * read_length
        return bits

    def start(self, address: int, read: bool) -> Message:
        """START (or Sr) and the address byte. WireNack when nothing acknowledges it, WireStuck while SDA
        is held low."""
        if self.sda_stuck_low:
            raise WireStuck("SDA held low")
        self.address_phases += 1
        try:
            chip = self.bus.chip_at(address)
        except OSError:
            raise WireNack(address) from None
        return Message(self, chip, address, read)

    def transfer(self, address: int, write: bytes, read_length: int) -> bytes:
        """`write` (may be empty), then with a repeated START `read_length` bytes (0: no read), then STOP."""
        data = b""
        if write or not read_length:
            message = self.start(address, read=False)
            for byte in write:
                message.take(byte)
            message.end()
        if read_length:
            message = self.start(address, read=True)
            data = message.give(read_length)
            message.end()
        return data
