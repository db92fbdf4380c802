"""A designed schedule (`temperatures: {mode: designed, legs: [...]}`, written by `rig design`): legs run
back to back from wherever the air is; in each the chamber ramps to the leg's temperature and holds there
while the field source sweeps the plan's fields `sweeps` times. As on a continuous ramp
(rig/schedules/tasks.py) every sample carries its DUT's temperature and each sweep has a nominal air
temperature, where the air is when the sweep starts if every sweep takes the estimated sweep time; a sweep
waits for the air to reach it. So the point list is known before the run and stable:

    L02-S003-F07     leg 2, sweep 3 of that leg, field 7 (O07 for a turntable's orientation)

Its part of `rig check`: the chamber's limits, the sweep's pace, the duration, and the standard errors the
design predicts for each DUT against chamber time (rig/planning/design.py, calib/design/planner.py).
"""

from __future__ import annotations

import math

from rig.config import DesignedTemperatures, Plan, Station
from rig.core.errors import ConfigError, LimitError
from rig.core.points import RampPoint
from rig.planning.inputs import planning_inputs, timing_of
from rig.planning.pace import (
    MAX_POINTS,
    MAX_SAMPLES_PER_DUT,
    MAX_SWEEP_SPAN_FRACTION,
    format_duration,
    sweep_time_s,
)
from rig.schedules.check import ScheduleCheck, plan_error

LEGS_PATH = ("temperatures", "legs")
DURATION_KEYS = {"to and at the ends": LEGS_PATH, "across via the checks": LEGS_PATH}


def leg_rate(temps: DesignedTemperatures, index: int) -> float:
    leg = temps.legs[index]
    return leg.rate_c_per_min or temps.rate_c_per_min


def nominal_air(from_c: float, to_c: float, rate_c_per_min: float, elapsed_s: float) -> float:
    """Where the air is `elapsed_s` into a leg that ramps from from_c to to_c and then holds."""
    span = to_c - from_c
    return from_c + math.copysign(min(rate_c_per_min * elapsed_s / 60.0, abs(span)), span)


def leg_points(plan: Plan, station: Station, targets: list[tuple[float, ...]], *, leg: int,
               sweeps: tuple[int, int], from_c: float, to_c: float, rate_c_per_min: float, sweep_s: float,
               first_index: int, first_temp_index: int, widths: tuple[int, int, int],
               field_indices: list[int] | None = None) -> list[RampPoint]:
    """Points of sweeps `sweeps` (first, last; 1-based) of one leg; `field_indices` (1-based) picks the
    targets of each sweep (default: all, in order). Shared with the sequential schedule
    (rig/schedules/sequential.py)."""
    source = station.field_source
    lw, sw, fw = widths
    picks = field_indices or list(range(1, len(targets) + 1))
    points = []
    for s in range(sweeps[0], sweeps[1] + 1):
        nominal = round(nominal_air(from_c, to_c, rate_c_per_min, (s - 1) * sweep_s), 6)
        for fi in picks:
            target = targets[fi - 1]
            points.append(RampPoint(
                id=f"L{leg:0{lw}d}-S{s:0{sw}d}-{source.point_letter}{fi:0{fw}d}",
                index=first_index + len(points), temp_index=first_temp_index + s - sweeps[0],
                setpoint_c=nominal, field_index=fi, command=tuple(target), target=source.record(target),
                samples=plan.samples_per_point, settle_s=plan.settle_s, ramp_c_per_min=rate_c_per_min,
                stability=plan.temperatures.stability, cycle=1, leg=leg, rising=to_c >= from_c, sweep=s,
                leg_start_c=from_c, leg_end_c=to_c,
            ))
    return points


def leg_times_s(temps: DesignedTemperatures, start_c: float, sweep_s: float, air_rate_c_per_min: float
                ) -> list[float]:
    """Each leg's time as a run takes it: a sweep begins when the one before has ended and the air has
    reached the sweep's nominal temperature (rig/schedules/tasks.py AwaitAir), the air moving at the
    leg's rate, or at the chamber's pace where that is slower."""
    from rig.engine.commands import AIR_TOLERANCE_C

    nominal_from, air, out = start_c, start_c, []
    for i, leg in enumerate(temps.legs):
        rate = leg_rate(temps, i)
        real = min(rate, air_rate_c_per_min)
        t = 0.0
        for k in range(leg.sweeps):
            nominal = nominal_air(nominal_from, leg.to_c, rate, k * sweep_s)
            behind = (nominal - air) if leg.to_c >= nominal_from else (air - nominal)
            t = max(t, (behind - AIR_TOLERANCE_C) / real * 60.0) + sweep_s
        out.append(t)
        air = nominal_air(air, leg.to_c, real, t)
        nominal_from = nominal_air(nominal_from, leg.to_c, rate, leg.sweeps * sweep_s)
    return out


class LegSchedule:
    """The points of a designed plan and its part of the plan check."""

    word = "sweeps"

    def __init__(self, plan: Plan, station: Station, targets: list[tuple[float, ...]]):
        assert isinstance(plan.temperatures, DesignedTemperatures)
        self.plan, self.station, self.targets, self.temps = plan, station, targets, plan.temperatures
        self.sweep_parts_s = sweep_time_s(plan, station, targets, timing_of(plan, station))
        self.sweep_s = sum(self.sweep_parts_s.values())
        self.inputs = planning_inputs(plan, station)

    def points(self) -> list[RampPoint]:
        temps, targets = self.temps, self.targets
        n_sweeps = sum(leg.sweeps for leg in temps.legs)
        n_points = n_sweeps * len(targets)
        if n_points > MAX_POINTS or n_points * self.plan.samples_per_point > MAX_SAMPLES_PER_DUT:
            raise plan_error(ConfigError, self.plan, LEGS_PATH,
                             f"{n_sweeps} sweeps x {len(targets)} fields x {self.plan.samples_per_point} "
                             f"samples is more than {MAX_POINTS} points or {MAX_SAMPLES_PER_DUT} samples per "
                             "DUT")
        widths = (max(2, len(str(len(temps.legs)))), max(3, len(str(max(leg.sweeps for leg in temps.legs)))),
                  max(2, len(str(len(targets)))))
        points: list[RampPoint] = []
        air = self.inputs.chamber.start_c
        for i, leg in enumerate(temps.legs):
            rate = leg_rate(temps, i)
            points += leg_points(self.plan, self.station, targets, leg=i + 1, sweeps=(1, leg.sweeps),
                                 from_c=air, to_c=leg.to_c, rate_c_per_min=rate,
                                 sweep_s=self.sweep_s, first_index=len(points),
                                 first_temp_index=len(points) // len(targets) + 1, widths=widths)
            air = nominal_air(air, leg.to_c, rate, leg.sweeps * self.sweep_s)
        return points

    def check(self) -> ScheduleCheck:
        from rig.planning.design import predicted_lines

        self._check_limits()
        points = self.points()
        n_sweeps = sum(leg.sweeps for leg in self.temps.legs)
        times = leg_times_s(self.temps, self.inputs.chamber.start_c, self.sweep_s, self.inputs.rate_c_per_min)
        breakdown = {"to and at the ends": sum(t for t, leg in zip(times, self.temps.legs, strict=True)
                                               if not leg.check),
                     "across via the checks": sum(t for t, leg in zip(times, self.temps.legs, strict=True)
                                                  if leg.check)}
        legs = ", ".join(f"{leg.to_c:g} degC x {leg.sweeps}" + (" (check)" if leg.check else "")
                         for leg in self.temps.legs)
        lines = [f"designed schedule: {len(self.temps.legs)} legs ({legs} sweeps), ramps at "
                 f"{self.temps.rate_c_per_min:g} degC/min",
                 f"one sweep of {len(self.targets)} fields: {format_duration(self.sweep_s)} ("
                 + ", ".join(f"{k} {format_duration(v)}" for k, v in self.sweep_parts_s.items()) + ")",
                 *self.inputs.lines()]
        prediction, predicted = predicted_lines(self.plan, self.station, self.targets, self.sweep_s)
        lines += predicted
        return ScheduleCheck(points, n_sweeps, breakdown, DURATION_KEYS, lines, self.word, prediction)

    def _check_limits(self) -> None:
        plan, temps = self.plan, self.temps
        lim = self.station.chamber.limits
        for i, leg in enumerate(temps.legs):
            if not lim.min_setpoint_c <= leg.to_c <= lim.max_setpoint_c:
                raise plan_error(LimitError, plan, (*LEGS_PATH, i, "to_c"),
                                 f"{leg.to_c:g} degC is outside chamber.limits min_setpoint_c "
                                 f"{lim.min_setpoint_c:g} .. max_setpoint_c {lim.max_setpoint_c:g}")
            rate = leg_rate(temps, i)
            if rate > lim.max_ramp_c_per_min:
                path = (*LEGS_PATH, i, "rate_c_per_min") if leg.rate_c_per_min else ("temperatures",
                                                                                     "rate_c_per_min")
                raise plan_error(LimitError, plan, path, f"{rate:g} degC/min exceeds chamber.limits "
                                 f"max_ramp_c_per_min {lim.max_ramp_c_per_min:g}")
        ends = [leg.to_c for leg in temps.legs] + [self.inputs.chamber.start_c]
        span = max(ends) - min(ends)
        swept_c = max(leg_rate(temps, i) for i in range(len(temps.legs))) * self.sweep_s / 60.0
        if span > 0 and swept_c > MAX_SWEEP_SPAN_FRACTION * span:
            raise plan_error(LimitError, plan, ("temperatures", "rate_c_per_min"),
                             f"one sweep of the field source takes {format_duration(self.sweep_s)} and spans "
                             f"{swept_c:.2g} degC at the fastest ramp; at most "
                             f"{MAX_SWEEP_SPAN_FRACTION:.0%} of the {span:g} degC the legs cover: ramp "
                             "slower, or take fewer fields or samples")
