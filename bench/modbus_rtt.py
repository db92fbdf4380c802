"""Modbus round-trip time on loopback: the chamber and coil drivers against their pymodbus simulators.

    python bench/modbus_rtt.py [--requests 500] [--framing tcp|rtu]

Prints median and 95th percentile in ms for
  - chamber read temperature: one FC03 of the F4T chamber temperature (27586, float32)
  - coil set + readback: CoilController.set() (two FC16) then read() (one FC03)
The request count is bounded; everything runs on 127.0.0.1 and stops by itself.
"""

from __future__ import annotations

import argparse
import statistics
import time

from drivers.chamber import F4T_CHAMBER_TEMP
from drivers.clock import SimClock
from drivers.coils import CoilController
from drivers.sim.devices.chamber import ChamberSim
from drivers.sim.devices.coils import CoilSim
from drivers.sim.world import World
from drivers.transports.modbus import ModbusTransport
from drivers.watlow import WatlowF4T


def link(name: str, port: int, framing: str, clock) -> ModbusTransport:
    if framing == "rtu":
        return ModbusTransport(
            name=name, serial_port=f"socket://127.0.0.1:{port}", baudrate=115200, timeout_s=1.0, clock=clock
        )
    return ModbusTransport(name=name, host="127.0.0.1", port=port, timeout_s=1.0, clock=clock)


def timed_ms(op, n: int) -> list[float]:
    op()  # connect and warm up
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        op()
        times.append((time.perf_counter() - t0) * 1000.0)
    return times


def summary(label: str, times: list[float]) -> str:
    p95 = statistics.quantiles(times, n=20)[-1]
    return f"{label:<34} n={len(times):4d}  median {statistics.median(times):6.2f} ms  p95 {p95:6.2f} ms"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requests", type=int, default=500)
    parser.add_argument("--framing", choices=("tcp", "rtu"), default="tcp")
    args = parser.parse_args()
    n = max(20, min(args.requests, 5000))
    clock = SimClock()
    world = World(clock)
    with ChamberSim(world, "f4t", framing=args.framing) as chamber_sim:
        chamber = WatlowF4T(
            link("chamber", chamber_sim.port, args.framing, clock),
            name="chamber",
            clock=clock,
            min_setpoint_c=-40,
            max_setpoint_c=125,
            max_ramp_c_per_min=5,
            safe_setpoint_c=25,
        )
        chamber.connect()
        times = timed_ms(lambda: chamber.transport.read_float32(F4T_CHAMBER_TEMP, word_order="little"), n)
        print(summary(f"chamber read temperature ({args.framing})", times))
        chamber.close()
    with CoilSim(world, framing=args.framing) as coil_sim:
        coils = CoilController(
            link("coils", coil_sim.port, args.framing, clock), name="coils", clock=clock, max_current_a=1.0
        )
        coils.connect()
        currents = iter([(0.1 * (i % 5), -0.05, 0.02) for i in range(n + 1)])

        def set_and_read():
            coils.set(next(currents))
            coils.read()

        print(summary(f"coil set + readback ({args.framing})", timed_ms(set_and_read, n)))
        coils.safe_state()
        coils.close()


if __name__ == "__main__":
    main()
