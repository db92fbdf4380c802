"""Per-sample cost of the I2C drivers, set against what each device itself allows.

For each device: wall time per read() with a simulated clock (so waits cost nothing), twice: on the
register-level fake bus (driver + transport + simulator and world physics), and with the bytes of a
recorded read() replayed (driver + transport alone); the I2C bus time of the same read() at 400 kHz
(bits counted from the transfers it really made); and the device's own limit (conversion time and
output data rate).

    /work/venv/bin/python bench/i2c_overhead.py [--reads 2000]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers import hmc5883l, mmc5983ma, tmp117
from drivers.base import Device
from drivers.clock import SimClock
from drivers.sim.devices.hmc5883l import HMC5883LSim
from drivers.sim.devices.mmc5983ma import MMC5983MASim
from drivers.sim.devices.tmp117 import TMP117Sim
from drivers.sim.transports.i2c_bus import FakeSMBus
from drivers.sim.world import DutTruth, World
from tests.helpers.smbus_doubles import RecordingSMBus, ScriptedSMBus

SCL_HZ = 400_000
START_STOP_BITS = 1  # a START, repeated START or STOP costs about one bit time
BYTE_BITS = 9  # 8 data bits + ACK/NACK


def transfer_bits(op: str, data: bytes) -> int:
    """Bits on the wire for one register transfer.

    write: S, addr+W, reg, n data bytes, P.   read: S, addr+W, reg, Sr, addr+R, n data bytes, P."""
    n = len(data)
    if op == "write":
        return 2 * START_STOP_BITS + (2 + n) * BYTE_BITS
    return 3 * START_STOP_BITS + (3 + n) * BYTE_BITS


@dataclass
class Case:
    label: str
    make: Callable[[FakeSMBus, SimClock], Device]
    attach: Callable[[FakeSMBus, World], None]
    conversion_s: float  # time the device needs for one read(), by the datasheet
    max_rate_hz: float  # the device's own rate limit for this kind of read


def mmc_sim(bus: FakeSMBus, world: World) -> None:
    bus.attach(mmc5983ma.ADDRESS, MMC5983MASim(world, "dut"))


MMC_MEASURE_S = mmc5983ma.MEASUREMENT_TIME_S[0]
CASES = [
    Case(
        "MMC5983MA single",
        lambda bus, clock: mmc5983ma.MMC5983MA(
            bus, name="dut", clock=clock, set_reset=False, read_temperature=False
        ),
        mmc_sim,
        MMC_MEASURE_S,
        mmc5983ma.MAX_ODR_HZ[0],
    ),
    Case(
        "MMC5983MA SET/RESET",
        lambda bus, clock: mmc5983ma.MMC5983MA(
            bus, name="dut", clock=clock, set_reset=True, read_temperature=False
        ),
        mmc_sim,
        2 * (MMC_MEASURE_S + mmc5983ma.SET_RESET_WAIT_S),
        mmc5983ma.MAX_ODR_HZ[0] / 2,
    ),
    Case(
        "HMC5883L single",
        lambda bus, clock: hmc5883l.HMC5883L(bus, name="dut", clock=clock),
        lambda bus, world: bus.attach(hmc5883l.ADDRESS, HMC5883LSim(world, "dut")),
        hmc5883l.MEASUREMENT_TIME_S,
        1 / hmc5883l.MEASUREMENT_TIME_S,
    ),
    Case(
        "TMP117 one-shot x8",
        lambda bus, clock: tmp117.TMP117(bus, name="dut", clock=clock, averaging=8),
        lambda bus, world: bus.attach(tmp117.ADDRESS, TMP117Sim(world, "dut")),
        tmp117.active_time_s(8),
        1 / tmp117.active_time_s(8),
    ),
]


def time_reads(device: Device, reads: int) -> float:
    """Mean wall time of read() in microseconds."""
    start = time.perf_counter()
    for _ in range(reads):
        device.read()
    return (time.perf_counter() - start) / reads * 1e6


def run(case: Case, reads: int) -> str:
    clock = SimClock()
    world = World(clock, ambient_nt=(20_000.0, -3_000.0, 42_000.0))
    world.add_dut("dut", DutTruth.random(np.random.default_rng(0)))
    fake = FakeSMBus()
    case.attach(fake, world)
    recorder = RecordingSMBus(fake)
    device = case.make(recorder, clock)
    device.connect()
    device.read()  # one-time work, e.g. the HMC's discarded measurement after the gain write
    setup = recorder.transcript()
    recorder.calls.clear()
    device.read()
    per_read = recorder.transcript()
    address = recorder.calls[0].address
    bits = sum(transfer_bits(op, data) for op, _, data in per_read)
    bus_us = bits / SCL_HZ * 1e6

    # driver + transport + simulator: the fake bus with the world behind it
    device = case.make(fake, clock)
    device.connect()
    device.read()
    with_sim_us = time_reads(device, reads)
    # driver + transport alone: the recorded bytes replayed
    script = setup + per_read * reads
    device = case.make(ScriptedSMBus(address, script), clock)
    device.connect()
    device.read()
    driver_us = time_reads(device, reads)

    period_us = 1e6 / case.max_rate_hz
    return (
        f"{case.label:<20} read() {with_sim_us:6.1f} us with simulator, {driver_us:5.1f} us driver alone "
        f"({driver_us / period_us:6.2%} of period) | I2C @400 kHz: {len(per_read)} transfers, {bits:3d} bits "
        f"= {bus_us:5.1f} us | device: conversion {case.conversion_s * 1e3:5.1f} ms, "
        f"max {case.max_rate_hz:5.1f} Hz ({period_us:6.0f} us)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reads", type=int, default=2000, help="read() calls timed per device")
    args = parser.parse_args()
    for case in CASES:
        print(run(case, args.reads))


if __name__ == "__main__":
    main()
