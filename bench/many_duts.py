"""Time per point for 1, 2, 4, 8 and 16 simulated DUTs: each DUT read in turn (before) against the
interleaved reading the campaign does (rig/interleave.py, after).

A "point" here is what collect_point does per point: SAMPLES times (every temperature sensor, the coil
readback, every DUT). The DUTs come from configs/stations/sim-16.yaml (MMC5983MA behind two TCA9548A
switches, serial magnetometers on one shared line), taken alternately so every N mixes both kinds.
Prints wall time and simulated time per point.

    .venv/bin/python bench/many_duts.py
"""

from __future__ import annotations

import time
from pathlib import Path

from rig import config as cfg
from rig.interleave import read_all
from rig.station import open_rig

STATION = Path(__file__).resolve().parent.parent / "configs" / "stations" / "sim-16.yaml"
SAMPLES = 10
COUNTS = (1, 2, 4, 8, 16)


def subset(station: cfg.Station, n: int) -> cfg.Station:
    mmcs = [d for d in station.duts if d.device_type == "mmc5983ma"]
    serials = [d for d in station.duts if d.device_type != "mmc5983ma"]
    mixed = [d for pair in zip(mmcs, serials, strict=False) for d in pair]
    mixed += mmcs[len(serials):] + serials[len(mmcs):]
    names = {d.name for d in mixed[:n]}
    data = station.model_dump(mode="json", exclude_none=True)
    data["duts"] = [d for d in data["duts"] if d["name"] in names]
    data["temperature_sensors"] = [s for s in data["temperature_sensors"] if s["beside"] in names]
    return cfg.Station.model_validate(data)


def one_point(rig, interleaved: bool) -> tuple[float, float]:
    clock = rig.clock
    wall0, sim0 = time.perf_counter(), clock.now()
    for _ in range(SAMPLES):
        if interleaved:
            read_all(rig.temp_sensors, clock)
            rig.field_source.read()
            read_all(rig.duts, clock)
        else:
            for sensor in rig.temp_sensors.values():
                sensor.read()
            rig.field_source.read()
            for dev in rig.duts.values():
                dev.read()
    return time.perf_counter() - wall0, clock.now() - sim0


def main() -> None:
    station = cfg.load_station(STATION)
    print(f"{SAMPLES} samples per point; seconds per point (median of 3)")
    print(f"{'DUTs':>4}  {'wall before':>11}  {'wall after':>10}  {'sim before':>10}  {'sim after':>9}")
    for n in COUNTS:
        rig = open_rig(subset(station, n))
        try:
            rows = {mode: sorted(one_point(rig, mode) for _ in range(3))[1] for mode in (False, True)}
        finally:
            rig.close()
        (wb, sb), (wa, sa) = rows[False], rows[True]
        print(f"{n:>4}  {wb:>11.3f}  {wa:>10.3f}  {sb:>10.3f}  {sa:>9.3f}")


if __name__ == "__main__":
    main()
