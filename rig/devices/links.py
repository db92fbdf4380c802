"""Open the link a device's driver is built on, from the station's transport settings.

    link = open_link(device_config, device_config.transport, clock)

Modbus TCP/RTU -> a ModbusTransport (retries, reconnects, raw-frame log); I2C -> an I2cLink on
/dev/i2c-N (one per bus number, shared; behind a `mux:` switch a MuxedBus on it), or on a USB-to-I2C
bridge (mcp2221, cp2112, ft232h: one per serial number or URL, shared the same way); serial -> a
SerialLink on the port's one SerialLine (devices naming the same port share it, each by its device id).
Simulated devices get the same kinds of link from rig/devices/simulated/bench.py (a Modbus server on
127.0.0.1, a pty, a simulated I2C bus). `switch_banks` gives the I2C switches as devices (safe state: channels
off).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers.clock import Clock
from drivers.registry import I2cLink, SerialLink
from drivers.tca9548a import MuxedBus, SwitchBank
from drivers.transports.modbus import ModbusTransport
from drivers.transports.serial import SerialLine
from rig.core.ports import port_key

MODBUS_TRIES = 3


def _modbus_tcp(dev_cfg, t, clock: Clock, shared: Shared | None = None) -> ModbusTransport:
    return ModbusTransport(host=t.host, port=t.port, timeout_s=t.timeout_s, name=dev_cfg.name,
                           unit=dev_cfg.unit, clock=clock, tries=MODBUS_TRIES)


def _modbus_rtu(dev_cfg, t, clock: Clock, shared: Shared | None = None) -> ModbusTransport:
    return ModbusTransport(serial_port=t.port, baudrate=t.baudrate, parity=t.parity, timeout_s=t.timeout_s,
                           name=dev_cfg.name, unit=dev_cfg.unit, clock=clock, tries=MODBUS_TRIES)


class Shared:
    """What the devices of one station build share: each /dev/i2c-N opened once (devices and switches
    on one bus share it), one SerialLine per port (devices on it share its lock and port)."""

    def __init__(self) -> None:
        self.i2c: dict[int, Any] = {}
        self.bridges: dict[str, Any] = {}  # by the bridge's bus label ("mcp2221 0001234567")
        self.lines: dict[str, SerialLine] = {}

    def bridge(self, t, clock: Clock | None = None) -> Any:
        """The bridge transport `t` names, opened once (DeviceNotFound naming it when it is missing)."""
        if t.bus not in self.bridges:
            self.bridges[t.bus] = open_bridge(t, clock)
        return self.bridges[t.bus]

    def bus(self, t) -> Any:
        """The bus object of an I2C transport: /dev/i2c-N, or the bridge."""
        return self.i2c_bus(t.bus) if t.kind == "i2c" else self.bridge(t)

    def i2c_bus(self, number: int) -> Any:
        from drivers.transports.i2c import open_smbus

        if number not in self.i2c:
            self.i2c[number] = open_smbus(number)
        return self.i2c[number]

    def serial_line(self, port: str, baudrate: int) -> SerialLine:
        key = port_key(port)  # COM7 and \\.\COM7 are one port
        if key not in self.lines:
            self.lines[key] = SerialLine(port, baudrate=baudrate)
        return self.lines[key]


def open_bridge(t, clock: Clock | None, *, hid_module: Any = None, usb_backend: Any = None) -> Any:
    """A USB-to-I2C bridge transport from its station settings; `hid_module` / `usb_backend` are the
    simulated USB's stand-ins for hidapi and pyusb (rig/devices/simulated/bench.py), None for the real
    ones."""
    if t.kind == "ft232h":
        from drivers.transports.ft232h import FT232HBus

        return FT232HBus(t.url, speed_hz=t.speed_hz, latency_ms=t.latency_ms, clock=clock,
                         usb_backend=usb_backend)
    if t.kind == "cp2112":
        from drivers.transports.cp2112 import CP2112Bus

        return CP2112Bus(t.serial, speed_hz=t.speed_hz, clock=clock, hid_module=hid_module)
    from drivers.transports.mcp2221 import MCP2221Bus

    return MCP2221Bus(t.serial, speed_hz=t.speed_hz, clock=clock, hid_module=hid_module)


def bus_label(bus: int | str) -> str:
    """"i2c-1" for /dev/i2c-1; a bridge's bus by its own label ("mcp2221 0001234567")."""
    return f"i2c-{bus}" if isinstance(bus, int) else bus


def switch_name(bus: int | str, address: int, simulated: bool = False) -> str:
    return f"{'sim ' if simulated else ''}{bus_label(bus)} switch 0x{address:02X}"


def muxed(bus: Any, number: int, mux, simulated: bool = False) -> Any:
    """The bus as a device behind switch `mux` sees it (a MuxedBus), or the bus itself without a mux."""
    if mux is None:
        return bus
    return MuxedBus(bus, mux.address, mux.channel, name=switch_name(number, mux.address, simulated))


def _i2c(dev_cfg, t, clock: Clock, shared: Shared) -> I2cLink:
    return I2cLink(muxed(shared.i2c_bus(t.bus), t.bus, t.mux), t.address)


def _bridge(dev_cfg, t, clock: Clock, shared: Shared) -> I2cLink:
    return I2cLink(muxed(shared.bridge(t, clock), t.bus, t.mux), t.address)


def _serial(dev_cfg, t, clock: Clock, shared: Shared) -> SerialLink:
    return SerialLink(t.port, t.baudrate, t.timeout_s, line=shared.serial_line(t.port, t.baudrate))


def _bus_order(item) -> tuple:
    (simulated, bus), _ = item
    return (simulated, isinstance(bus, str), bus if isinstance(bus, int) else 0, str(bus))


def switch_banks(station, shared: Shared, sim_bus: Callable[[int], Any] | None = None) -> list[SwitchBank]:
    """One SwitchBank per bus with switches on it (real, and simulated through `sim_bus(number)`): the
    station's safe state switches every channel off at the end."""
    found: dict[tuple[bool, int | str], tuple[Any, set[int]]] = {}
    for dev_cfg in station.devices():
        t = dev_cfg.transport
        if getattr(t, "mux", None) is not None:
            found.setdefault((dev_cfg.simulated, t.bus), (t, set()))[1].add(t.mux.address)
    banks = []
    for (simulated, number), (t, addresses) in sorted(found.items(), key=_bus_order):
        if simulated and sim_bus is None:
            continue
        bus = sim_bus(number) if simulated else shared.bus(t)
        names = {a: switch_name(number, a, simulated) for a in sorted(addresses)}
        label = f"{'sim ' if simulated else ''}{bus_label(number)} switches"
        banks.append(SwitchBank(bus, names, name=label))
    return banks


OPENERS = {"modbus_tcp": _modbus_tcp, "modbus_rtu": _modbus_rtu, "i2c": _i2c, "serial": _serial,
           "mcp2221": _bridge, "cp2112": _bridge, "ft232h": _bridge}


def open_link(dev_cfg, transport, clock: Clock, shared: Shared | None = None):
    """The link for a real transport (`kind` other than sim). Opening a real I2C bus may fail
    (DeviceNotFound naming the bus); the others open when the driver connects. Devices built with the
    same `shared` share buses and serial lines."""
    return OPENERS[transport.kind](dev_cfg, transport, clock, shared or Shared())
