"""What the three USB-to-I2C bridge transports share: the smbus2 `SMBus` methods the drivers, the switch
(drivers/tca9548a.py) and the bus scan use, each made of one I2C transfer a bridge performs.

    bus = MCP2221Bus("0001234567", speed_hz=100_000, clock=clock)   # or CP2112Bus, FT232HBus
    bus.read_i2c_block_data(0x30, 0x00, 7)     # START 0x30+W, 0x00, Sr 0x30+R, 7 bytes, STOP
    bus.write_byte(0x70, 0x08)                 # a switch's control byte
    bus.close()

A bridge implements `_transfer(address, write: bytes, read_length) -> bytes` (the write, then with a
repeated START the read; read_length 0: no read) and `_recover()` (free the bus, or reopen the USB
device). Errors, the same for every bridge:

- no ACK at the address: OSError(errno.EREMOTEIO, "Remote I/O error"), what smbus2 raises, at once and
  without retries (the drivers and the bus scan decide what a missing chip means);
- the bridge missing at open: DeviceNotFound naming the kind and the serial number or URL;
- a USB device that went away, a stuck bus, an engine that stays busy, a reply that never comes, a
  short read: DeviceNotFound / DeviceTimeout / ProtocolError naming the bridge, after the project's
  bounded retries (drivers/transports/retry.py) with `_recover()` between tries.

Raw frames (HID reports, MPSSE batches) are logged at DEBUG on "magrig.transport.<kind>", as the other
transports log theirs (`rig --debug` shows them).
"""

from __future__ import annotations

import errno
import logging
from typing import TypeVar

from drivers.clock import Clock, RealClock
from drivers.errors import DeviceError
from drivers.transports.retry import with_retries

T = TypeVar("T")
BLOCK_MAX_BYTES = 32  # the SMBus block limit smbus2 keeps (I2C_SMBUS_BLOCK_MAX); the drivers stay within it
TRIES = 3
BACKOFF_S = 0.002
SPEED_RANGE_HZ = (10_000, 400_000)  # what all three bridges can clock (CP2112: 10-400 kHz)


def nack_error() -> OSError:
    """What smbus2 raises when no chip ACKs the address (Linux i2c-dev: EREMOTEIO)."""
    return OSError(errno.EREMOTEIO, "Remote I/O error")


def hex_bytes(data: bytes) -> str:
    return data.hex(" ") or "-"


def _byte(value: int) -> int:
    if not 0 <= value <= 0xFF:
        raise ValueError(f"byte value {value} out of range 0..255")
    return value


def _block(length: int) -> int:
    if not 1 <= length <= BLOCK_MAX_BYTES:
        raise ValueError(f"I2C block of {length} bytes: must be 1..{BLOCK_MAX_BYTES}")
    return length


class BridgeBus:
    """The smbus2 subset on top of one bridge. Subclasses set `kind` and implement `_transfer`,
    `_recover` and `close`; `name` ("mcp2221 0001234567") names the bridge in every error."""

    kind = "bridge"

    def __init__(self, name: str, *, clock: Clock | None = None, tries: int = TRIES,
                 backoff_s: float = BACKOFF_S):
        self.name = name
        self.clock = clock or RealClock()
        self.tries = tries
        self.backoff_s = backoff_s
        self.frame_log = logging.getLogger(f"magrig.transport.{self.kind}")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name})"

    # --- to implement -------------------------------------------------------------------------------
    def _transfer(self, address: int, write: bytes, read_length: int) -> bytes:
        raise NotImplementedError

    def _recover(self) -> None:
        """Between retries: free the bus, or reopen a USB device that went away."""

    def close(self) -> None:
        raise NotImplementedError

    # --- the one path every method takes ------------------------------------------------------------
    def transfer(self, address: int, write: bytes, read_length: int, what: str) -> bytes:
        """One I2C transfer, retried on bridge faults (never on a NACK); `what` names it in errors."""
        if not 0 <= address <= 0x7F:
            raise ValueError(f"I2C address {address} out of range 0..0x7F")
        operation = f"{what} at 0x{address:02X}"

        def attempt() -> bytes:
            data = self._transfer(address, write, read_length)
            if len(data) != read_length:
                raise DeviceError(self.name, "I2C read", f"short read: {len(data)} of {read_length} bytes")
            return data

        return with_retries(attempt, device=self.name, operation=operation, tries=self.tries,
                            backoff_s=self.backoff_s, clock=self.clock, retry_on=(DeviceError,),
                            recover=self._recover)

    def log_frame(self, direction: str, data: bytes) -> None:
        """A raw frame at DEBUG; a report's zero padding is counted, not printed."""
        if self.frame_log.isEnabledFor(logging.DEBUG):
            shown = data.rstrip(b"\x00")
            padding = f" (+{len(data) - len(shown)} zero bytes)" if len(data) - len(shown) > 1 else ""
            if padding == "":
                shown = data
            self.frame_log.debug("%s %s %s%s", self.name, direction, hex_bytes(shown), padding,
                                 extra={"device": self.name})

    # --- smbus2 API (same names and arguments) ------------------------------------------------------
    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self.transfer(i2c_addr, bytes([_byte(register)]), 1, "read register")[0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self.transfer(i2c_addr, bytes([_byte(register), _byte(value)]), 0, "write register")

    def read_word_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        """SMBus words are little-endian: the first byte on the wire is the low byte."""
        return int.from_bytes(self.transfer(i2c_addr, bytes([_byte(register)]), 2, "read word"), "little")

    def write_word_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        data = bytes([_byte(register)]) + int(value & 0xFFFF).to_bytes(2, "little")
        self.transfer(i2c_addr, data, 0, "write word")

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int,
                            force: bool | None = None) -> list[int]:
        return list(self.transfer(i2c_addr, bytes([_byte(register)]), _block(length), "read block"))

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: list[int],
                             force: bool | None = None) -> None:
        _block(len(data))
        self.transfer(i2c_addr, bytes([_byte(register), *(_byte(v) for v in data)]), 0, "write block")

    def read_byte(self, i2c_addr: int, force: bool | None = None) -> int:
        return self.transfer(i2c_addr, b"", 1, "read byte")[0]

    def write_byte(self, i2c_addr: int, value: int, force: bool | None = None) -> None:
        self.transfer(i2c_addr, bytes([_byte(value)]), 0, "write byte")

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def check_speed(kind: str, speed_hz: float) -> None:
    low, high = SPEED_RANGE_HZ
    if not low <= speed_hz <= high:
        raise ValueError(f"{kind}: I2C speed {speed_hz:g} Hz out of range {low}..{high} Hz")
