"""MMC5983MA readings through each USB-to-I2C bridge, on its simulator (the real transport on a simulated
USB, the bus and USB time on the simulated clock).

Per bridge and bus speed: the simulated time of one reading of one MMC5983MA on the bridge's bus (a
SET/RESET pair and the die temperature, the driver's defaults), and the part of it the bridge costs (the
same reading on the smbus2 fake, which has no bus time, takes only the driver's own waits); then 16
MMC5983MA behind two TCA9548A switches on one bridge, read in turn as a point does: simulated seconds per
point (what the bench would take) and the wall time of our code per point (the simulators included).

    .venv/bin/python bench/bridges.py [--points 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drivers.clock import SimClock
from drivers.mmc5983ma import MMC5983MA
from drivers.sim.devices.mmc5983ma import MMC5983MASim
from drivers.sim.transports.cp2112 import CP2112Sim
from drivers.sim.transports.ft232h import FT232HSim
from drivers.sim.transports.hidbus import FakeHid
from drivers.sim.transports.i2c_bus import FakeSMBus
from drivers.sim.transports.i2c_wire import I2CWire
from drivers.sim.transports.mcp2221 import MCP2221ASim
from drivers.sim.transports.usbfake import FakeUsbBackend
from drivers.sim.world import DutTruth, World
from drivers.tca9548a import MuxedBus
from drivers.transports.cp2112 import CP2112Bus
from drivers.transports.ft232h import FT232HBus
from drivers.transports.mcp2221 import MCP2221Bus

BRIDGES = ("smbus2 fake", "mcp2221", "cp2112", "ft232h latency 16 ms", "ft232h latency 2 ms")


def open_bus(kind: str, fake: FakeSMBus, clock: SimClock, speed_hz: int):
    """The bus the drivers talk to: the fake itself, or a bridge transport on that bridge's simulator."""
    if kind == "smbus2 fake":
        return fake
    wire = I2CWire(fake)
    if kind.startswith("ft232h"):
        backend = FakeUsbBackend()
        backend.plug(FT232HSim(wire, clock, serial="FT0BENCH"))
        latency_ms = int(kind.split()[2])
        return FT232HBus("ftdi://::FT0BENCH/1", speed_hz=speed_hz, clock=clock, usb_backend=backend,
                         latency_ms=latency_ms)
    usb = FakeHid(clock)
    model, transport = (MCP2221ASim, MCP2221Bus) if kind == "mcp2221" else (CP2112Sim, CP2112Bus)
    usb.plug(model(wire, clock, serial="BENCH"))
    return transport("BENCH", speed_hz=speed_hz, clock=clock, hid_module=usb)


def build(kind: str, n_duts: int, speed_hz: int) -> tuple[SimClock, list[MMC5983MA]]:
    clock = SimClock()
    world = World(clock, ambient_nt=(20_000.0, -3_000.0, 42_000.0))
    fake = FakeSMBus()
    for address in (0x70, 0x71):
        fake.add_switch(address)
    bus = open_bus(kind, fake, clock, speed_hz)
    duts = []
    for i in range(n_duts):
        name = f"dut{i + 1}"
        world.add_dut(name, DutTruth.random(np.random.default_rng(i)))
        switch, channel = 0x70 + i // 8, i % 8
        fake.chips[switch].attach(channel, 0x30, MMC5983MASim(world, name))
        dut = MMC5983MA(MuxedBus(bus, switch, channel, name=f"switch 0x{switch:02X}"), 0x30, name=name,
                        clock=clock)
        dut.connect()
        duts.append(dut)
    return clock, duts


def one_reading_s(kind: str, speed_hz: int) -> float:
    clock, (dut,) = build(kind, 1, speed_hz)
    dut.read()  # the switch's channel is selected once, as in a run
    start = clock.now()
    dut.read()
    return clock.now() - start


def point(kind: str, speed_hz: int, points: int) -> tuple[float, float]:
    """(simulated s, wall s) per point of 16 DUTs read in turn."""
    clock, duts = build(kind, 16, speed_hz)
    for dut in duts:
        dut.read()
    sim_start, wall_start = clock.now(), time.perf_counter()
    for _ in range(points):
        for dut in duts:
            dut.read()
    return (clock.now() - sim_start) / points, (time.perf_counter() - wall_start) / points


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=5)
    args = parser.parse_args()
    print(f"{'bridge':<22} {'SCL':>7}  {'one reading':>11}  {'bridge part':>11}  "
          f"{'16 DUTs: sim s/point':>20}  {'wall s/point':>12}")
    for speed_hz in (100_000, 400_000):
        base = one_reading_s("smbus2 fake", speed_hz)
        for kind in BRIDGES:
            reading = one_reading_s(kind, speed_hz)
            sim_s, wall_s = point(kind, speed_hz, args.points)
            print(f"{kind:<22} {speed_hz // 1000:>4} kHz  {reading * 1e3:>8.1f} ms  "
                  f"{(reading - base) * 1e3:>8.1f} ms  {sim_s:>20.3f}  {wall_s:>12.3f}")


if __name__ == "__main__":
    main()
