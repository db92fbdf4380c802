"""The tasks of every schedule that samples while the temperature moves (a ramp, a designed or a
sequential schedule), and stop-when-good-enough after each sweep.

The points come from the schedule (rig/schedules/ramp.py, designed.py, sequential.py: legs x sweeps x
fields); a sequential schedule adds its decisions (rig/schedules/sequential_run.py). A point of a leg:

    StartRamp(leg_end_c, rate)   when its leg is not yet commanded (first point of a leg, a retake after a
                                 hold or a pause, a resume): the chamber ramps from wherever the air is
    AwaitAir(nominal_c, rising)  the sweep waits until the air has reached its nominal temperature (at
                                 once when the air is already past it: a resumed ramp goes on from where
                                 the chamber is, it never goes back to the range start)
    MoveField, Settle, CollectPoint (no temperature band: the temperature moves), Checkpoint

The very first point of the plan first brings the DUTs to the range start (SetChamber + WaitStable).
A chamber that ramps its set point itself (`ramps_setpoint`, the F4T) gets one ramp command per leg; any
other chamber gets its set point stepped by STEP_C at the ramp's pace, ahead of the air, at every
AwaitAir (which every point passes through every few seconds).

Only the engine pauses, holds, retakes and ends safe; these handlers raise Hold like the others.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Generator
from dataclasses import dataclass
from typing import Any

from rig.core.points import RampPoint
from rig.engine.commands import (
    AwaitAir,
    Checkpoint,
    CollectPoint,
    Hold,
    MoveField,
    SetChamber,
    Settle,
    StartRamp,
    Task,
    WaitStable,
)
from rig.engine.stability import criteria_of
from rig.session.events import Kind, Reason

log = logging.getLogger("magrig.ramp")

AIR_TOLERANCE_C = 0.2  # the air counts as at a sweep's nominal temperature this close to it
STEP_C = 0.5  # set point increment for a chamber that cannot ramp by itself
MAX_POLL_S = 10.0


@dataclass
class _Stepping:
    """A set point moved by hand at the ramp's pace (chambers without a ramp of their own)."""

    t0: float
    from_c: float
    end_c: float
    rate_c_per_min: float
    written_c: float

    def due_c(self, t: float) -> float:
        span = abs(self.end_c - self.from_c)
        sign = 1.0 if self.end_c > self.from_c else -1.0
        return self.from_c + sign * min(self.rate_c_per_min * (t - self.t0) / 60.0 + STEP_C, span)


class RampMode:
    """The ramp part of a CampaignRunner: its tasks and the handlers of StartRamp and AwaitAir."""

    def __init__(self, runner, *, settle_at_start: bool = True):
        self.runner = runner
        self.settle_at_start = settle_at_start  # a ramp starts from a stable range start; designed legs
        # start ramping from wherever the air is
        self.leg: int | None = None  # the leg the chamber is ramping for; None until commanded
        self.stepping: _Stepping | None = None
        self.rate_c_per_min = 1.0  # of the leg being ramped

    def tasks(self) -> list[Task]:
        return [Task(p.id, functools.partial(self.point_commands, p)) for p in self.runner.points]

    def handlers(self) -> dict:
        return {StartRamp: self.start_ramp, AwaitAir: self.await_air}

    def point_commands(self, point: RampPoint, retake: bool) -> Generator[Any, Any, None]:
        if retake or self.leg != point.leg:
            self.leg = None
            if point.index == 0 and self.settle_at_start:  # the DUTs begin the first leg at its start
                limit = self.runner.rig.station.chamber.limits.max_ramp_c_per_min
                yield SetChamber(point.leg_start_c, limit)
                yield WaitStable(point.leg_start_c, criteria_of(point.stability))
            yield StartRamp(point.leg_end_c, point.ramp_c_per_min)
            self.leg = point.leg
        self.runner._stability_stats = yield AwaitAir(point.setpoint_c, point.rising,
                                                   point.stability.max_wait_s)
        yield MoveField(point.command)
        yield Settle(point.settle_s)
        yield CollectPoint(point, None)
        yield Checkpoint(point.id)

    # --- handlers ---------------------------------------------------------------------------------
    def start_ramp(self, cmd: StartRamp) -> None:
        chamber, clock = self.runner.rig.chamber, self.runner.rig.clock
        air_c = chamber.read().air_c
        self.rate_c_per_min = cmd.rate_c_per_min
        if getattr(chamber, "ramps_setpoint", False):
            chamber.set_ramp_rate(cmd.rate_c_per_min)
            chamber.set(cmd.end_c)
            self.stepping = None
        else:
            self.stepping = _Stepping(clock.now(), air_c, cmd.end_c, cmd.rate_c_per_min, air_c)
            self._step_setpoint()
        self.runner.status.thermal = f"ramp {air_c:.1f} -> {cmd.end_c:g} degC at {cmd.rate_c_per_min:g}/min"
        log.info("ramp from %.2f to %g degC at %g degC/min", air_c, cmd.end_c, cmd.rate_c_per_min)

    def _step_setpoint(self) -> None:
        s = self.stepping
        if s is None:
            return
        due = s.due_c(self.runner.rig.clock.now())
        if abs(due - s.written_c) >= STEP_C or (due == s.end_c and s.written_c != s.end_c):
            self.runner.rig.chamber.set(due)
            s.written_c = due

    def await_air(self, cmd: AwaitAir) -> dict:
        runner, clock = self.runner, self.runner.rig.clock
        start = clock.now()
        while True:
            self._step_setpoint()
            runner._check_chamber()  # Hold on an alarm; updates status.chamber_c
            air = float(runner.status.chamber_c)
            off = cmd.nominal_c - air if cmd.rising else air - cmd.nominal_c  # > 0: not there yet
            if off <= AIR_TOLERANCE_C:
                return {"nominal_c": cmd.nominal_c, "air_c": air, "waited_s": clock.now() - start}
            if clock.now() - start > cmd.max_wait_s:
                raise Hold(f"chamber air {air:.2f} degC did not reach {cmd.nominal_c:g} degC within "
                           f"{cmd.max_wait_s:g} s", code=Reason.STABILITY_TIMEOUT,
                           device=runner.rig.chamber.name)
            runner.status.thermal = f"ramp: air {air:.2f} degC, next sweep at {cmd.nominal_c:g} degC"
            poll = min(MAX_POLL_S, max(1.0, off / self.rate_c_per_min * 60.0))
            runner.engine.wait(poll, poll)


# --- stop when good enough ------------------------------------------------------------------------------
class StopWhen:
    """An on_point callback: after the last point of a sweep (or temperature step), stop the run once
    every DUT's live T24 fit meets the plan's `stop_when` targets (calib/design/targets.py); on a designed
    plan, whose ends are held until every DUT is close to them, also not before every DUT's temperature has
    come within the plan's band of both ends of its range (else the calibration would extrapolate, and
    acceptance fails it: precision reached early is no reason to leave an end unvisited). A ramp cannot
    promise that: its DUTs lag the air; acceptance judges what it covered."""

    def __init__(self, runner, *, settle_at_start: bool = True):
        self.runner = runner
        self.settle_at_start = settle_at_start  # a ramp starts from a stable range start; designed legs
        # start ramping from wherever the air is
        points = runner.points
        self.group_ends = {p.id for p, nxt in zip(points, [*points[1:], None], strict=True)
                           if nxt is None or nxt.temp_index != p.temp_index}
        temperatures = runner.plan.temperatures
        self.range_c = temperatures.covered_c() if getattr(temperatures, "mode", None) == "designed" else None
        self.band_c = temperatures.band_c()
        self.seen_c: dict[str, tuple[float, float]] = {}  # each DUT's lowest and highest temperature

    def _short_of_range(self) -> list[str]:
        """The DUTs whose temperatures have not yet come within band_c of both ends of the range."""
        for dut, temp in self.runner.status.dut_temps_c.items():
            low, high = self.seen_c.get(dut, (temp, temp))
            self.seen_c[dut] = (min(low, temp), max(high, temp))
        if self.range_c is None:
            return []
        lo, hi = self.range_c
        return [dut for dut, (low, high) in self.seen_c.items()
                if low > lo + self.band_c or high < hi - self.band_c]

    def __call__(self, point_id: str) -> None:
        from calib.design.targets import check_targets

        short = self._short_of_range()
        if point_id not in self.group_ends or short:
            return
        targets = self.runner.plan.stop_when
        statuses = {dut: check_targets(live.acc, targets) for dut, live in self.runner.live.items()}
        if not statuses or not all(s.met for s in statuses.values()):
            return
        worst = max(statuses, key=lambda d: statuses[d].worst_ratio)
        message = (f"stop_when targets met by every DUT after point {point_id} (closest: {worst} "
                   f"{statuses[worst].worst} at {statuses[worst].worst_ratio:.2f} of its target)")
        self.runner.engine.event(Kind.RUN, message, code=Reason.TARGETS_MET, point_id=point_id,
                                 ratios={d: s.ratios for d, s in statuses.items()})
        self.runner.engine.request_stop(message, Reason.TARGETS_MET)


def attach(runner) -> RampMode | None:
    """Hook the plan's ramp mode and stop_when into a CampaignRunner; the RampMode of a plan that samples
    while the temperature moves (a ramp; designed legs, which start from wherever the air is)."""
    if runner.plan.stop_when:
        runner.on_point.append(StopWhen(runner))
    if not runner.plan.moving:
        return None
    return RampMode(runner, settle_at_start=runner.plan.ramp is not None)
