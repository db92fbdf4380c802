"""Build every device of a station from its config: real transports, or the same drivers on simulators.

    rig = open_rig(station)              # build, connect, make safe FIRST; raises on the first failure
    rig.devices(); rig.chamber; rig.field_source; rig.duts; rig.temp_sources; rig.world (sims only)
    rig.close()                          # safe_state + close + stop the simulators

    built = build_devices(station)       # no I/O yet: for `rig devices check`, which connects one by one

A device is simulated exactly when the station says so (`transport: {kind: sim}`); then it gets its
simulator (FakeSMBus + chip model, SerialMagSim on a pty, Modbus sims on loopback), all fed by ONE World
on the campaign clock, and the SAME driver class as on real hardware. A real device that fails stays
failed: nothing falls back to a simulator. An all-simulated station runs on SimClock; anything real
means RealClock (real chambers do not run on simulated time).

RunLock: a small pid file next to the session. A second run on a live session is refused; a lock left by
a dead process (kill -9, power cut) is reported and taken over (the caller makes the hardware safe first).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.base import Device, make_all_safe
from drivers.chamber import WatlowF4, WatlowF4T
from drivers.clock import Clock, RealClock, SimClock
from drivers.coils import CoilController
from drivers.hmc5883l import HMC5883L
from drivers.mmc5983ma import MMC5983MA
from drivers.serialmag import SerialMagnetometer
from drivers.tmp117 import TMP117
from drivers.transports.modbus import ModbusTransport
from drivers.turntable import Turntable
from rig import config as cfg
from rig.errors import ERRORS, SessionError

MODBUS_TRIES = 3


@dataclass
class Built:
    """Devices constructed but not connected, plus the simulation behind them (if any)."""

    clock: Clock
    devices: dict[str, Device]
    world: Any = None
    sims: list[Any] = field(default_factory=list)

    def stop_sims(self) -> None:
        for sim in reversed(self.sims):
            with contextlib.suppress(Exception):
                sim.stop()
        self.sims.clear()


@dataclass
class Rig:
    """A connected station: devices by role. `temp_sources[dut]` is the device whose read() gives the
    DUT's temperature (the DUT itself for temp_source "self")."""

    station: cfg.Station
    built: Built
    chamber: Device
    field_source: Device
    duts: dict[str, Device]
    temp_sensors: dict[str, Device]
    temp_sources: dict[str, Device]

    @property
    def clock(self) -> Clock:
        return self.built.clock

    @property
    def world(self):
        return self.built.world

    @property
    def simulated(self) -> dict[str, bool]:
        return self.station.simulated_devices()

    def devices(self) -> list[Device]:
        return list(self.built.devices.values())

    def make_safe(self) -> list[str]:
        """safe_state() on every device; returns the names of those that failed (logged)."""
        return make_all_safe(self.devices())

    def close(self) -> None:
        """Make safe, close every link, stop the simulators. Never raises."""
        self.make_safe()
        for dev in self.devices():
            with contextlib.suppress(Exception):
                dev.close()
        self.built.stop_sims()


# --- construction ---------------------------------------------------------------------------------
def station_clock(station: cfg.Station) -> Clock:
    return SimClock() if all(station.simulated_devices().values()) else RealClock()


def make_world(station: cfg.Station, clock: Clock):
    from drivers.sim.world import World

    source = station.field_source
    coils = isinstance(source, cfg.Coils)
    world = World(
        clock,
        field_source="coils" if coils else "turntable",
        ambient_nt=station.sim_ambient_nt(),
        coil_constants_nt_per_a=source.constants if coils else None,
        site_field_nt=station.sim_site_field_nt(),
        air_c=station.sim.air_c,
        turntable_rate_deg_s=getattr(source, "rate_deg_s", 20.0),
        seed=station.sim.seed,
    )
    for name, truth in station.sim_dut_truths().items():
        world.add_dut(name, truth)
    return world


def _modbus(dev_cfg, clock: Clock, start_sim: Callable[[], int] | None) -> ModbusTransport:
    t = dev_cfg.transport
    common = {"name": dev_cfg.name, "unit": dev_cfg.unit, "clock": clock, "tries": MODBUS_TRIES}
    if t.kind == "sim":
        return ModbusTransport(host="127.0.0.1", port=start_sim(), timeout_s=1.0, **common)
    if t.kind == "modbus_tcp":
        return ModbusTransport(host=t.host, port=t.port, timeout_s=t.timeout_s, **common)
    return ModbusTransport(serial_port=t.port, baudrate=t.baudrate, parity=t.parity, timeout_s=t.timeout_s,
                           **common)


def _i2c_bus(dev_cfg, chip_factory: Callable[[], Any], default_address: int):
    """(bus, address): a FakeSMBus with the chip model for a sim device, else the real /dev/i2c-N."""
    t = dev_cfg.transport
    if t.kind == "sim":
        from drivers.sim.i2c_bus import FakeSMBus

        bus = FakeSMBus()  # one bus per simulated chip: no address clashes between identical chips
        bus.attach(default_address, chip_factory())
        return bus, default_address
    from drivers.transports.i2c import open_smbus

    return open_smbus(t.bus), t.address


def build_devices(station: cfg.Station, plan: cfg.Plan | None = None, clock: Clock | None = None,
                  errors: dict[str, str] | None = None) -> Built:
    """Construct every driver (and start the simulators of simulated devices). No device I/O yet,
    except that opening a real I2C bus may fail (DeviceNotFound naming the bus). With `errors` given,
    a device that cannot be built is recorded there ({name: message}) and the others are still built;
    without it the first failure raises."""
    clock = clock or station_clock(station)
    built = Built(clock=clock, devices={})
    any_sim = any(station.simulated_devices().values())
    built.world = make_world(station, clock) if any_sim else None

    def started(sim):
        built.sims.append(sim)
        return sim.start()

    try:
        for name, factory in _factories(station, plan, clock, built.world, started):
            try:
                built.devices[name] = factory()
            except (*ERRORS, OSError) as exc:
                if errors is None:
                    raise
                errors[name] = str(exc)
    except BaseException:
        built.stop_sims()
        raise
    return built


def _factories(station, plan, clock, world, started) -> list[tuple[str, Callable[[], Device]]]:
    """(device name, constructor) for every device of the station, in station order."""
    from drivers import hmc5883l, mmc5983ma, tmp117

    out: list[tuple[str, Callable[[], Device]]] = []
    ch = station.chamber
    register_map = "f4t" if ch.type == "watlow_f4t" else "f4"

    alarm = getattr(ch, "alarm", None)  # station-given alarm register; none by default
    if ch.simulated:
        from drivers.sim.chamber import SIM_STATION_ALARM as alarm  # the sim plays a lab that has one

    def chamber_sim():
        from drivers.sim.chamber import ChamberSim

        return started(ChamberSim(world, register_map, ch.unit, alarm=alarm))

    chamber_cls = WatlowF4T if ch.type == "watlow_f4t" else WatlowF4
    out.append((ch.name, lambda: chamber_cls(_modbus(ch, clock, chamber_sim), name=ch.name, clock=clock,
                                             alarm=alarm, **ch.limits.model_dump())))

    fs = station.field_source
    if isinstance(fs, cfg.Coils):
        def coil_sim():
            from drivers.sim.coils import CoilSim

            return started(CoilSim(world, fs.unit, compliance_limit_a=max(2.0, fs.max_current_a),
                                   rated_current_a=max(3.0, fs.max_current_a)))

        out.append((fs.name, lambda: CoilController(_modbus(fs, clock, coil_sim), name=fs.name, clock=clock,
                                                    max_current_a=fs.max_current_a)))
    else:
        def table_sim():
            from drivers.sim.turntable import TurntableSim

            return started(TurntableSim(world, fs.unit, az_limits_deg=fs.az_limits_deg,
                                        el_limits_deg=fs.el_limits_deg))

        out.append((fs.name, lambda: Turntable(_modbus(fs, clock, table_sim), name=fs.name, clock=clock,
                                               az_limits_deg=fs.az_limits_deg,
                                               el_limits_deg=fs.el_limits_deg)))

    set_reset = plan is None or plan.set_reset == "pair"
    for d in station.duts:
        opts = d.driver_options(set_reset)
        if d.type == "mmc5983ma":
            def make_mmc(d=d, opts=opts):
                from drivers.sim.mmc5983ma import MMC5983MASim

                bus, address = _i2c_bus(d, lambda: MMC5983MASim(world, d.name), mmc5983ma.ADDRESS)
                return MMC5983MA(bus, address, name=d.name, clock=clock, **opts)

            out.append((d.name, make_mmc))
        elif d.type in ("hmc5883l", "hmc5983"):
            def make_hmc(d=d, opts=opts):
                from drivers.sim.hmc5883l import HMC5883LSim

                bus, address = _i2c_bus(d, lambda: HMC5883LSim(world, d.name, opts["variant"]),
                                        hmc5883l.ADDRESS)
                return HMC5883L(bus, address, name=d.name, clock=clock, **opts)

            out.append((d.name, make_hmc))
        else:
            def make_serial(d=d, opts=opts):
                t = d.transport
                if t.kind == "sim":
                    from drivers.sim.serialmag import SerialMagSim

                    port, baud, timeout_s = started(SerialMagSim(world, d.name)), 9600, 0.5
                else:
                    port, baud, timeout_s = t.port, t.baudrate, t.timeout_s
                return SerialMagnetometer.from_port(port, name=d.name, clock=clock, baudrate=baud,
                                                    timeout_s=timeout_s, **opts)

            out.append((d.name, make_serial))

    for s in station.temperature_sensors:
        def make_tmp(s=s):
            from drivers.sim.tmp117 import TMP117Sim

            bus, address = _i2c_bus(s, lambda: TMP117Sim(world, s.beside), tmp117.ADDRESS)
            return TMP117(bus, address, name=s.name, clock=clock)

        out.append((s.name, make_tmp))
    return out


def open_rig(station: cfg.Station, plan: cfg.Plan | None = None, clock: Clock | None = None) -> Rig:
    """Build and connect every device, then make every one safe before anything else happens (this is
    also what makes a kill -9'ed previous run safe). A device that fails to connect raises its
    DeviceError; the devices already connected are made safe and closed first."""
    built = build_devices(station, plan, clock)
    connected: list[Device] = []
    try:
        for dev in built.devices.values():
            dev.connect()
            connected.append(dev)
        for dev in connected:
            dev.safe_state()
    except BaseException:
        for dev in connected:
            with contextlib.suppress(Exception):
                dev.safe_state()
            with contextlib.suppress(Exception):
                dev.close()
        built.stop_sims()
        raise
    devices = built.devices
    duts = {d.name: devices[d.name] for d in station.duts}
    sensors = {s.name: devices[s.name] for s in station.temperature_sensors}
    sources = {d.name: duts[d.name] if d.temp_source == "self" else sensors[d.temp_source]
               for d in station.duts}
    return Rig(station, built, devices[station.chamber.name], devices[station.field_source.name], duts,
               sensors, sources)


def check_devices(station: cfg.Station) -> list[tuple[str, dict | None, Any, str | None]]:
    """For `rig devices check`: [(name, describe() or None, one reading or None, error or None)] in
    station order. Every device is tried, whatever happened to the others; each is left safe and closed."""
    errors: dict[str, str] = {}
    built = build_devices(station, errors=errors)
    results = []
    try:
        for dev_cfg in station.devices():
            name = dev_cfg.name
            dev = built.devices.get(name)
            if dev is None:
                results.append((name, None, None, errors.get(name, "not built")))
                continue
            connected = False
            try:
                dev.connect()
                connected = True
                dev.safe_state()
                results.append((name, dev.describe(), dev.read(), None))
            except (*ERRORS, OSError) as exc:
                results.append((name, None, None, str(exc)))
            finally:
                if connected:
                    with contextlib.suppress(Exception):
                        dev.safe_state()
                with contextlib.suppress(Exception):
                    dev.close()
    finally:
        built.stop_sims()
    return results


# --- run lock -------------------------------------------------------------------------------------
def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class RunLock:
    """`<session>.lock` holding the pid of the run that owns the session."""

    def __init__(self, session_path: str | Path):
        self.path = Path(f"{session_path}.lock")
        self.stale_pid: int | None = None

    def acquire(self) -> None:
        """Take the lock. SessionError if a live process holds it; a dead holder's lock is taken over
        and remembered in `stale_pid` (the caller reports it)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                pid = self._holder()
                if pid is not None and pid != os.getpid() and pid_alive(pid):
                    raise SessionError(f"{self.path}: session is in use by running process {pid}; "
                                       "stop it first (Ctrl-C) or wait for it to finish") from None
                self.stale_pid = pid
                self.path.unlink(missing_ok=True)
                continue
            with os.fdopen(fd, "w") as f:
                f.write(f"{os.getpid()}\n")
            return
        raise SessionError(f"{self.path}: could not take the run lock")

    def _holder(self) -> int | None:
        try:
            return int(self.path.read_text().strip() or "0") or None
        except (OSError, ValueError):
            return None

    def release(self) -> None:
        if self._holder() == os.getpid():
            self.path.unlink(missing_ok=True)

    def __enter__(self) -> RunLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()
