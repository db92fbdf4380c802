"""Read every DUT once, overlapping what they wait for, so N DUTs take far less than N times one.

    samples = read_all(rig.duts, rig.clock)        # {dut name: FieldSample}, in the duts' order

Drivers that offer `read_steps()` (drivers/steps.py: MMC5983MA, HMC5883L) are interleaved in this thread:
each starts its conversion, and whichever is due next is resumed (one bus is one lock, so transfers still
go one at a time). The others (the serial magnetometers, which wait for their line) are read in worker
threads meanwhile, one per device; a shared serial line's lock keeps its devices' exchanges apart.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any

from drivers.clock import Clock
from drivers.steps import interleave


def read_all(duts: dict[str, Any], clock: Clock) -> dict[str, Any]:
    stepped = {name: dev for name, dev in duts.items() if hasattr(dev, "read_steps")}
    blocking = {name: dev for name, dev in duts.items() if name not in stepped}
    if not blocking:
        got = interleave({name: dev.read_steps() for name, dev in stepped.items()}, clock)
        return {name: got[name] for name in duts}
    with ThreadPoolExecutor(max_workers=len(blocking), thread_name_prefix="dut-read") as pool:
        futures = {name: pool.submit(dev.read) for name, dev in blocking.items()}
        got = interleave({name: dev.read_steps() for name, dev in stepped.items()}, clock)
        got.update({name: future.result() for name, future in futures.items()})
    return {name: got[name] for name in duts}
