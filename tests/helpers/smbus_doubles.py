"""Test doubles with the smbus2 `SMBus` methods: `RecordingSMBus(inner)` records every transfer on its way
through; `ScriptedSMBus(address, script)` plays a literal transcript, checking each write and answering
each read, so tests can hold drivers to the datasheet's bytes."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from drivers.sim.transports.i2c_bus import FakeSMBus, I2CChip


@dataclass(frozen=True)
class I2CCall:
    """One transfer as seen on the wire: "read" or "write", address, register (None for a one-byte
    transfer without register pointer, smbus2 read_byte / write_byte), the data bytes."""

    op: str
    address: int
    register: int | None
    data: bytes

    def __str__(self) -> str:
        arrow = "->" if self.op == "read" else "<-"
        reg = "-" if self.register is None else f"0x{self.register:02X}"
        return f"{self.op} 0x{self.address:02X} reg {reg} {arrow} {self.data.hex(' ')}"


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

    def transcript(self) -> list[tuple[str, int | None, bytes]]:
        """The calls as (op, register, data), the form ScriptedSMBus and transcript tests use."""
        return [(c.op, c.register, c.data) for c in self.calls]

    def _record(self, op: str, address: int, register: int | None, run: Callable[[], bytes]) -> bytes:
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

    def read_byte(self, i2c_addr: int, force: bool | None = None) -> int:
        return self._record("read", i2c_addr, None, lambda: bytes([self.inner.read_byte(i2c_addr)]))[0]

    def write_byte(self, i2c_addr: int, value: int, force: bool | None = None) -> None:
        def run() -> bytes:
            self.inner.write_byte(i2c_addr, value)
            return bytes([value])

        self._record("write", i2c_addr, None, run)


class ScriptedSMBus:
    """Plays a transcript for one chip: entries ("write", register, bytes) must match the driver's
    write exactly; entries ("read", register, bytes) must match register and length, and answer the
    bytes. Any mismatch raises AssertionError naming the step. Every call lands in `calls`."""

    def __init__(self, address: int, script: list[tuple[str, int, bytes]]):
        self.address = address
        self.script = list(script)
        self.step = 0
        self.calls: list[I2CCall] = []

    def _next(self, op: str, address: int, register: int | None, data: bytes, length: int) -> bytes:
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

    def _mismatch(self, op: str, address: int, register: int | None, data: bytes, length: int) -> str:
        got = f"{op} {_reg(register)} ({length} bytes{': ' + data.hex(' ') if op == 'write' else ''})"
        if address != self.address:
            return f"step {self.step}: {got} sent to 0x{address:02X}, not 0x{self.address:02X}"
        if self.step >= len(self.script):
            return f"step {self.step}: {got} after the end of the transcript"
        want_op, want_register, want_data = self.script[self.step]
        want = f"{want_op} {_reg(want_register)} ({len(want_data)} bytes: {want_data.hex(' ')})"
        return f"step {self.step}: expected {want}, got {got}"

    def assert_done(self) -> None:
        left = self.script[self.step:]
        if left:
            raise AssertionError(f"transcript not finished: {len(left)} steps left, next {left[0]}")

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._next("read", i2c_addr, register, b"", 1)[0]

    def read_byte(self, i2c_addr: int, force: bool | None = None) -> int:
        return self._next("read", i2c_addr, None, b"", 1)[0]

    def write_byte(self, i2c_addr: int, value: int, force: bool | None = None) -> None:
        self._next("write", i2c_addr, None, bytes([value]), 1)

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


def _reg(register: int | None) -> str:
    return "(no register)" if register is None else f"0x{register:02X}"
