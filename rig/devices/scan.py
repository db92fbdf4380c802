"""`rig devices scan`: what answers on a station's I2C buses (on the bus and behind each switch channel)
and on its serial ports, with what each is: what an operator needs before writing `address:` and `mux:`
into a station file. The scanning itself is drivers/busscan.py; this module picks the buses and ports.

    report = scan_station(station)           # every bus and port its devices name, simulated ones too
    report = scan_targets(buses=[1], ports=[("/dev/ttyUSB0", 9600)])   # /dev/i2c-1 and one port
    report = scan_targets(bridges=True)      # every USB-to-I2C bridge plugged in, and its bus
    report.lines() -> the text `rig devices scan` prints; report.problems -> [...]

A USB-to-I2C bridge (MCP2221A, CP2112, FT232H) is listed by its USB vendor:product id and serial number
and its bus scanned through the bridge transport itself (drivers/transports/), as a station's devices
use it; a bridge that cannot be opened, or a bus that is stuck, is that bus's error.

Against a station, each finding is matched with the station device configured there, and station
devices that do not answer are listed. Simulated devices are scanned on their simulated buses and lines
(one simulated bus per bus number with its switches; a simulated chip without a switch has a bus of its
own). Modbus devices are not scanned: `rig devices check` talks to them.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from typing import Any

from drivers import busscan
from drivers.clock import RealClock, SimClock
from drivers.errors import DeviceError
from drivers.transports.serial import SerialLine
from drivers.transports.usb_bridges import bridges_present
from rig.core.configbase import BRIDGE_KINDS, Cp2112, Ft232h, Mcp2221
from rig.core.errors import ERRORS, ConfigError
from rig.core.ports import check_port, port_key
from rig.devices.links import open_bridge

SERIAL_TIMEOUT_S = 0.05  # an HMR2300 answers in about 2 ms; a USB adapter adds a few


@dataclass
class BusReport:
    label: str
    scan: busscan.I2cScan | None = None
    error: str | None = None
    expected: dict[tuple, str] = field(default_factory=dict)  # (switch, channel, address) -> device name


@dataclass
class PortReport:
    label: str
    port: str
    baudrate: int
    found: list[busscan.SerialFound] = field(default_factory=list)
    error: str | None = None
    expected: dict[int, str] = field(default_factory=dict)  # device id -> device name


@dataclass
class ScanReport:
    bridges: list[str] = field(default_factory=list)  # the USB-to-I2C bridges plugged in, and notes
    buses: list[BusReport] = field(default_factory=list)
    ports: list[PortReport] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # devices not scanned (Modbus), by name

    @property
    def problems(self) -> list[str]:
        """Buses or ports that could not be scanned, and station devices that did not answer."""
        out = [f"{b.label}: {b.error}" for b in self.buses if b.error]
        out += [f"{p.label}: {p.error}" for p in self.ports if p.error]
        out += [f"{name} not found ({b.label} {_where(*key)})" for b in self.buses if b.scan is not None
                for key, name in b.expected.items() if key not in _keys(b.scan)]
        out += [f"{name} not found ({p.label} id {i:02d})" for p in self.ports if not p.error
                for i, name in p.expected.items() if i not in {f.device_id for f in p.found}]
        return out

    def lines(self) -> list[str]:
        out: list[str] = list(self.bridges)
        for b in self.buses:
            out.append(b.label)
            if b.error:
                out.append(f"  cannot scan: {b.error}")
                continue
            found = b.scan.found
            if not found:
                out.append("  nothing answers")
            for f in sorted(found, key=_order):
                station = b.expected.get((f.switch, f.channel, f.address))
                out.append(f"  0x{f.address:02X}  {f.where:<22} {f.what}" + _station(station))
            out += [f"  note: {n}" for n in b.scan.notes]
        for p in self.ports:
            out.append(f"{p.label} ({p.port})")
            if p.error:
                out.append(f"  cannot scan: {p.error}")
                continue
            if not p.found:
                out.append(f"  nothing answers (ids asked at {p.baudrate} baud, then at the other rates)")
            for f in p.found:
                info = f.info
                extra = ", ".join(f"{k.replace('_', ' ')} {info[k]}" for k in ("serial_number", "firmware")
                                  if info.get(k))
                out.append(f"  id {f.device_id:02d}  {f.baudrate} baud  {info['model']}"
                           + (f", {extra}" if extra else "") + _station(p.expected.get(f.device_id)))
        if self.skipped:
            out.append(f"not scanned (Modbus; see rig devices check): {', '.join(self.skipped)}")
        return out


def _order(f: busscan.Found) -> tuple:
    return (f.switch is not None, f.switch or 0, f.channel or 0, f.address)


def _station(name: str | None) -> str:
    return f"  [station: {name}]" if name else ""


def _keys(scan: busscan.I2cScan) -> set[tuple]:
    return {(f.switch, f.channel, f.address) for f in scan.found}


def _where(switch, channel, address) -> str:
    return f"0x{address:02X}" + ("" if switch is None else f" behind switch 0x{switch:02X} channel {channel}")


# --- what to scan -------------------------------------------------------------------------------------------
def scan_targets(buses: list[int] = (), ports: list[tuple[str, int]] = (), *, device_ids=None,
                 timeout_s: float = SERIAL_TIMEOUT_S, bridges: bool = False) -> ScanReport:
    """Real buses /dev/i2c-N, serial ports and (`bridges`) every USB-to-I2C bridge plugged in, with no
    station to compare against."""
    report = ScanReport()
    if bridges:
        found, notes = bridges_present()
        report.bridges = [f"USB-to-I2C bridges plugged in: {len(found) or 'none'}"]
        report.bridges += [f"  {_bridge_text(f)}" for f in found] + [f"  note: {n}" for n in notes]
        for f in found:
            report.buses.append(_scan_bridge(_bridge_transport(f)))
    for number in buses:
        report.buses.append(_scan_real_bus(number))
    for port, baud in _distinct_ports(ports):
        report.ports.append(_scan_port(PortReport("serial port", port, baud), device_ids, timeout_s))
    return report


def _distinct_ports(ports) -> list[tuple[str, int]]:
    """Each port once (COM7 and \\\\.\\COM7 are one); a name that is no port is refused naming it."""
    out: dict[str, tuple[str, int]] = {}
    for port, baud in ports:
        try:
            check_port(port)
        except ValueError as exc:
            raise ConfigError(f"--port: {exc}") from None
        out.setdefault(port_key(port), (port, baud))
    return list(out.values())


def scan_station(station, *, device_ids=None, timeout_s: float = SERIAL_TIMEOUT_S) -> ScanReport:
    report = ScanReport()
    real_buses: dict[int, BusReport] = {}
    real_bridges: dict[str, tuple[Any, BusReport]] = {}
    sim_buses: dict[Any, BusReport] = {}
    ports: dict[str, PortReport] = {}
    bench = None
    if any(d.simulated for d in station.devices()):
        from rig.devices.simulated.bench import SimBench

        bench = SimBench(station, SimClock())
    try:
        for dev in station.devices():
            t = dev.transport
            kinds = dev.spec.transports
            mux = getattr(t, "mux", None)
            key_switch = (None, None) if mux is None else (mux.address, mux.channel)
            if "i2c" in kinds and dev.simulated and t.kind in BRIDGE_KINDS:
                link = bench.link(dev)
                bus = bench.i2c_bus(t.bus)
                label = f"{t.bus} (simulated, {_bridge_text(_chip_info(t.kind, bench.bridge_chips[t.bus]))})"
                entry = sim_buses.setdefault(bus, BusReport(label))
                entry.expected[(*key_switch, link.address)] = dev.name
            elif "i2c" in kinds and dev.simulated:
                link = bench.link(dev)
                if mux is not None or t.address is not None:  # wired explicitly: its simulated bus
                    bus = bench.i2c_bus(t.bus)
                    entry = sim_buses.setdefault(bus, BusReport(f"i2c-{t.bus} (simulated)"))
                else:
                    entry = sim_buses.setdefault(link.bus, BusReport(f"simulated bus of {dev.name}"))
                entry.expected[(*key_switch, link.address)] = dev.name
            elif t.kind in BRIDGE_KINDS:
                _, entry = real_bridges.setdefault(t.bus, (t, BusReport(f"{t.bus} (USB-to-I2C bridge)")))
                entry.expected[(*key_switch, t.address)] = dev.name
            elif "i2c" in kinds:
                entry = real_buses.setdefault(t.bus, BusReport(f"i2c-{t.bus} (/dev/i2c-{t.bus})"))
                entry.expected[(*key_switch, t.address)] = dev.name
            elif "serial" in kinds and dev.simulated:
                link = bench.link(dev)
                label = f"serial line {t.line} (simulated)" if getattr(t, "line", None) else \
                    f"serial port of {dev.name} (simulated)"
                entry = ports.setdefault(link.port, PortReport(label, link.port, link.baudrate))
                entry.expected[getattr(dev.device_options, "device_id", 0)] = dev.name
            elif "serial" in kinds:
                entry = ports.setdefault(port_key(t.port), PortReport("serial port", t.port, t.baudrate))
                entry.expected[getattr(dev.device_options, "device_id", 0)] = dev.name
            else:
                report.skipped.append(dev.name)
        for number, entry in real_buses.items():
            scanned = _scan_real_bus(number)
            entry.scan, entry.error = scanned.scan, scanned.error
            report.buses.append(entry)
        for t, entry in real_bridges.values():
            scanned = _scan_bridge(t)
            entry.scan, entry.error = scanned.scan, scanned.error
            report.buses.append(entry)
        for bus, entry in sim_buses.items():
            try:
                entry.scan = busscan.scan_i2c(bus)
            except DeviceError as exc:  # a bridge's stuck bus, a bridge gone
                entry.error = str(exc)
            report.buses.append(entry)
        for entry in ports.values():
            report.ports.append(_scan_port(entry, device_ids, timeout_s))
    finally:
        if bench is not None:
            bench.stop()
    return report


def _scan_real_bus(number: int) -> BusReport:
    from drivers.transports.i2c import open_smbus

    entry = BusReport(f"i2c-{number} (/dev/i2c-{number}{_adapter_name(number)})")
    try:
        bus = open_smbus(number)
    except DeviceError as exc:
        entry.error = exc.detail
        return entry
    try:
        entry.scan = busscan.scan_i2c(bus)
    finally:
        with contextlib.suppress(Exception):
            bus.close()
    return entry


def _bridge_text(found: dict) -> str:
    serial = found.get("serial_number")
    return f"{found['model']} USB {found['usb_id']}, serial number {serial or '(none given)'}"


def _chip_info(kind: str, chip) -> dict:
    """A simulated bridge as bridges_present() describes a real one."""
    model = {"mcp2221": "MCP2221A", "cp2112": "CP2112", "ft232h": "FT232H"}[kind]
    return {"kind": kind, "model": model, "usb_id": f"{chip.vendor_id:04x}:{chip.product_id:04x}",
            "serial_number": chip.serial_number}


def _bridge_transport(found: dict):
    """The station transport settings that open a bridge found plugged in (at 100 kHz)."""
    serial = found["serial_number"]
    if found["kind"] == "ft232h":
        url = f"ftdi://ftdi:232h:{serial}/1" if serial else "ftdi://ftdi:232h/1"
        return Ft232h(kind="ft232h", url=url, address=0x08)
    model = Mcp2221 if found["kind"] == "mcp2221" else Cp2112
    return model(kind=found["kind"], serial=serial, address=0x08)


def _scan_bridge(t) -> BusReport:
    """Open the bridge, scan its bus, close it; what fails is the bus's error."""
    entry = BusReport(f"{t.bus} (USB-to-I2C bridge)")
    try:
        bus = open_bridge(t, RealClock())
    except DeviceError as exc:
        entry.error = exc.detail
        return entry
    try:
        entry.scan = busscan.scan_i2c(bus)
    except DeviceError as exc:
        entry.error = str(exc)
    finally:
        with contextlib.suppress(Exception):
            bus.close()
    return entry


def _adapter_name(number: int) -> str:
    """The kernel's name of the adapter (e.g. "MCP2221 usb-i2c bridge"), where sysfs tells it."""
    try:
        with open(f"/sys/class/i2c-dev/i2c-{number}/name", encoding="utf-8") as f:
            return f": {f.read().strip()}"
    except OSError:
        return ""


def _scan_port(entry: PortReport, device_ids, timeout_s: float) -> PortReport:
    line = SerialLine(entry.port, baudrate=entry.baudrate)
    try:
        entry.found = busscan.scan_serial(line, device_ids=device_ids, timeout_s=timeout_s)
    except (*ERRORS, OSError) as exc:
        entry.error = getattr(exc, "detail", None) or str(exc)
    finally:
        line.close_port()
    return entry

