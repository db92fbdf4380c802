"""A world behind a USB-to-I2C bridge for the bridge tests: an MMC5983MA at 0x30 on the bus, and behind a
TCA9548A at 0x70 a TMP117 at 0x48 on channel 3; each bridge's simulator plugged into a simulated USB."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.clock import SimClock
from drivers.sim.devices.mmc5983ma import MMC5983MASim
from drivers.sim.devices.tmp117 import TMP117Sim
from drivers.sim.transports.i2c_bus import FakeSMBus
from drivers.sim.transports.i2c_wire import I2CWire
from drivers.sim.world import DutTruth, World


@dataclass
class Bench:
    clock: SimClock
    world: World
    bus: FakeSMBus
    wire: I2CWire
    mmc: MMC5983MASim
    switch: Any


def bench() -> Bench:
    clock = SimClock()
    world = World(clock, ambient_nt=(20_000.0, -3_000.0, 42_000.0))
    world.add_dut("dut", DutTruth.random(np.random.default_rng(1), noise_nt=0.0))
    bus = FakeSMBus()
    mmc = MMC5983MASim(world, "dut")
    bus.attach(0x30, mmc)
    switch = bus.add_switch(0x70)
    switch.attach(3, 0x48, TMP117Sim(world, "dut"))
    return Bench(clock, world, bus, I2CWire(bus), mmc, switch)


def trimmed(report: bytes) -> bytes:
    """A report without its zero padding (at least 2 bytes), for comparing with the notes' bytes."""
    return report.rstrip(b"\x00").ljust(2, b"\x00")
