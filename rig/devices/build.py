"""Build every device of a station from its config and its driver's spec: real transports, or the same
drivers on simulators.

    rig = open_rig(station)              # build, connect, make safe FIRST; raises on the first failure
    rig.devices(); rig.chamber; rig.field_source; rig.duts; rig.temp_sources; rig.world (sims only)
    rig.close()                          # safe_state + close + stop the simulators

    built = build_devices(station)       # no I/O yet: for `rig devices check`, which connects one by one

Every device is built the same way: `spec.build(link, options, name=, clock=, set_reset=)` where the
spec comes from drivers/registry.py and the link from rig/devices/links.py (real transport) or
rig/devices/simulated/bench.py (`transport: {kind: sim}`: the device's simulator, all fed by ONE World on the
campaign clock). A real device that fails stays failed: nothing falls back to a simulator. An all-simulated
station runs on SimClock; anything real means RealClock (real chambers do not run on simulated time).

The run lock of a session is rig/session/lock.py.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from typing import Any

from drivers.base import Device, each_by_line, make_all_safe
from drivers.clock import Clock, RealClock, SimClock
from rig import config as cfg
from rig.core.errors import ERRORS
from rig.devices.links import Shared, open_link, switch_banks


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


def build_devices(station: cfg.Station, plan: cfg.Plan | None = None, clock: Clock | None = None,
                  errors: dict[str, str] | None = None) -> Built:
    """Construct every driver (and start the simulators of simulated devices), in station order. No
    device I/O yet, except that opening a real I2C bus may fail (DeviceNotFound naming the bus). With
    `errors` given, a device that cannot be built is recorded there ({name: message}) and the others are
    still built; without it the first failure raises. The plan's `set_reset: off` reaches every driver."""
    clock = clock or station_clock(station)
    built = Built(clock=clock, devices={})
    bench = None
    if any(station.simulated_devices().values()):
        from rig.devices.simulated.bench import SimBench

        bench = SimBench(station, clock)
        built.world, built.sims = bench.world, bench.running
    set_reset = plan is None or plan.set_reset == "pair"
    shared = Shared()  # buses and serial lines the station's devices share
    try:
        for dev_cfg in station.devices():
            try:
                if dev_cfg.simulated:
                    link = bench.link(dev_cfg)
                else:
                    link = open_link(dev_cfg, dev_cfg.transport, clock, shared)
                built.devices[dev_cfg.name] = dev_cfg.spec.build(
                    link, dev_cfg.device_options, name=dev_cfg.name, clock=clock, set_reset=set_reset)
            except (*ERRORS, OSError) as exc:
                if errors is None:
                    raise
                errors[dev_cfg.name] = str(exc)
        add_switch_banks(built, station, shared, bench)
    except BaseException:
        built.stop_sims()
        raise
    return built


def add_switch_banks(built: Built, station: cfg.Station, shared: Shared, bench) -> None:
    """The I2C switches as devices, after the others: their safe state (every channel off) comes last."""
    for bank in switch_banks(station, shared, bench.i2c_bus if bench is not None else None):
        built.devices[bank.name] = bank


def open_rig(station: cfg.Station, plan: cfg.Plan | None = None, clock: Clock | None = None) -> Rig:
    """Build and connect every device, then make every one safe before anything else happens (this is
    also what makes a kill -9'ed previous run safe). The devices of each serial line go in a thread of that
    line, beside the others (drivers/base.py each_by_line). A device that fails to connect raises its
    DeviceError (the first in station order, where several did); the devices already connected are made
    safe and closed first."""
    built = build_devices(station, plan, clock)
    devices = list(built.devices.values())
    done: set[int] = set()  # ids of the devices connected (set.add is atomic across the line threads)

    def connect(dev: Device) -> None:
        dev.connect()
        done.add(id(dev))

    connected: list[Device] = []
    try:
        # each serial line in a thread of its own (drivers/base.py each_by_line): their quiet waits overlap
        try:
            failed = each_by_line(devices, connect, stop_at_error=True)
        finally:
            connected = [dev for dev in devices if id(dev) in done]
        if failed:
            raise failed[min(failed)]
        failed = each_by_line(connected, lambda dev: dev.safe_state())
        if failed:
            raise failed[min(failed)]
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

