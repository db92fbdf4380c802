"""A chamber without a ramp of its own gets its set point stepped at the ramp's pace
(rig/run/ramping.py)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from drivers.clock import SimClock
from rig.engine.commands import StartRamp
from rig.engine.executor import RunStatus
from rig.run.ramping import STEP_C, RampHandlers


class SteppedChamber:
    """Records set points; no ramp register (ramps_setpoint False), like the legacy F4."""

    name = "chamber"
    ramps_setpoint = False

    def __init__(self, air_c: float):
        self.air_c = air_c
        self.setpoints: list[float] = []

    def read(self):
        return SimpleNamespace(air_c=self.air_c)

    def set(self, setpoint_c: float) -> None:
        self.setpoints.append(setpoint_c)

    def set_ramp_rate(self, c_per_min: float) -> None:
        raise AssertionError("a stepped chamber is never given a ramp rate")


def test_a_chamber_without_ramps_is_stepped_at_the_rate_from_where_the_air_is():
    clock = SimClock()
    chamber = SteppedChamber(air_c=22.0)
    runner = SimpleNamespace(rig=SimpleNamespace(chamber=chamber, clock=clock), status=RunStatus())
    mode = RampHandlers(runner)
    mode.start_ramp(StartRamp(end_c=30.0, rate_c_per_min=2.0))
    assert chamber.setpoints == [pytest.approx(22.0 + STEP_C)]  # one increment ahead of the air
    for _ in range(60):  # 10 minutes in 10 s slices
        clock.sleep(10.0)
        mode._step_setpoint()
    steps = chamber.setpoints
    assert all(0 < b - a <= STEP_C + 2.0 / 6 for a, b in zip(steps, steps[1:], strict=False))
    assert steps[-1] == 30.0  # 8 degC at 2 degC/min: the end after 4 minutes, and no further
    assert steps.index(30.0) == len(steps) - 1
