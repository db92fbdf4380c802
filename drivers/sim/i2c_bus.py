"""A register-level I2C bus with the smbus2 `SMBus` method names and signatures, plus two test doubles.

    bus = FakeSMBus()
    bus.attach(0x30, MMC5983MASim(world, "dut1"))
    bus.nack(0x30, count=2)    # NACK the next 2 transfers to 0x30 (count=None: all, until nack(addr, 0))
    bus.detach(0x30)           # unplug: every transfer raises OSError(121, "Remote I/O error")

Chips implement `on_read(register, length) -> bytes` and `on_write(register, data)`; `RegisterChip`
gives them a byte register file with auto-increment. `RecordingSMBus(inner)` records every transfer
on its way through; `ScriptedSMBus(address, script)` plays a literal transcript, checking each write
and answering each read, so tests can hold drivers to the datasheet's bytes.
"""

from __future__ import annotations

import errno
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

BLOCK_MAX_BYTES = 32


class I2CChip(Protocol):
    def on_read(self, register: int, length: int) -> bytes: ...

    def on_write(self, register: int, data: bytes) -> None: ...


def _nack() -> OSError:
    """What the Linux i2c-dev ioctl raises through smbus2 when no chip ACKs."""
    return OSError(errno.EREMOTEIO, "Remote I/O error")


def _check_byte(value: int) -> None:
    if not 0 <= value <= 0xFF:
        raise ValueError(f"byte value {value} out of range 0..255")


def _check_block(length: int) -> None:
    if length > BLOCK_MAX_BYTES:
        raise ValueError(f"Data length cannot exceed {BLOCK_MAX_BYTES} bytes")


class RegisterChip:
    """A byte-wide register file with auto-increment; subclasses override read_register/write_register
    (and usually call `update()` first to bring time-dependent state up to the world's clock)."""

    def __init__(self) -> None:
        self.registers = bytearray(256)

    def update(self) -> None:
        """Advance conversions to the current time; called before every transfer."""

    def read_register(self, register: int) -> int:
        return self.registers[register]

    def write_register(self, register: int, value: int) -> None:
        self.registers[register] = value

    def on_read(self, register: int, length: int) -> bytes:
        self.update()
        return bytes(self.read_register((register + i) & 0xFF) for i in range(length))

    def on_write(self, register: int, data: bytes) -> None:
        self.update()
        for i, value in enumerate(data):
            self.write_register((register + i) & 0xFF, value)


class FakeSMBus:
    """In-process stand-in for `smbus2.SMBus`: same methods, same argument names, errno 121 on NACK."""

    def __init__(self, bus: int | str | None = None, force: bool = False):
        self.bus = bus
        self.force = force
        self.chips: dict[int, I2CChip] = {}
        self._nacks: dict[int, int | None] = {}  # address -> transfers left to NACK (None: all)

    # --- wiring and fault hooks -------------------------------------------------------------------
    def attach(self, address: int, chip: I2CChip) -> None:
        self.chips[address] = chip

    def detach(self, address: int) -> I2CChip | None:
        """Unplug the chip (returned, so a test can plug the same one back in)."""
        return self.chips.pop(address, None)

    def nack(self, address: int, count: int | None = None) -> None:
        """NACK the next `count` transfers to `address`; None NACKs all of them; 0 heals."""
        if count == 0:
            self._nacks.pop(address, None)
        else:
            self._nacks[address] = count

    def _chip(self, address: int) -> I2CChip:
        if address in self._nacks:
            left = self._nacks[address]
            if left is not None:
                if left <= 1:
                    del self._nacks[address]
                else:
                    self._nacks[address] = left - 1
            raise _nack()
        chip = self.chips.get(address)
        if chip is None:
            raise _nack()
        return chip

    # --- smbus2 API -------------------------------------------------------------------------------
    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._chip(i2c_addr).on_read(register, 1)[0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        _check_byte(value)
        self._chip(i2c_addr).on_write(register, bytes([value]))

    def read_word_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        """SMBus words are little-endian: the first byte on the wire is the low byte."""
        return int.from_bytes(self._chip(i2c_addr).on_read(register, 2), "little")

    def write_word_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self._chip(i2c_addr).on_write(register, int(value & 0xFFFF).to_bytes(2, "little"))

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        _check_block(length)
        return list(self._chip(i2c_addr).on_read(register, length))

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: list[int], force: bool | None = None
    ) -> None:
        _check_block(len(data))
        for value in data:
            _check_byte(value)
        self._chip(i2c_addr).on_write(register, bytes(data))

    def close(self) -> None:
        """Nothing to release."""

    def __enter__(self) -> FakeSMBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class I2CCall:
    """One transfer as seen on the wire: "read" or "write", address, register, the data bytes."""

    op: str
    address: int
    register: int
    data: bytes

    def __str__(self) -> str:
        arrow = "->" if self.op == "read" else "<-"
        return f"{self.op} 0x{self.address:02X} reg 0x{self.register:02X} {arrow} {self.data.hex(' ')}"


class RecordingSMBus:
    """Passes every smbus2 call through to `inner` and records it in `calls` (failed ones too,
    with op "nack")."""

    def __init__(self, inner: FakeSMBus):
        self.inner = inner
        self.calls: list[I2CCall] = []

    @classmethod
    def with_chip(cls, address: int, chip: I2CChip) -> RecordingSMBus:
        """A recorder around a fresh FakeSMBus holding one chip."""
        bus = FakeSMBus()
        bus.attach(address, chip)
        return cls(bus)

    def transcript(self) -> list[tuple[str, int, bytes]]:
        """The calls as (op, register, data), the form ScriptedSMBus and transcript tests use."""
        return [(c.op, c.register, c.data) for c in self.calls]

    def _record(self, op: str, address: int, register: int, run: Callable[[], bytes]) -> bytes:
        try:
            data = run()
        except OSError:
            self.calls.append(I2CCall("nack", address, register, b""))
            raise
        self.calls.append(I2CCall(op, address, register, data))
        return data

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self.read_i2c_block_data(i2c_addr, register, 1)[0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self.write_i2c_block_data(i2c_addr, register, [value])

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        def run() -> bytes:
            return bytes(self.inner.read_i2c_block_data(i2c_addr, register, length))

        return list(self._record("read", i2c_addr, register, run))

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: list[int], force: bool | None = None
    ) -> None:
        def run() -> bytes:
            self.inner.write_i2c_block_data(i2c_addr, register, list(data))
            return bytes(data)

        self._record("write", i2c_addr, register, run)


class ScriptedSMBus:
    """Plays a transcript for one chip: entries ("write", register, bytes) must match the driver's
    write exactly; entries ("read", register, bytes) must match register and length, and answer the
    bytes. Any mismatch raises AssertionError naming the step. Every call lands in `calls`."""

    def __init__(self, address: int, script: list[tuple[str, int, bytes]]):
        self.address = address
        self.script = list(script)
        self.step = 0
        self.calls: list[I2CCall] = []

    def _next(self, op: str, address: int, register: int, data: bytes, length: int) -> bytes:
        want = self.script[self.step] if self.step < len(self.script) else None
        if (
            address != self.address or want is None or want[0] != op or want[1] != register
            or len(want[2]) != length or (op == "write" and want[2] != data)
        ):
            raise AssertionError(self._mismatch(op, address, register, data, length))
        self.step += 1
        reply = want[2] if op == "read" else data
        self.calls.append(I2CCall(op, address, register, reply))
        return reply

    def _mismatch(self, op: str, address: int, register: int, data: bytes, length: int) -> str:
        got = f"{op} 0x{register:02X} ({length} bytes{': ' + data.hex(' ') if op == 'write' else ''})"
        if address != self.address:
            return f"step {self.step}: {got} sent to 0x{address:02X}, not 0x{self.address:02X}"
        if self.step >= len(self.script):
            return f"step {self.step}: {got} after the end of the transcript"
        want_op, want_register, want_data = self.script[self.step]
        want = f"{want_op} 0x{want_register:02X} ({len(want_data)} bytes: {want_data.hex(' ')})"
        return f"step {self.step}: expected {want}, got {got}"

    def assert_done(self) -> None:
        left = self.script[self.step:]
        if left:
            raise AssertionError(f"transcript not finished: {len(left)} steps left, next {left[0]}")

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._next("read", i2c_addr, register, b"", 1)[0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self._next("write", i2c_addr, register, bytes([value]), 1)

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        return list(self._next("read", i2c_addr, register, b"", length))

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: list[int], force: bool | None = None
    ) -> None:
        self._next("write", i2c_addr, register, bytes(data), len(data))
