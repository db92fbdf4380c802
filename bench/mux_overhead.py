"""Time per point for N MMC5983MA DUTs at 0x30 behind TCA9548A switches, against one DUT on the bus.

A point is one read() of every DUT in turn (SET/RESET pair and die temperature, the driver's defaults).
For N = 1, 2, 4, 8 (one switch) and 16 (two switches), on the register-level fake bus with a simulated
clock: wall time of our code per point; the waits the driver spends on the (simulated) clock per point;
the I2C bus time at 400 kHz per point, counted in bits from the transfers really made (the fake bus has
no timing model of its own), with the switch's share; and the resulting time per point on hardware
(waits + bus time; the DUTs are read one after the other).

    .venv/bin/python bench/mux_overhead.py [--points 200]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drivers.clock import SimClock
from drivers.mmc5983ma import MMC5983MA
from drivers.sim.devices.mmc5983ma import MMC5983MASim
from drivers.sim.transports.i2c_bus import FakeSMBus
from drivers.sim.world import DutTruth, World
from drivers.tca9548a import MuxedBus
from tests.helpers.smbus_doubles import RecordingSMBus

SCL_HZ = 400_000
START_STOP_BITS = 1  # a START, repeated START or STOP costs about one bit time
BYTE_BITS = 9  # 8 data bits + ACK/NACK
SWITCH_ADDRESSES = range(0x70, 0x78)


def transfer_bits(op: str, register: int | None, data: bytes) -> int:
    """Bits on the wire: one-byte transfer S addr byte P; register write S addr reg data P;
    register read S addr reg Sr addr data P."""
    n = len(data)
    if register is None:
        return 2 * START_STOP_BITS + (1 + n) * BYTE_BITS
    if op == "write":
        return 2 * START_STOP_BITS + (2 + n) * BYTE_BITS
    return 3 * START_STOP_BITS + (3 + n) * BYTE_BITS


def build(n_duts: int, muxed: bool) -> tuple[SimClock, RecordingSMBus, list[MMC5983MA]]:
    clock = SimClock()
    world = World(clock, ambient_nt=(20_000.0, -3_000.0, 42_000.0))
    fake = FakeSMBus()
    rec = RecordingSMBus(fake)
    duts = []
    for i in range(n_duts):
        name = f"dut{i + 1}"
        world.add_dut(name, DutTruth.random(np.random.default_rng(i)))
        if muxed:
            switch_address = 0x70 + i // 8
            if switch_address not in fake.chips:
                fake.add_switch(switch_address)
            fake.chips[switch_address].attach(i % 8, 0x30, MMC5983MASim(world, name))
            bus = MuxedBus(rec, switch_address, i % 8)
        else:
            fake.attach(0x30, MMC5983MASim(world, name))
            bus = rec
        duts.append(MMC5983MA(bus, name=name, clock=clock))
    for dut in duts:
        dut.connect()
    return clock, rec, duts


def run(n_duts: int, muxed: bool, points: int) -> str:
    clock, rec, duts = build(n_duts, muxed)
    for dut in duts:  # one warm-up point
        dut.read()
    rec.calls.clear()
    sim_start = clock.now()
    start = time.perf_counter()
    for _ in range(points):
        for dut in duts:
            dut.read()
    wall_ms = (time.perf_counter() - start) / points * 1e3
    waits_ms = (clock.now() - sim_start) / points * 1e3
    bits = [transfer_bits(c.op, c.register, c.data) for c in rec.calls]
    switch_bits = sum(b for b, c in zip(bits, rec.calls, strict=True) if c.address in SWITCH_ADDRESSES)
    bus_ms = sum(bits) / SCL_HZ / points * 1e3
    switch_ms = switch_bits / SCL_HZ / points * 1e3
    hw_ms = waits_ms + bus_ms
    label = f"{n_duts:2d} DUT{'s' if n_duts > 1 else ' '} {'muxed' if muxed else 'direct'}"
    return (
        f"{label:<16} per point: our code {wall_ms:6.2f} ms wall | waits {waits_ms:6.1f} ms | "
        f"I2C {bus_ms:5.2f} ms of which switch {switch_ms:4.2f} ms ({switch_ms / hw_ms:5.2%}) | "
        f"on hardware ~{hw_ms:6.1f} ms = {hw_ms / n_duts:5.2f} ms per DUT"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=200, help="points timed per configuration")
    args = parser.parse_args()
    print(run(1, False, args.points))
    for n in (1, 2, 4, 8, 16):
        print(run(n, True, args.points))


if __name__ == "__main__":
    main()
