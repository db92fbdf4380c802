"""The simulated part of a station: ONE world on the campaign clock, and a simulator for every device
whose transport is `{kind: sim}`; the world itself is made in rig/devices/simulated/world.py.

    bench = SimBench(station, clock)
    link = bench.link(device_config)        # starts the device's simulator; the SAME driver is built on it
    bench.i2c_bus(1)                        # the shared simulated bus 1 (its switches), for the safe state
    bench.stop()

Each driver's spec names its simulator (drivers/registry.py); the world comes from the station's `sim:`
(rig/devices/simulated/world.py: its field source's field, the DUT truths and the simulator's defaults). A
station may mix real and simulated devices (a dry run with a real chamber): the simulated ones share the
world, the real ones talk to their real transports, and a simulated probe beside a real DUT reads a mount that
follows the simulated air.

A simulated device's `transport: {kind: sim, faults: ...}` becomes its fault schedule
(drivers/sim/devices/faults.py), handed to its simulator's fault hooks; world.faults keeps them by device
name. Simulated chips wired explicitly (`{kind: sim, bus: 0, address: 0x30}`, or behind a switch with
`mux: {address: 0x70, channel: 3}`) share ONE simulated bus per bus number, with a TCA9548A model per
switch, so the channel switching is exercised (a chip without `address` or `mux` keeps a bus of its own);
simulated serial devices naming the same `line:` share one pty (SerialMagLine), each by its device id.
A chip behind a simulated USB-to-I2C bridge (`{kind: mcp2221 | cp2112 | ft232h, sim: true, ...}`) sits on
that bridge's own simulated bus (its switches too); the bridge's simulator (drivers/sim/transports/mcp2221.py,
cp2112.py, ft232h.py) is plugged into one simulated USB (a hidapi stand-in, a pyusb backend), and the
REAL bridge transport is opened on it: `i2c_bus(label)` is that transport.
A simulated serial device runs on a pty (drivers/sim/transports/pty.py: POSIX only): where the system has none
(Windows), such a device is refused with one line before anything is written; the rest runs.
"""

from __future__ import annotations

import contextlib
from typing import Any

from drivers.clock import Clock
from drivers.registry import I2cLink, SerialLink, SimI2c, SimModbus, SimSerial
from drivers.sim.devices.faults import DeviceFaults, Window
from drivers.sim.transports.i2c_bus import FakeSMBus
from drivers.transports.serial import SerialLine
from rig.core.configbase import BRIDGE_KINDS, ModbusTcp
from rig.core.errors import ConfigError
from rig.devices.links import muxed, open_bridge, open_link
from rig.devices.simulated.world import make_world

LOOPBACK = "127.0.0.1"
FAULTY_TIMEOUT_S = 0.3  # a simulator answers within ms: a lost reply need not cost the usual second


def _window(spec) -> Window | None:
    return None if spec is None else Window(spec.after_s, spec.for_s)


class SimBench:
    def __init__(self, station, clock: Clock):
        self.clock = clock
        self.seed = station.sim.seed
        self.station = station
        self.world = make_world(station, clock)
        self.running: list[Any] = []
        self.buses: dict[int | str, FakeSMBus] = {}  # simulated buses with switches, by bus number / bridge
        self.bridges: dict[str, Any] = {}  # simulated bridges' transports, by bus label
        self.bridge_chips: dict[str, Any] = {}  # their simulators (fault hooks for tests)
        self.hid = None  # the simulated USB, made with the first simulated bridge: hidapi's stand-in,
        self.usb_backend = None  # and pyusb's
        self.lines: dict[str, tuple[SerialLine, float]] = {}  # shared serial lines by `line:` name

    def link(self, dev_cfg):
        """Start the device's simulator and return the link its driver is built on."""
        t = dev_cfg.transport
        if getattr(t, "line", None) is not None:
            line, timeout_s = self._line(t.line)
            return SerialLink(line.port, line.baudrate, timeout_s, line=line)
        endpoint = self._simulator(dev_cfg)(dev_cfg.sim_request(self.world))
        faults = self.faults_of(dev_cfg)
        match endpoint:
            case SimModbus(server=server):
                server.faults = faults
                loopback = ModbusTcp(kind="modbus_tcp", host=LOOPBACK, port=self._start(server))
                if faults is not None:
                    loopback.timeout_s = FAULTY_TIMEOUT_S
                return open_link(dev_cfg, loopback, self.clock)
            case SimSerial(firmware=firmware, baudrate=baudrate, timeout_s=timeout_s):
                firmware.faults = faults
                timeout_s = timeout_s if faults is None else min(timeout_s, FAULTY_TIMEOUT_S)
                return SerialLink(self._start(firmware), baudrate, timeout_s)
            case SimI2c(chip=chip, address=address):
                address = t.address if t.address is not None else address
                if t.kind in BRIDGE_KINDS:
                    return self._bridge_link(t, chip, address, faults)
                if t.mux is not None:  # ONE bus per bus number, the chip behind its switch channel
                    if faults is not None:  # the chip's own faults; bus-level NACKs would hit its neighbours
                        chip.faults = faults
                    bus = self._world_bus(t.bus)
                    bus.chips[t.mux.address].attach(t.mux.channel, address, chip)
                    return I2cLink(muxed(bus, t.bus, t.mux, simulated=True), address)
                if t.address is not None:  # wired explicitly: on simulated bus `bus`, as a real chip would be
                    bus = self._world_bus(t.bus)
                else:  # no wiring stated: a bus of its own, so identical chips never clash
                    bus = FakeSMBus()
                bus.attach(address, chip)
                if faults is not None:
                    chip.faults = faults
                    bus.set_faults(address, faults)
                return I2cLink(bus, address)
        raise TypeError(f"{dev_cfg.name}: simulator returned {endpoint!r}")

    def _simulator(self, dev_cfg):
        """The device's `simulate`; one that cannot load for want of a POSIX module (a serial device's
        pty and termios on Windows) is refused naming the device."""
        try:
            return dev_cfg.spec.load_simulator()
        except ImportError as exc:
            raise ConfigError(
                f"station {self.station.name}: {dev_cfg.name} ({dev_cfg.spec.type}) cannot be simulated on "
                f"this system ({exc}); its simulator needs a POSIX pseudo-terminal. Use a station without "
                "simulated serial devices (configs/stations/sim-4.yaml), or run on Linux or macOS") from None

    def faults_of(self, dev_cfg) -> DeviceFaults | None:
        """The device's fault schedule from its `transport: {kind: sim, faults: ...}` (None: no faults),
        seeded by the station's `sim.seed`; also kept in world.faults under the device's name."""
        spec = getattr(dev_cfg.transport, "faults", None)
        if spec is None:
            return None
        stuck = spec.stuck_temperature
        faults = DeviceFaults(
            dev_cfg.name, self.clock, seed=self.seed,
            one_in={k: getattr(spec, k) for k in ("no_reply", "exception", "garbled", "nack")
                    if getattr(spec, k) is not None},
            unplug=_window(spec.unplug), alarm=_window(spec.alarm),
            stuck=Window() if stuck is True else _window(stuck))
        self.world.faults[dev_cfg.name] = faults
        return faults
    def _bridge_link(self, t, chip, address: int, faults) -> I2cLink:
        """A chip on a simulated bridge's bus (behind its switch channel, or on the bus itself)."""
        world_bus = self._world_bus(t.bus)
        if faults is not None:
            chip.faults = faults
        if t.mux is not None:
            world_bus.chips[t.mux.address].attach(t.mux.channel, address, chip)
        else:
            world_bus.attach(address, chip)
            if faults is not None:
                world_bus.set_faults(address, faults)
        return I2cLink(muxed(self.i2c_bus(t.bus), t.bus, t.mux, simulated=True), address)

    def _bridge(self, label: str) -> Any:
        """The simulated bridge `label`: its simulator on the simulated USB, and the real transport
        opened on it (once)."""
        if label not in self.bridges:
            from drivers.sim.transports.i2c_wire import I2CWire

            t = next(d.transport for d in self.station.devices()
                     if d.simulated and getattr(d.transport, "bus", None) == label)
            wire = I2CWire(self._world_bus(label))
            if t.kind == "ft232h":  # pyusb and pyftdi (the `bridges` extra): only an FT232H needs them
                from drivers.sim.transports.ft232h import FT232HSim
                from drivers.sim.transports.usbfake import FakeUsbBackend

                serial = _url_serial(t.url) or f"FT0SIM{len(self.bridges):02d}"
                chip = FT232HSim(wire, self.clock, serial=serial)
                self.usb_backend = self.usb_backend or FakeUsbBackend()
                self.usb_backend.plug(chip)
            else:
                from drivers.sim.transports.cp2112 import CP2112Sim
                from drivers.sim.transports.hidbus import FakeHid
                from drivers.sim.transports.mcp2221 import MCP2221ASim

                model = MCP2221ASim if t.kind == "mcp2221" else CP2112Sim
                chip = model(wire, self.clock, serial=t.serial or f"SIM{len(self.bridges):04d}")
                self.hid = self.hid or FakeHid(self.clock)
                self.hid.plug(chip)
            self.bridge_chips[label] = chip
            self.bridges[label] = open_bridge(t, self.clock, hid_module=self.hid,
                                              usb_backend=self.usb_backend)
        return self.bridges[label]

    def i2c_bus(self, number: int | str):
        """The bus the simulated devices on bus `number` talk to: the simulated bus with every switch
        the station puts on it (all channels off), or for a bridge's label the bridge transport."""
        return self._bridge(number) if isinstance(number, str) else self._world_bus(number)

    def _world_bus(self, number: int | str) -> FakeSMBus:
        """The simulated chips and switches of bus `number` (a bus number, or a bridge's label)."""
        if number not in self.buses:
            bus = self.buses[number] = FakeSMBus(number)
            for dev_cfg in self.station.devices():
                t = dev_cfg.transport
                mux = getattr(t, "mux", None)
                if dev_cfg.simulated and mux is not None and t.bus == number and mux.address not in bus.chips:
                    bus.add_switch(mux.address)
        return self.buses[number]

    def _line(self, name: str) -> tuple[SerialLine, float]:
        """One pty with every simulated device naming `line: name` behind it (SerialMagLine)."""
        if name not in self.lines:
            members = [d for d in self.station.devices()
                       if d.simulated and getattr(d.transport, "line", None) == name]
            endpoints = [self._simulator(d)(d.sim_request(self.world)) for d in members]
            from drivers.sim.devices.serialmag import SerialMagLine  # loads only where the pty above did

            firmware = SerialMagLine([e.firmware for e in endpoints])
            port = self._start(firmware)
            line = SerialLine(port, baudrate=endpoints[0].baudrate)
            self.lines[name] = (line, endpoints[0].timeout_s)
        return self.lines[name]

    def _start(self, sim) -> Any:
        self.running.append(sim)
        return sim.start()

    def stop(self) -> None:
        for bridge in self.bridges.values():
            with contextlib.suppress(Exception):
                bridge.close()
        self.bridges.clear()
        for sim in reversed(self.running):
            with contextlib.suppress(Exception):
                sim.stop()
        self.running.clear()


def _url_serial(url: str) -> str | None:
    """The serial number an ftdi:// URL names, if it names one (ftdi://ftdi:232h:SERIAL/1)."""
    fields = url.split("://", 1)[-1].split("/", 1)[0].split(":")
    serial = fields[2] if len(fields) > 2 else ""
    return serial if serial and not (serial.isdigit() and len(serial) < 3) else None
