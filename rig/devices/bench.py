"""The simulated part of a station: ONE world on the campaign clock, and a simulator for every device
whose transport is `{kind: sim}`. The only production module that imports drivers.sim.

    bench = SimBench(station, clock)
    link = bench.link(device_config)        # starts the device's simulator; the SAME driver is built on it
    bench.i2c_bus(1)                        # the shared simulated bus 1 (its switches), for the safe state
    bench.stop()

Each driver's spec names its simulator (drivers/registry.py); the world's field comes from the station's
field source (`world_field`: the `sim:` truth over what the station declares), the DUT truths and the
simulator's defaults from drivers/sim/world/truths.py. A station may mix real and simulated devices (a dry run
with a real chamber): the simulated ones share the world, the real ones talk to their real transports, and a
simulated probe beside a real DUT reads a mount that follows the simulated air.

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

import numpy as np

from drivers.clock import Clock
from drivers.registry import I2cLink, SerialLink, SimI2c, SimModbus, SimSerial
from drivers.sim.devices.faults import DeviceFaults, Window
from drivers.sim.transports.i2c_bus import FakeSMBus
from drivers.sim.world import DutTruth, World
from drivers.sim.world.truths import (
    AIR_C,
    DUT_KEYS,
    dut_truth,
    mount_truth,
    world_deviations,
)
from drivers.transports.serial import SerialLine
from rig.core.configbase import BRIDGE_KINDS, ModbusTcp
from rig.core.errors import ConfigError
from rig.devices.links import muxed, open_bridge, open_link
from rig.fieldsources.fieldmaths import TYPICAL_FIELD_NT

LOOPBACK = "127.0.0.1"
FAULTY_TIMEOUT_S = 0.3  # a simulator answers within ms: a lost reply need not cost the usual second


def dut_truths(station) -> dict[str, DutTruth]:
    """{DUT name: truth} for the simulated DUTs, from the station's `sim.duts` (defaults applied)."""
    out = {}
    for position, dut in enumerate(station.duts):
        if not dut.simulated:
            continue
        spec = station.sim.duts.get(dut.name)
        if spec is None:
            out[dut.name] = dut_truth(station.sim.seed, position)
        else:
            truth: Any = spec.truth if spec.truth == "random" else spec.truth.model_dump()
            out[dut.name] = dut_truth(station.sim.seed, position, truth, spec.noise_nt, spec.thermal_lag_s,
                                      **spec.model_dump(include=set(DUT_KEYS)))
            out[dut.name].sensor_lag_s = spec.sensor_lag_s
        out[dut.name].position_m = true_position_m(station, dut)
    return out


def true_position_m(station, device) -> np.ndarray:
    """Where a simulated sensor really sits (m): its stated position_mm plus sim.duts' position_error_mm."""
    stated = np.zeros(3) if device.position_mm is None else np.asarray(device.position_mm, float)
    spec = station.sim.duts.get(device.name)
    error = np.zeros(3) if spec is None else np.asarray(spec.position_error_mm, float)
    return (stated + error) / 1000.0


def reference_truths(station) -> dict[str, DutTruth]:
    """{name: truth} of the simulated reference magnetometers. A reference's calibration file is its
    truth, so it is never drawn at random: `sim.duts` states it (S, b_nt...) to match the shipped file,
    or it is an ideal sensor (what an identity calibration file describes)."""
    out = {}
    for ref in station.reference_magnetometers:
        if not ref.simulated:
            continue
        spec = station.sim.duts.get(ref.name)
        beside = {} if spec is None else spec.model_dump(include=set(DUT_KEYS))  # as a DUT's
        if spec is None or spec.truth == "random":
            out[ref.name] = dut_truth(station.sim.seed, 0, {"S": np.eye(3)},
                                      None if spec is None else spec.noise_nt,
                                      None if spec is None else spec.thermal_lag_s, **beside)
        else:
            out[ref.name] = dut_truth(station.sim.seed, 0, spec.truth.model_dump(), spec.noise_nt,
                                      spec.thermal_lag_s, **beside)
        out[ref.name].position_m = true_position_m(station, ref)
    return out


def world_field(station) -> dict:
    """The simulated field source's keywords: the station's `sim:` truth where it states one, else what
    the station declares (else a typical field)."""
    sim = station.sim
    out = station.field_source.declared_world()
    truth = {"ambient_nt": sim.ambient_nt, "site_field_nt": sim.site_field_nt,
             "coil_constants_nt_per_a": sim.coil_constants_nt_per_a,
             "coil_geometry": None if sim.coil_geometry is None else
             (sim.coil_geometry.shape, tuple(sim.coil_geometry.size_m), tuple(sim.coil_geometry.spacing_m))}
    for key, value in truth.items():
        if key in out and value is not None:
            out[key] = value if key == "coil_geometry" else np.asarray(value, float)
    for key in ("ambient_nt", "site_field_nt"):
        if key in out and out[key] is None:
            out[key] = np.asarray(TYPICAL_FIELD_NT, float)
    out["coil_nonlinearity_per_a"] = np.asarray(sim.coil_nonlinearity_per_a, float)
    axes = sim.turntable_axes
    out["turntable_axes"] = None if axes is None else (tuple(axes.az_tilt_deg), axes.el_tilt_deg,
                                                       tuple(axes.zero_offsets_deg))
    if sim.ambient_drift_nt_per_h is not None:  # nT/h in the station, nT/s in the world
        out["ambient_drift_nt_per_s"] = np.asarray(sim.ambient_drift_nt_per_h, float) / 3600.0
    return out


def make_world(station, clock: Clock) -> World:
    """The station's world: its field source's field, its deviations (drivers/sim/world/truths.py), its
    DUTs."""
    air_c = AIR_C if station.sim.air_c is None else station.sim.air_c
    world = World(clock, air_c=air_c, seed=station.sim.seed, **world_field(station),
                  **world_deviations(station.sim.model_dump()))
    for name, truth in (dut_truths(station) | reference_truths(station)).items():
        world.add_dut(name, truth)
    for sensor in station.temperature_sensors:
        if sensor.simulated and sensor.beside not in world.duts:
            world.add_dut(sensor.beside, mount_truth())
    return world


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
