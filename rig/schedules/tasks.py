"""The tasks a plan's points run as: generators of engine commands (rig/engine/commands.py), and nothing
else. What each command does to the rig is the runner's (rig/run/); what the run itself does (events, more
tasks, an early stop) is the engine's. A schedule never touches either.

Step and dwell (rig/schedules/steps.py), a point of a temperature step:

    SetChamber(setpoint, ramp)   when the step changes, or the point is retaken after a hold or a pause
    WaitStable(setpoint)         every DUT's own temperature stable; its statistics go with each point
    MoveField, Settle, CollectPoint (a DUT leaving its settled temperature by HOLD_BAND_FACTOR bands holds
    the point), Checkpoint

A schedule that samples while the temperature moves (a ramp, a designed or a sequential schedule: legs x
sweeps x fields, rig/schedules/ramp.py, designed.py, sequential.py), a point of a leg:

    StartRamp(leg_end_c, rate)   when its leg is not yet commanded (first point of a leg, a retake after a
                                 hold or a pause, a resume): the chamber ramps from wherever the air is
    AwaitAir(nominal_c, rising)  the sweep waits until the air has reached its nominal temperature (at
                                 once when the air is already past it: a resumed ramp goes on from where
                                 the chamber is, it never goes back to the range start)
    MoveField, Settle, CollectPoint (no temperature band: the temperature moves), Checkpoint

The very first point of a ramp first brings the DUTs to the range start (SetChamber + WaitStable).

Stop when good enough (`stop_when`): after the last point of a step or a sweep, ReadTargets; once every
DUT's live T24 fit meets its targets (and, on a designed plan, every DUT has come within the plan's band of
both ends of its range), an Event and a RequestStop.
"""

from __future__ import annotations

import functools
from collections.abc import Generator
from typing import Any

from rig import config as cfg
from rig.core.points import Point, RampPoint
from rig.engine.commands import (
    AwaitAir,
    Checkpoint,
    CollectPoint,
    Event,
    MoveField,
    ReadTargets,
    RequestStop,
    SetChamber,
    Settle,
    StartRamp,
    Task,
    WaitStable,
)
from rig.engine.stability import criteria_of
from rig.session.events import Kind, Reason

HOLD_BAND_FACTOR = 2.0  # during a point, a DUT may drift this many stability bands before the point is held
Commands = Generator[Any, Any, None]


class TargetsWatch:
    """Stop when good enough: after the last point of a sweep (or temperature step), the run stops once every
    DUT's live T24 fit meets the plan's `stop_when` targets (calib/design/targets.py); on a designed plan,
    whose ends are held until every DUT is close to them, also not before every DUT's temperature has come
    within the plan's band of both ends of its range (else the calibration would extrapolate, and
    acceptance fails it: precision reached early is no reason to leave an end unvisited). A ramp cannot
    promise that: its DUTs lag the air; acceptance judges what it covered."""

    def __init__(self, plan: cfg.Plan, points: list[Point]):
        self.targets = plan.stop_when
        self.group_ends = {p.id for p, nxt in zip(points, [*points[1:], None], strict=True)
                           if nxt is None or nxt.temp_index != p.temp_index}
        temperatures = plan.temperatures
        self.range_c = temperatures.covered_c() if getattr(temperatures, "mode", None) == "designed" else None
        self.band_c = temperatures.band_c()
        self.seen_c: dict[str, tuple[float, float]] = {}  # each DUT's lowest and highest temperature

    def short_of_range(self, temps_c: dict[str, float]) -> list[str]:
        """The DUTs whose temperatures have not yet come within band_c of both ends of the range."""
        for dut, temp in temps_c.items():
            low, high = self.seen_c.get(dut, (temp, temp))
            self.seen_c[dut] = (min(low, temp), max(high, temp))
        if self.range_c is None:
            return []
        lo, hi = self.range_c
        return [dut for dut, (low, high) in self.seen_c.items()
                if low > lo + self.band_c or high < hi - self.band_c]

    def after(self, point_id: str, temps_c: dict[str, float]) -> Commands:
        """The commands after a point is recorded: at a group's end, the targets read and the stop asked."""
        short = self.short_of_range(temps_c)
        if point_id not in self.group_ends or short:
            return
        statuses = yield ReadTargets(self.targets)
        if not statuses or not all(s.met for s in statuses.values()):
            return
        worst = max(statuses, key=lambda d: statuses[d].worst_ratio)
        message = (f"stop_when targets met by every DUT after point {point_id} (closest: {worst} "
                   f"{statuses[worst].worst} at {statuses[worst].worst_ratio:.2f} of its target)")
        yield Event(Kind.RUN, message, Reason.TARGETS_MET, point_id,
                    {"ratios": {d: s.ratios for d, s in statuses.items()}})
        yield RequestStop(message, Reason.TARGETS_MET)


class StepTasks:
    """The tasks of a step-and-dwell plan: a temperature step's first point waits for stability, and every
    point of the step records that wait's statistics."""

    def __init__(self, plan: cfg.Plan, station: cfg.Station, points: list[Point]):
        self.points = points
        self.watch = TargetsWatch(plan, points) if plan.stop_when else None
        self.stable_at_c: float | None = None  # the set point the DUTs were last found stable at
        self.stability: dict = {}

    def tasks(self) -> list[Task]:
        return [Task(p.id, functools.partial(self.commands, p)) for p in self.points]

    def commands(self, point: Point, retake: bool) -> Commands:
        criteria = criteria_of(point.stability)
        if retake or self.stable_at_c != point.setpoint_c:
            self.stable_at_c = None
            yield SetChamber(point.setpoint_c, point.ramp_c_per_min)
            self.stability = yield WaitStable(point.setpoint_c, criteria)
            self.stable_at_c = point.setpoint_c
        yield MoveField(point.command)
        yield Settle(point.settle_s)
        collected = yield CollectPoint(point, criteria.band_c * HOLD_BAND_FACTOR, self.stability)
        yield Checkpoint(point.id)
        if self.watch is not None:
            yield from self.watch.after(point.id, collected.temps_c)


class MovingTasks:
    """The tasks of a plan that samples while the temperature moves (see the module docstring)."""

    def __init__(self, plan: cfg.Plan, station: cfg.Station, points: list[RampPoint]):
        self.points = points
        self.watch = TargetsWatch(plan, points) if plan.stop_when else None
        # a ramp starts from a stable range start; designed and sequential legs ramp from wherever the air is
        self.settle_at_start = plan.ramp is not None
        # the chamber's limit: how the range start is reached
        self.max_ramp_c_per_min = station.chamber.limits.max_ramp_c_per_min
        self.leg: int | None = None  # the leg the chamber is ramping for; None until commanded

    def tasks(self) -> list[Task]:
        return [Task(p.id, functools.partial(self.commands, p)) for p in self.points]

    def leg_commands(self, point: RampPoint, retake: bool) -> Commands:
        """Up to the point's air: its leg commanded when it is not, then AwaitAir; returns AwaitAir's
        statistics."""
        if retake or self.leg != point.leg:
            self.leg = None
            if point.index == 0 and self.settle_at_start:  # the DUTs begin the first leg at its start
                yield SetChamber(point.leg_start_c, self.max_ramp_c_per_min)
                yield WaitStable(point.leg_start_c, criteria_of(point.stability))
            yield StartRamp(point.leg_end_c, point.ramp_c_per_min)
            self.leg = point.leg
        return (yield AwaitAir(point.setpoint_c, point.rising, point.stability.max_wait_s))

    def commands(self, point: RampPoint, retake: bool) -> Commands:
        stability = yield from self.leg_commands(point, retake)
        yield MoveField(point.command)
        yield Settle(point.settle_s)
        collected = yield CollectPoint(point, None, stability)
        yield Checkpoint(point.id)
        if self.watch is not None:
            yield from self.watch.after(point.id, collected.temps_c)

