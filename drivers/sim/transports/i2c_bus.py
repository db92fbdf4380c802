"""A register-level I2C bus with the smbus2 `SMBus` method names and signatures (its test doubles, a
recording and a scripted bus: tests/helpers/smbus_doubles.py).

    bus = FakeSMBus()
    bus.attach(0x30, MMC5983MASim(world, "dut1"))
    bus.nack(0x30, count=2)    # NACK the next 2 transfers to 0x30 (count=None: all, until nack(addr, 0))
    bus.detach(0x30)           # unplug: every transfer raises OSError(121, "Remote I/O error")
    bus.set_faults(0x30, faults)  # a drivers.sim.devices.faults.DeviceFaults: "nack" or "unplug" draws NACK
    mux = bus.add_switch(0x70) # a TCA9548A; mux.attach(3, 0x30, chip) puts a chip behind channel 3
    bus.write_quick(0x30)      # the SMBus quick command of bus scans: only the ACK (or errno 121) tells

A chip behind a switch answers only while its channel is enabled. When several chips answer at one
address (two enabled channels, or a channel and the main bus), every one of them takes each write, and a
read returns the bitwise AND of their bytes: I2C is open-drain (wired-AND), so the master sees a garbled
mix; both chips ACK, so nothing fails loudly. The notes (1.5) only say such chips "share the bus".

Chips implement `on_read(register, length) -> bytes` and `on_write(register, data)`; `RegisterChip`
gives them a byte register file with auto-increment (a one-byte read with no register, `read_byte`,
reads at the auto-incremented pointer).
"""

from __future__ import annotations

import errno
from typing import Any, Protocol

BLOCK_MAX_BYTES = 32


class I2CChip(Protocol):
    def on_read(self, register: int, length: int) -> bytes: ...

    def on_write(self, register: int, data: bytes) -> None: ...


SWITCH_CHANNELS = 8
SWITCH_POWER_UP = 0x00


class I2CSwitchSim:
    """TI TCA9548A / NXP PCA9548A (hardware-notes 1.5): one control byte, no register pointer; bit n
    connects channel n; power-up and RESET give 0x00; reading one byte returns the control byte.

    Fault hooks: `readback = value` (reads return that byte whatever was written; None heals); an absent
    switch is `bus.nack(address)` or `bus.detach(address)`. `reset()` is the RESET pin.
    """

    def __init__(self) -> None:
        # the enabled switches of the bus it sits on (FakeSMBus._enabled), kept up to date from here
        self.enabled_on: dict[I2CSwitchSim, None] | None = None
        self._control = SWITCH_POWER_UP
        self.channels: list[dict[int, I2CChip]] = [{} for _ in range(SWITCH_CHANNELS)]
        self.readback: int | None = None
        self.writes = 0  # control bytes received, for tests and benches

    @property
    def control(self) -> int:
        return self._control

    @control.setter
    def control(self, value: int) -> None:
        self._control = value
        if self.enabled_on is not None:
            if value:
                self.enabled_on[self] = None
            else:
                self.enabled_on.pop(self, None)

    def attach(self, channel: int, address: int, chip: I2CChip) -> None:
        self.channels[channel][address] = chip

    def detach(self, channel: int, address: int) -> I2CChip | None:
        return self.channels[channel].pop(address, None)

    def reset(self) -> None:
        self.control = SWITCH_POWER_UP

    def on_send(self, value: int) -> None:
        self.control = value
        self.writes += 1

    def on_receive(self) -> int:
        return self.control if self.readback is None else self.readback

    def visible(self, address: int) -> list[I2CChip]:
        """The chips at `address` on the enabled channels."""
        control = self.control
        if control & (control - 1) == 0:  # one channel or none: the usual case, looked up directly
            chips = self.channels[control.bit_length() - 1] if control else {}
            return [chips[address]] if address in chips else []
        return [
            chips[address] for n, chips in enumerate(self.channels)
            if self.control >> n & 1 and address in chips
        ]

    # The notes describe only single-byte control transfers: a register-style transfer is not modelled.
    def on_read(self, register: int, length: int) -> bytes:
        raise ValueError("I2C switch: register reads are not described (read one byte: read_byte)")

    def on_write(self, register: int, data: bytes) -> None:
        raise ValueError("I2C switch: register writes are not described (write one byte: write_byte)")


def switch_writes(devices) -> int:
    """Control bytes the simulated switches behind `devices` (a rig's devices: its switch banks list their
    TCA9548A drivers as `switches`) have received so far: for tests and benches that count selections."""
    total = 0
    for dev in devices:
        for switch in getattr(dev, "switches", ()):
            chip = getattr(switch.bus, "chips", {}).get(switch.address)
            total += chip.writes if isinstance(chip, I2CSwitchSim) else 0
    return total


class _Collision:
    """Several chips answering at one address: writes reach all, reads are the wired-AND of their bytes."""

    def __init__(self, chips: list):
        self.chips = chips

    def on_read(self, register: int, length: int) -> bytes:
        replies = [chip.on_read(register, length) for chip in self.chips]
        return bytes(_wired_and(column) for column in zip(*replies, strict=True))

    def on_write(self, register: int, data: bytes) -> None:
        for chip in self.chips:
            chip.on_write(register, data)

    def on_send(self, value: int) -> None:
        for chip in self.chips:
            _send(chip, value)

    def on_receive(self) -> int:
        return _wired_and([_receive(chip) for chip in self.chips])


def _wired_and(values) -> int:
    out = 0xFF
    for v in values:
        out &= v
    return out


def _send(chip: object, value: int) -> None:
    """A plain one-byte write (smbus2 write_byte): only chips without a register pointer model it."""
    if not hasattr(chip, "on_send"):
        raise ValueError(f"{type(chip).__name__}: one-byte writes without a register are not modelled")
    chip.on_send(value)  # type: ignore[attr-defined]


def _receive(chip: object) -> int:
    if not hasattr(chip, "on_receive"):
        raise ValueError(f"{type(chip).__name__}: one-byte reads without a register are not modelled")
    return chip.on_receive()  # type: ignore[attr-defined]


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
        self.pointer = 0  # where a plain one-byte read (no register written first) reads

    def update(self) -> None:
        """Advance conversions to the current time; called before every transfer."""

    def read_register(self, register: int) -> int:
        return self.registers[register]

    def write_register(self, register: int, value: int) -> None:
        self.registers[register] = value

    def on_read(self, register: int, length: int) -> bytes:
        self.update()
        self.pointer = (register + length) & 0xFF
        if register + length <= len(self.registers):  # no wrap: the usual burst
            return bytes(map(self.read_register, range(register, register + length)))
        return bytes(self.read_register((register + i) & 0xFF) for i in range(length))

    def on_write(self, register: int, data: bytes) -> None:
        self.update()
        self.pointer = (register + len(data)) & 0xFF
        for i, value in enumerate(data):
            self.write_register((register + i) & 0xFF, value)

    def on_receive(self) -> int:
        """A one-byte read without a register (smbus2 read_byte): the register at the auto-incrementing
        pointer, which moves on."""
        return self.on_read(self.pointer, 1)[0]


class FakeSMBus:
    """In-process stand-in for `smbus2.SMBus`: same methods, same argument names, errno 121 on NACK."""

    def __init__(self, bus: int | str | None = None, force: bool = False):
        self.bus = bus
        self.force = force
        self.chips: dict[int, I2CChip] = {}
        # those with a channel on, looked at on every transfer (each switch keeps it up to date)
        self._enabled: dict[I2CSwitchSim, None] = {}
        self._nacks: dict[int, int | None] = {}  # address -> transfers left to NACK (None: all)
        self._faults: dict[int, Any] = {}  # address -> fault schedule, drawn once per transfer

    # --- wiring and fault hooks -------------------------------------------------------------------
    def attach(self, address: int, chip: I2CChip) -> None:
        self.chips[address] = chip
        if isinstance(chip, I2CSwitchSim):
            chip.enabled_on = self._enabled
            chip.control = chip.control  # listed as enabled if it is

    def detach(self, address: int) -> I2CChip | None:
        """Unplug the chip (returned, so a test can plug the same one back in)."""
        chip = self.chips.pop(address, None)
        if isinstance(chip, I2CSwitchSim):
            self._enabled.pop(chip, None)
            chip.enabled_on = None
        return chip

    def nack(self, address: int, count: int | None = None) -> None:
        """NACK the next `count` transfers to `address`; None NACKs all of them; 0 heals."""
        if count == 0:
            self._nacks.pop(address, None)
        else:
            self._nacks[address] = count

    def set_faults(self, address: int, faults) -> None:
        """Draw a fault of `faults` (drivers.sim.devices.faults.DeviceFaults) for every transfer to
        `address`."""
        self._faults[address] = faults

    def chip_at(self, address: int):
        """The chip that acknowledges `address` now, NACK faults applied (OSError 121 when none does):
        how a bridge simulator (drivers/sim/transports/i2c_wire.py) reaches the same chips."""
        return self._chip(address)

    def _chip(self, address: int):
        if not self._faults and not self._nacks:  # no fault hook set: the usual case, looked up directly
            found = self._answering(address)
            if len(found) == 1:
                return found[0]
            if not found:
                raise _nack()
            return _Collision(found)
        faults = self._faults.get(address)
        if faults is not None and faults.draw() in ("nack", "unplug"):
            raise _nack()
        if address in self._nacks:
            left = self._nacks[address]
            if left is not None:
                if left <= 1:
                    del self._nacks[address]
                else:
                    self._nacks[address] = left - 1
            raise _nack()
        found = self._answering(address)
        if not found:
            raise _nack()
        return found[0] if len(found) == 1 else _Collision(found)

    def _answering(self, address: int) -> list:
        """Every chip that ACKs `address`: on the main bus, and behind enabled switch channels."""
        chip = self.chips.get(address)
        found = [] if chip is None else [chip]
        for switch in self._enabled:  # a switch with every channel off hides everything behind it
            control = switch.control
            if control & (control - 1) == 0:  # one channel: looked up directly
                chip = switch.channels[control.bit_length() - 1].get(address)
                if chip is not None:
                    found.append(chip)
            else:
                found += switch.visible(address)
        return found

    def add_switch(self, address: int) -> I2CSwitchSim:
        """A TCA9548A on the main bus at `address` (0x70..0x77), all channels off."""
        switch = I2CSwitchSim()
        self.attach(address, switch)
        return switch

    # --- smbus2 API -------------------------------------------------------------------------------
    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._chip(i2c_addr).on_read(register, 1)[0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        _check_byte(value)
        self._chip(i2c_addr).on_write(register, bytes([value]))

    def read_byte(self, i2c_addr: int, force: bool | None = None) -> int:
        return _receive(self._chip(i2c_addr))

    def write_quick(self, i2c_addr: int, force: bool | None = None) -> None:
        """SMBus quick command: the address alone; only the ACK says anything (bus scans)."""
        self._chip(i2c_addr)

    def write_byte(self, i2c_addr: int, value: int, force: bool | None = None) -> None:
        _check_byte(value)
        _send(self._chip(i2c_addr), value)

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
