"""drivers/steps.py: one device's steps run alone, several interleaved on one simulated clock."""

from __future__ import annotations

import pytest

from drivers.clock import SimClock
from drivers.steps import interleave, run_steps


def device(name: str, waits: list[float], log: list[tuple[str, float]], clock: SimClock):
    """A device that notes (name, time) at each of its transfers and waits `waits` in between."""
    def steps():
        for wait_s in waits:
            log.append((name, clock.now()))
            yield wait_s
        log.append((name, clock.now()))
        return name.upper()
    return steps()


def test_the_device_due_first_goes_next_and_ties_keep_the_given_order():
    clock = SimClock(0.0)
    log: list[tuple[str, float]] = []
    got = interleave({"a": device("a", [0.008, 0.001], log, clock), "b": device("b", [0.001], log, clock),
                      "c": device("c", [0.001, 0.008], log, clock)}, clock)
    assert got == {"a": "A", "b": "B", "c": "C"}
    assert [n for n, _ in log] == ["a", "b", "c", "b", "c", "a", "a", "c"]  # a and c due at 9 ms: a first
    assert clock.now() == pytest.approx(0.009)  # the longest chain, not the sum of them


def test_an_error_closes_the_other_devices_and_is_raised():
    clock = SimClock(0.0)
    closed = []

    def fine():
        try:
            yield 1.0
        finally:
            closed.append("fine")

    def broken():
        yield 0.5
        raise RuntimeError("bus fault")

    with pytest.raises(RuntimeError, match="bus fault"):
        interleave({"fine": fine(), "broken": broken()}, clock)
    assert closed == ["fine"]


def test_run_steps_sleeps_each_wait():
    clock = SimClock(0.0)
    log: list[tuple[str, float]] = []
    assert run_steps(device("a", [0.25, 0.5], log, clock), clock) == "A"
    assert log == [("a", 0.0), ("a", 0.25), ("a", 0.75)]
