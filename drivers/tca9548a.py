"""TI TCA9548A / NXP PCA9548A 8-channel I2C switch, and a bus wrapper that selects a channel per transfer.

    switch = TCA9548A(bus, 0x70, name="mux0")
    dut_bus = MuxedBus(bus, 0x70, channel=3, name="mux0")   # give dut_bus to MMC5983MA, TMP117...
    MMC5983MA(dut_bus, 0x30, name="dut4")

Facts (hardware-notes 1.5): address 0x70..0x77 (A2A1A0), up to 8 switches and 64 channels on one bus;
one control byte and no register pointer (smbus2 `write_byte(addr, mask)` / `read_byte(addr)`), bit n
enables channel n; power-up and RESET leave 0x00 (all channels off).

Policy: at most one channel of all the switches on a physical bus is enabled at any time, so two
identical DUTs (two MMC5983MA at 0x30) can never answer together. Every MuxedBus on the same bus object
shares one lock and one record of each switch's control byte: the channel is written only when it is not
already selected, and read back after every write. A switch that does not answer or reads back another
byte is reported as a fault of the switch (DeviceNotFound / ProtocolError naming the switch), never of the
DUT behind it; the switch's byte is then unknown and written again at the next transfer.

A switch whose state is unknown (never written by this process) is switched off before another switch's
channel is enabled, so a channel left on by an earlier run cannot collide. With the Linux kernel driver
(i2c-mux-pca954x) bound, each channel is its own /dev/i2c-N: use that bus directly, not MuxedBus.
"""

from __future__ import annotations

import errno
import logging
import threading
import weakref
from typing import Any

from drivers.base import Device
from drivers.errors import DeviceError, DeviceNotFound, DeviceTimeout, OptionError, ProtocolError

log = logging.getLogger("magrig.drivers.tca9548a")

# --- register map: one control byte ---------------------------------------------------------------------
ADDRESSES = range(0x70, 0x78)  # 0x70 + A2A1A0
CHANNELS = 8  # bit n of the control byte enables channel n
POWER_UP_CONTROL = 0x00  # all channels disabled after power-up or RESET
NACK_ERRNOS = (errno.EREMOTEIO, errno.ENXIO)  # ENXIO from some adapters (an MCP2221 bridge)


def channel_mask(channel: int) -> int:
    """Control byte enabling exactly `channel` (0..7)."""
    if channel not in range(CHANNELS):
        raise OptionError(f"I2C switch channel {channel!r}: must be 0..{CHANNELS - 1}")
    return 1 << channel


def check_address(address: int) -> None:
    if address not in ADDRESSES:
        raise OptionError(f"I2C switch address 0x{address:02X}: a TCA9548A answers at 0x70..0x77")


class TCA9548A:
    """One switch at one address. Not locked itself: MuxedBus calls it under the bus lock."""

    def __init__(self, bus: Any, address: int = 0x70, *, name: str | None = None):
        check_address(address)
        self.bus = bus
        self.address = address
        self.name = name or f"i2c switch 0x{address:02X}"
        self.control: int | None = None  # last byte written and read back; None: unknown
        self.bank: _PhysicalBus | None = None  # the bus record that selects through it (MuxedBus)

    def write_control(self, value: int) -> None:
        """Write the control byte and verify it by reading it back."""
        self._unknown()  # until the read-back agrees
        try:  # straight to the bus: every switch change of a many-DUT sample comes through here
            self.bus.write_byte(self.address, value)
        except OSError as exc:
            raise self._fault(exc, f"write control byte 0x{value:02X}") from exc
        got = self.read_control()
        if got != value:
            raise ProtocolError(
                self.name, f"write control byte 0x{value:02X}",
                f"switch at 0x{self.address:02X} read back 0x{got:02X}: a fault of the I2C switch, "
                "not of the device behind it",
            )
        self.control = value
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s: control 0x%02X", self.name, value, extra={"device": self.name})

    def read_control(self) -> int:
        try:
            return self.bus.read_byte(self.address)
        except OSError as exc:
            raise self._fault(exc, "read control byte") from exc

    def select(self, channel: int) -> None:
        """Enable `channel` alone (written only when it is not known to be selected already)."""
        mask = channel_mask(channel)
        if self.control != mask:
            self.write_control(mask)

    def disable(self) -> None:
        """All channels off (the power-up state); written only when not known to be off already."""
        if self.control != POWER_UP_CONTROL:
            self.write_control(POWER_UP_CONTROL)

    def _unknown(self) -> None:
        """Forget the control byte, and the bus record's selection made through it."""
        self.control = None
        if self.bank is not None:
            self.bank.selected = None

    def _fault(self, exc: OSError, what: str) -> DeviceError:
        """A failed transfer to the switch, as the switch's fault; its byte is then unknown."""
        self._unknown()
        where = f"switch at 0x{self.address:02X}"
        if exc.errno in NACK_ERRNOS:
            detail = f"no ACK from the {where}: a fault of the I2C switch, not of the device behind it"
            return DeviceNotFound(self.name, what, detail)
        if exc.errno == errno.ETIMEDOUT:
            return DeviceTimeout(self.name, what, f"bus timeout at the {where}")
        return DeviceError(self.name, what, f"I2C error at the {where}: {exc}")


def identify(bus: Any, address: int) -> str | None:
    """For bus scans (on a bus nothing else is using): a switch reads back the control byte written to
    it. Writes 0x00 (every channel off, the power-up state); None when the chip there does not read it
    back. Transfer errors (OSError) are the caller's to judge."""
    before = bus.read_byte(address)
    bus.write_byte(address, POWER_UP_CONTROL)
    if bus.read_byte(address) != POWER_UP_CONTROL:
        return None
    return f"TCA9548A/PCA9548A I2C switch (control byte read back; was 0x{before:02X}, now all channels off)"


class _PhysicalBus:
    """What every MuxedBus on one bus object shares: the lock and the switches by address."""

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.switches: dict[int, TCA9548A] = {}
        # (address, mask) the last select() left as the one enabled channel of all the switches; any
        # control byte written or lost since forgets it
        self.selected: tuple[int, int] | None = None

    def switch(self, bus: Any, address: int, name: str | None) -> TCA9548A:
        with self.lock:
            found = self.switches.get(address)
            if found is None:
                found = self.switches[address] = TCA9548A(bus, address, name=name)
                found.bank = self
            return found

    def select(self, address: int, mask: int) -> None:
        """Enable the channels of `mask` (one bit) of one switch, every other switch off first (call under
        the lock). Nothing is written where the byte is known to be right already."""
        if self.selected == (address, mask):  # nothing written or lost since this very selection
            return
        for other in self.switches.values():
            if other.control != POWER_UP_CONTROL and other.address != address:
                other.write_control(POWER_UP_CONTROL)
        target = self.switches[address]
        if target.control != mask:
            target.write_control(mask)
        self.selected = (address, mask)


_BUSES: weakref.WeakKeyDictionary[Any, _PhysicalBus] = weakref.WeakKeyDictionary()
_BUSES_LOCK = threading.Lock()


def _physical(bus: Any) -> _PhysicalBus:
    with _BUSES_LOCK:
        shared = _BUSES.get(bus)
        if shared is None:
            shared = _BUSES[bus] = _PhysicalBus()
        return shared


def bus_lock(bus: Any) -> threading.RLock:
    """The lock that MuxedBus holds on `bus` for each switch-select-and-transfer."""
    return _physical(bus).lock


def switch_on(bus: Any, address: int, name: str | None = None) -> TCA9548A:
    """The one TCA9548A object for `address` on `bus` (created on first use; `name` applies then)."""
    return _physical(bus).switch(bus, address, name)


def disable_all(bus: Any) -> None:
    """Every known switch on `bus` off (safe state): all tried, the first failure raised afterwards."""
    shared = _physical(bus)
    first: DeviceError | None = None
    with shared.lock:
        for switch in shared.switches.values():
            try:
                switch.write_control(POWER_UP_CONTROL)
            except DeviceError as exc:
                first = first or exc
    if first is not None:
        raise first


class MuxedBus:
    """The smbus2 methods our drivers use, each preceded by selecting one switch channel.

    Hand it to a driver in place of the bus. The bus object itself is shared and never closed here.
    """

    def __init__(self, bus: Any, address: int, channel: int, *, name: str | None = None):
        self._mask = channel_mask(channel)  # checked now, not at the first transfer
        self.bus = bus
        self.channel = channel
        self._shared = _physical(bus)
        self._lock = self._shared.lock
        self.switch = self._shared.switch(bus, address, name)
        self._address = self.switch.address

    def __repr__(self) -> str:
        return f"MuxedBus({self.switch.name}, channel {self.channel})"

    # Each transfer selects its channel and goes on under the bus lock, written out per method (no closure
    # per transfer: these are the hot path of a many-DUT campaign).
    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        with self._lock:
            self._shared.select(self._address, self._mask)
            return self.bus.read_byte_data(i2c_addr, register, force)

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        with self._lock:
            self._shared.select(self._address, self._mask)
            self.bus.write_byte_data(i2c_addr, register, value, force)

    def read_word_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        with self._lock:
            self._shared.select(self._address, self._mask)
            return self.bus.read_word_data(i2c_addr, register, force)

    def write_word_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        with self._lock:
            self._shared.select(self._address, self._mask)
            self.bus.write_word_data(i2c_addr, register, value, force)

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        with self._lock:
            self._shared.select(self._address, self._mask)
            return self.bus.read_i2c_block_data(i2c_addr, register, length, force)

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: list[int], force: bool | None = None
    ) -> None:
        with self._lock:
            self._shared.select(self._address, self._mask)
            self.bus.write_i2c_block_data(i2c_addr, register, data, force)

    def read_byte(self, i2c_addr: int, force: bool | None = None) -> int:
        with self._lock:
            self._shared.select(self._address, self._mask)
            return self.bus.read_byte(i2c_addr, force)

    def write_byte(self, i2c_addr: int, value: int, force: bool | None = None) -> None:
        with self._lock:
            self._shared.select(self._address, self._mask)
            self.bus.write_byte(i2c_addr, value, force)

    def close(self) -> None:
        """Nothing to release: the physical bus belongs to whoever opened it."""


class SwitchBank(Device):
    """The switches of one bus as one station device: connect() checks that each answers (a fault
    named as the switch's), safe_state() switches every channel of every switch off (the end of a run).

        bank = SwitchBank(bus, {0x70: "i2c-1 switch 0x70", 0x71: "i2c-1 switch 0x71"}, name="i2c-1 switches")
    """

    kind = "i2c_switch"

    def __init__(self, bus: Any, switches: dict[int, str], *, name: str, clock=None):
        super().__init__(name, clock)
        self.bus = bus
        self.switches = [switch_on(bus, address, label) for address, label in switches.items()]

    def connect(self) -> None:
        with bus_lock(self.bus):
            for switch in self.switches:
                switch.read_control()

    def read(self) -> dict[str, int | None]:
        """{switch name: control byte as last written and verified (None: unknown)}."""
        return {switch.name: switch.control for switch in self.switches}

    def describe(self) -> dict:
        return {**super().describe(), "model": "TCA9548A",
                "switches": {s.name: f"0x{s.address:02X}" for s in self.switches}}

    def safe_state(self) -> None:
        """Every channel off. Never raises (a dead switch is logged)."""
        try:
            disable_all(self.bus)
        except DeviceError as exc:
            log.warning("%s: channels not confirmed off: %s", self.name, exc, extra={"device": self.name})
