"""Readings as steps, so that one thread can interleave the conversions of many devices.

A driver's `read_steps()` is a generator: it does its bus transfers, yields how many seconds it must wait
before its next transfer (a conversion, a SET/RESET settle, a status poll), and returns the reading.

    sample = run_steps(dut.read_steps(), clock)          # = dut.read(): the waits are slept in turn
    samples = interleave({"a": a.read_steps(), "b": b.read_steps()}, clock)

`interleave` resumes whichever device is due first, so N devices that each wait for a conversion take
about as long as one (their transfers still go one at a time: one bus is one lock).
"""

from __future__ import annotations

import heapq
from collections.abc import Generator, Hashable
from typing import Any, TypeVar

from drivers.clock import Clock

T = TypeVar("T")
Steps = Generator[float, None, T]


def run_steps(steps: Steps[T], clock: Clock) -> T:
    """Run one device's steps alone, sleeping each wait on `clock`."""
    try:
        wait_s = next(steps)
        while True:
            clock.sleep(wait_s)
            wait_s = steps.send(None)
    except StopIteration as done:
        return done.value


def interleave(steps: dict[Hashable, Steps[Any]], clock: Clock) -> dict[Hashable, Any]:
    """Run several devices' steps together: the one due first goes next (of several due at the same
    instant, the first in `steps`' order). {key: reading}; the first error is raised after the other
    devices' steps are closed."""
    order = {key: n for n, key in enumerate(steps)}
    queue: list[tuple[float, int, Hashable]] = []  # (due, order, key): a heap, for many devices
    results: dict[Hashable, Any] = {}

    def advance(key: Hashable, started: bool) -> None:
        try:
            wait_s = steps[key].send(None) if started else next(steps[key])
        except StopIteration as done:
            results[key] = done.value
            return
        heapq.heappush(queue, (clock.now() + wait_s, order[key], key))

    try:
        for key in steps:
            advance(key, False)
        while queue:
            due, _, key = heapq.heappop(queue)
            wait_s = due - clock.now()
            if wait_s > 0:
                clock.sleep(wait_s)
            advance(key, True)
    except BaseException:
        for gen in steps.values():
            gen.close()
        raise
    return results
