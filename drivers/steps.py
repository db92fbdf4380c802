"""Readings as steps, so that one thread can interleave the conversions of many devices.

A driver's `read_steps()` is a generator: it does its bus transfers, yields how many seconds it must wait
before its next transfer (a conversion, a SET/RESET settle, a status poll), and returns the reading.

    sample = run_steps(dut.read_steps(), clock)          # = dut.read(): the waits are slept in turn
    samples = interleave({"a": a.read_steps(), "b": b.read_steps()}, clock)

`interleave` resumes whichever device is due first, so N devices that each wait for a conversion take
about as long as one (their transfers still go one at a time: one bus is one lock).
"""

from __future__ import annotations

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
    """Run several devices' steps together: the one due first goes next. {key: reading}; the first
    error is raised after the other devices' steps are closed."""
    due: dict[Hashable, float] = {}
    results: dict[Hashable, Any] = {}

    def advance(key: Hashable) -> None:
        try:
            wait_s = next(steps[key]) if key not in due else steps[key].send(None)
        except StopIteration as done:
            due.pop(key, None)
            results[key] = done.value
            return
        due[key] = clock.now() + wait_s

    try:
        for key in steps:
            advance(key)
        while due:
            key = min(due, key=due.__getitem__)
            wait_s = due[key] - clock.now()
            if wait_s > 0:
                clock.sleep(wait_s)
            advance(key)
    except BaseException:
        for gen in steps.values():
            gen.close()
        raise
    return results
