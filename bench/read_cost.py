"""The Python cost of reading a simulated station, without a campaign around it: on
configs/stations/sim-64.yaml (or --station) with the demo plan's SET/RESET pairs, the wall, CPU (the
process's) and simulated milliseconds of one sample of every DUT (rig/devices/interleave.py read_all: the
I2C DUTs interleaved, the serial ones in their threads), of the I2C DUTs alone, of every temperature
sensor (read_all: also how a stability poll reads them now), and of the same sources read one after
another (how rig/run/runner.py's stability poll read them before); with the I2C switch control bytes
written per call. --profile N prints the N costliest functions of the DUTs' reading (cProfile).

    python bench/read_cost.py [--station PATH] [--samples 20] [--profile 25]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from drivers.sim.transports.i2c_bus import switch_writes  # noqa: E402
from rig import config as cfg  # noqa: E402
from rig.devices.build import open_rig  # noqa: E402
from rig.devices.interleave import read_all  # noqa: E402

STATION = REPO / "configs" / "stations" / "sim-64.yaml"
DEMO = REPO / "configs" / "plans" / "demo.yaml"


def measure(rig, what, samples: int) -> tuple[float, float, float, float]:
    """(wall ms, CPU ms of the process, simulated ms, switch writes) per call of what()."""
    clock = rig.clock
    writes0, sim0 = switch_writes(rig.devices()), clock.now()
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(samples):
        what()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    n = samples
    writes = switch_writes(rig.devices()) - writes0
    return wall * 1e3 / n, cpu * 1e3 / n, (clock.now() - sim0) * 1e3 / n, writes / n


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--station", type=Path, default=STATION)
    parser.add_argument("--samples", type=int, default=20)
    parser.add_argument("--profile", type=int, default=0)
    args = parser.parse_args()
    rig = open_rig(cfg.load_station(args.station), cfg.load_plan(DEMO))
    try:
        clock = rig.clock
        i2c = {n: d for n, d in rig.duts.items() if hasattr(d, "read_steps")}
        sources = list({s.name: s for s in rig.temp_sources.values()}.values())
        cases = {
            "every DUT (read_all)": lambda: read_all(rig.duts, clock),
            "the I2C DUTs alone": lambda: read_all(i2c, clock),
            "every temperature sensor (read_all)": lambda: read_all(rig.temp_sensors, clock),
            "the sources one after another": lambda: [s.read() for s in sources],
        }
        read_all(rig.duts, clock)  # first readings connect lazily
        print(f"{args.station.name}: {len(rig.duts)} DUTs ({len(i2c)} on I2C), {len(rig.temp_sensors)} "
              f"sensors; per call, {args.samples} calls")
        print(f"{'':40} {'wall ms':>8} {'CPU ms':>8} {'sim ms':>8} {'switch writes':>14}")
        for label, what in cases.items():
            wall, cpu, sim, writes = measure(rig, what, args.samples)
            print(f"{label:40} {wall:8.2f} {cpu:8.2f} {sim:8.1f} {writes:14.1f}")
        if args.profile:
            prof = cProfile.Profile()
            prof.enable()
            for _ in range(args.samples):
                read_all(rig.duts, clock)
            prof.disable()
            pstats.Stats(prof).sort_stats("tottime").print_stats(args.profile)
    finally:
        rig.close()


if __name__ == "__main__":
    main()
