"""Bus and port scans for setting up a station: which I2C addresses answer, on the bus and behind each
channel of each TCA9548A/PCA9548A switch, and which serial devices answer on a line, each with what it is.

    scan = scan_i2c(bus)              # an smbus2.SMBus, or a simulated bus with the same methods
    scan.found -> [Found(address, switch, channel, what)]; scan.notes -> ["0x70: ..."]
    found = scan_serial(line, device_ids=range(99), timeout_s=0.05)   # -> [SerialFound(id, baud, info)]

I2C presence is asked as i2cdetect asks it by default: an SMBus quick write, except at 0x30-0x37 and
0x50-0x5F where a quick write can set an EEPROM's write protection, so a one-byte read is used there; an
adapter without quick writes (a CP2112) is asked by one-byte reads everywhere. A chip that answers is
then identified by the drivers' own identification registers (each spec's I2cProbe: product id, id
bytes, device id), read without writing anything. Switches (0x70-0x77) are recognised by reading back
the control byte; the main bus is scanned with every switch off, then each channel alone (an address
already seen on the main bus is left out there: it would answer on every channel). The scan ends with
every switch off, the power-up state.

Serial devices are asked by their driver's SerialProbe at each device id, at the line's baud rate, and at
the other rates only when nothing answered.
"""

from __future__ import annotations

import errno
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from drivers import registry, tca9548a
from drivers.errors import DeviceError, DeviceNotFound

SCAN_ADDRESSES = range(0x08, 0x78)  # 7-bit addresses outside the reserved ones
READ_PROBE_RANGES = (range(0x30, 0x38), range(0x50, 0x60))  # where a quick write could set a write protect


@dataclass(frozen=True)
class Found:
    address: int
    what: str  # what the identification registers say, or why nothing more is known
    switch: int | None = None  # behind this switch's channel, or on the bus itself
    channel: int | None = None

    @property
    def where(self) -> str:
        return "bus" if self.switch is None else f"switch 0x{self.switch:02X} channel {self.channel}"


@dataclass
class I2cScan:
    found: list[Found] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def switches(self) -> list[int]:
        return [f.address for f in self.found if f.switch is None and f.address in tca9548a.ADDRESSES
                and f.what.startswith("TCA9548A")]


@dataclass(frozen=True)
class SerialFound:
    device_id: int
    baudrate: int
    info: dict  # model, serial_number, firmware (None where the device did not say)


class _Presence:
    """Asks whether an address answers, the i2cdetect way (module docstring)."""

    def __init__(self, bus: Any):
        self.bus = bus
        self.quick = hasattr(bus, "write_quick")

    def answers(self, address: int) -> bool:
        try:
            if self.quick and not any(address in r for r in READ_PROBE_RANGES):
                try:
                    self.bus.write_quick(address)
                    return True
                except OSError as exc:
                    if exc.errno not in (errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL):
                        raise
                    self.quick = False  # this adapter has no quick command: read from now on
            self.bus.read_byte(address)
            return True
        except OSError:  # NACK (EREMOTEIO, ENXIO on an MCP2221, ETIMEDOUT on a CP2112) or any bus error
            return False


def identify(bus: Any, address: int, probes: Iterable[registry.I2cProbe]) -> str:
    """What the chip at `address` says it is, by every probe that names this address."""
    candidates = [p for p in probes if address in p.addresses]
    for probe in candidates:
        try:
            found = probe.identify(bus, address)
        except (OSError, ValueError):  # it does not answer that register read: not this chip
            continue
        if found:
            return found
    if not candidates:
        return "answers; no chip the rig drives lives at this address"
    return "answers, but its identification registers match no chip the rig drives here"


def scan_i2c(bus: Any, addresses: Iterable[int] = SCAN_ADDRESSES,
             probes: list[registry.I2cProbe] | None = None) -> I2cScan:
    """Scan one bus (module docstring). Nothing else may use the bus meanwhile."""
    probes = registry.probes(registry.I2cProbe) if probes is None else probes
    addresses = list(addresses)
    presence = _Presence(bus)
    scan = I2cScan()
    switches = []
    for address in [a for a in addresses if a in tca9548a.ADDRESSES]:
        if not presence.answers(address):
            continue
        what = _switch(bus, address)
        scan.found.append(Found(address, what or "answers at a switch address but does not read back its "
                                                  "control byte: not a TCA9548A, or a faulty one"))
        if what:
            switches.append(address)
    on_bus = {f.address for f in scan.found}
    for address in addresses:
        if address not in on_bus and presence.answers(address):
            scan.found.append(Found(address, identify(bus, address, probes)))
            on_bus.add(address)
    for switch in switches:
        for channel in range(tca9548a.CHANNELS):
            if not _select(bus, switch, tca9548a.channel_mask(channel), scan.notes):
                break
            for address in addresses:
                if address not in on_bus and presence.answers(address):
                    scan.found.append(Found(address, identify(bus, address, probes), switch, channel))
        _select(bus, switch, tca9548a.POWER_UP_CONTROL, scan.notes)
    return scan


def _switch(bus: Any, address: int) -> str | None:
    try:
        return tca9548a.identify(bus, address)
    except OSError:
        return None


def _select(bus: Any, switch: int, mask: int, notes: list[str]) -> bool:
    """Write a switch's control byte and check it; a note when the switch does not keep it."""
    try:
        bus.write_byte(switch, mask)
        if bus.read_byte(switch) == mask:
            return True
        notes.append(f"switch 0x{switch:02X} does not keep control byte 0x{mask:02X}: a fault of the switch")
    except OSError as exc:
        notes.append(f"switch 0x{switch:02X}: no answer writing control byte 0x{mask:02X} ({exc})")
    return False


def scan_serial(line: Any, *, device_ids: Iterable[int] | None = None, timeout_s: float = 0.05,
                baudrates: Iterable[int] | None = None,
                probes: list[registry.SerialProbe] | None = None,
                progress: Callable[[str], None] | None = None) -> list[SerialFound]:
    """Every device that answers on `line` (a drivers.transports.serial.SerialLine), at its baud rate
    first. DeviceError (a port that cannot be opened) propagates: the port itself is the finding."""
    out: list[SerialFound] = []
    for probe in registry.probes(registry.SerialProbe) if probes is None else probes:
        rates = [line.baudrate] + [b for b in (baudrates or probe.baudrates) if b != line.baudrate]
        ids = list(probe.device_ids if device_ids is None else device_ids)
        for baud in rates:
            if baud != line.baudrate:
                line.close_port()
                line.baudrate = baud
            if progress is not None:
                progress(f"{line.port}: ids {ids[0]:02d}..{ids[-1]:02d} at {baud} baud")
            if probe.quiet is not None:
                _quiet(probe, line)
            found = [SerialFound(i, baud, info) for i in ids if (info := _ask(probe, line, i, timeout_s))]
            out += found
            if found:
                break
    return out


def _quiet(probe: registry.SerialProbe, line: Any) -> None:
    try:
        probe.quiet(line)
    except DeviceNotFound:  # the port itself
        raise
    except DeviceError:
        pass  # the ids are asked all the same


def _ask(probe: registry.SerialProbe, line: Any, device_id: int, timeout_s: float) -> dict | None:
    try:
        return probe.identify(line, device_id, timeout_s)
    except DeviceNotFound:  # the port itself
        raise
    except DeviceError as exc:
        return {"model": f"something answers, but not as expected: {exc.detail}", "serial_number": None,
                "firmware": None}
