"""Read every DUT once, overlapping what they wait for, so N DUTs take far less than N times one.

    samples = read_all(rig.duts, rig.clock)        # {dut name: FieldSample}, in the duts' order

Drivers that offer `read_steps()` (drivers/steps.py: MMC5983MA, HMC5883L) are interleaved in this thread:
each starts its conversion, and whichever is due next is resumed (one bus is one lock, so transfers still
go one at a time). The others (the serial magnetometers, which wait for their line) are read in worker
threads meanwhile, one per device; a shared serial line's lock keeps its devices' exchanges apart. On a
simulated clock no device waits on its wire, so they are read after the interleave, one after another in
this thread: beside it, or in threads of their own, they would only take turns at the interpreter, and
cost more than they overlap. The workers are kept between calls (starting threads for every sample cost
more than a serial reading), and every reading has ended, done or failed, before read_all returns or
raises.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor, wait
from typing import Any

from drivers.clock import Clock
from drivers.steps import interleave

_workers: ThreadPoolExecutor | None = None
_workers_size = 0
_workers_lock = threading.Lock()


def _pool(size: int) -> ThreadPoolExecutor:
    """Worker threads for `size` readings at once, kept for the next call (a bigger pool when needed)."""
    global _workers, _workers_size
    with _workers_lock:
        if _workers is None or _workers_size < size:
            if _workers is not None:
                _workers.shutdown(wait=False)
            _workers, _workers_size = ThreadPoolExecutor(size, thread_name_prefix="dut-read"), size
        return _workers


def read_all(duts: dict[str, Any], clock: Clock) -> dict[str, Any]:
    stepped = {name: dev for name, dev in duts.items() if hasattr(dev, "read_steps")}
    blocking = {name: dev for name, dev in duts.items() if name not in stepped}
    # on a simulated clock nothing waits on a wire: the blocking ones go after, here (threads would only
    # share the GIL)
    if not blocking or getattr(clock, "simulated", False):
        got = interleave({name: dev.read_steps() for name, dev in stepped.items()}, clock)
        got.update({name: dev.read() for name, dev in blocking.items()})
        return {name: got[name] for name in duts}
    pool = _pool(len(blocking))
    futures = {name: pool.submit(dev.read) for name, dev in blocking.items()}
    try:
        got = interleave({name: dev.read_steps() for name, dev in stepped.items()}, clock)
    finally:
        wait(futures.values())  # no reading goes on behind a failure
    got.update({name: future.result() for name, future in futures.items()})
    return {name: got[name] for name in duts}
