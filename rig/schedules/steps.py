"""Temperature steps (step and dwell): every field target at each stable setpoint, in the plan's order.

    T03-F07     temperature step 3, field 7 (O07 for a turntable's orientation)

All fields at the first temperature, then all at the second, and so on. At each step the fields go in a
fresh order of their own (`field_order: shuffled`, the default), drawn from the step's number alone so
that every run and resume of a plan takes the same; `field_order: listed` keeps the plan's order.

Its part of `rig check`: sizes, the chamber's setpoint and ramp limits, and the time spent ramping,
settling, moving and sampling.
"""

from __future__ import annotations

import math
import random

from rig.config import Plan, Station
from rig.core.errors import ConfigError, LimitError
from rig.core.points import Point, point_id
from rig.core.yamlload import KeyPath
from rig.planning.inputs import planning_inputs
from rig.planning.pace import (
    MAX_FIELDS,
    MAX_POINTS,
    MAX_SAMPLES_PER_DUT,
    MAX_TEMPERATURES,
    stable_after_ramp_s,
)
from rig.schedules.check import ScheduleCheck, plan_error

ORDER_SEED = 20_240_024  # any fixed number: the orders only need to differ from step to step

DURATION_KEYS: dict[str, KeyPath] = {
    "ramps": ("temperatures", "ramp_c_per_min"),
    "stability": ("temperatures", "stability"),
    "moves+settle": ("settle_s",),
    "sampling": ("samples_per_point",),
}


def count_temperatures(plan: Plan) -> int:
    """Number of temperature steps, counted without expanding a range."""
    temps = plan.temperatures
    if temps.range is None:
        return len(temps.steps or [])
    r = temps.range
    span = (r.stop_c - r.start_c) / r.step_c
    if not math.isfinite(span) or span + 1 > MAX_TEMPERATURES:
        raise plan_error(ConfigError, plan, ("temperatures", "range", "step_c"),
                         f"{r.start_c:g} to {r.stop_c:g} degC in steps of {r.step_c:g} is more than "
                         f"{MAX_TEMPERATURES} temperatures")
    return math.floor(span + 1e-9) + 1


def check_size(plan: Plan) -> tuple[int, int]:
    """(temperatures, fields) of the plan; ConfigError before anything big is built."""
    n_temps, n_fields = count_temperatures(plan), plan.fields.count()
    if n_fields > MAX_FIELDS:
        raise plan_error(ConfigError, plan, ("fields",), f"{n_fields} field targets; at most {MAX_FIELDS}")
    n_points = n_temps * n_fields
    if n_points > MAX_POINTS:
        raise plan_error(ConfigError, plan, ("fields",), f"{n_temps} temperatures x {n_fields} fields = "
                         f"{n_points} points; at most {MAX_POINTS}")
    if n_points * plan.samples_per_point > MAX_SAMPLES_PER_DUT:
        raise plan_error(ConfigError, plan, ("samples_per_point",),
                         f"{n_points} points x {plan.samples_per_point} samples = "
                         f"{n_points * plan.samples_per_point} samples per DUT; "
                         f"at most {MAX_SAMPLES_PER_DUT}")
    return n_temps, n_fields


class StepSchedule:
    """The points of a step-and-dwell plan and its part of the plan check."""

    word = "temperatures"

    def __init__(self, plan: Plan, station: Station, targets: list[tuple[float, ...]]):
        self.plan, self.station, self.targets = plan, station, targets

    def points(self) -> list[Point]:
        plan, letter = self.plan, self.station.field_source.point_letter
        check_size(plan)
        steps = plan.temperatures.step_list()
        record = self.station.field_source.record
        points = []
        for ti, step in enumerate(steps, start=1):
            stability = plan.temperatures.stability_for(step)
            ramp = step.ramp_c_per_min or plan.temperatures.ramp_c_per_min
            for fi in self.field_order(ti):
                target = self.targets[fi - 1]
                points.append(Point(
                    id=point_id(ti, fi, len(steps), len(self.targets), letter), index=len(points),
                    temp_index=ti, setpoint_c=step.setpoint_c, field_index=fi, command=tuple(target),
                    target=record(target), samples=plan.samples_per_point, settle_s=plan.settle_s,
                    ramp_c_per_min=ramp, stability=stability,
                ))
        return points

    def field_order(self, temp_index: int) -> list[int]:
        """The 1-based field indices in the order step `temp_index` takes them."""
        order = list(range(1, len(self.targets) + 1))
        if self.plan.field_order == "listed":
            return order
        # Fisher-Yates on random.Random's random(): the one output Python keeps the same across versions,
        # so a session is resumed in its own order whatever the interpreter
        draw = random.Random(ORDER_SEED * 1000 + temp_index).random
        for i in range(len(order) - 1, 0, -1):
            j = int(draw() * (i + 1))
            order[i], order[j] = order[j], order[i]
        return order

    def check(self) -> ScheduleCheck:
        points = self.points()
        n_temps, _ = check_size(self.plan)
        self._check_setpoints(points)
        inputs = planning_inputs(self.plan, self.station)
        lines = inputs.lines()
        listed = self.plan.field_order == "listed"
        lines.append("field order: the plan's (field_order: listed)" if listed else
                     "field order: a fresh one at each step (field_order: shuffled; listed keeps the plan's)")
        if inputs.slowest_lag_s() is None:
            lines.append("stability waits: not predicted without every DUT's lag (counted as the dwell "
                         "alone)")
        return ScheduleCheck(points, n_temps, self._duration(points, inputs), DURATION_KEYS, lines, self.word)

    def _step_path(self, temp_index: int) -> KeyPath:
        temps = self.plan.temperatures
        return ("temperatures", "range") if temps.steps is None else ("temperatures", "steps", temp_index - 1)

    def _check_setpoints(self, points: list[Point]) -> None:
        plan, lim = self.plan, self.station.chamber.limits
        for p in points:
            if not lim.min_setpoint_c <= p.setpoint_c <= lim.max_setpoint_c:
                raise plan_error(
                    LimitError, plan, self._step_path(p.temp_index),
                    f"temperature step {p.temp_index} setpoint {p.setpoint_c:g} degC is "
                    f"outside chamber.limits min_setpoint_c {lim.min_setpoint_c:g} .. "
                    f"max_setpoint_c {lim.max_setpoint_c:g}"
                )
            if p.ramp_c_per_min > lim.max_ramp_c_per_min:
                step = plan.temperatures.steps[p.temp_index - 1] if plan.temperatures.steps else None
                path = ((*self._step_path(p.temp_index), "ramp_c_per_min") if step and step.ramp_c_per_min
                        else ("temperatures", "ramp_c_per_min"))
                raise plan_error(
                    LimitError, plan, path,
                    f"temperature step {p.temp_index} ramp {p.ramp_c_per_min:g} degC/min "
                    f"exceeds chamber.limits max_ramp_c_per_min {lim.max_ramp_c_per_min:g}"
                )

    def _duration(self, points: list[Point], inputs) -> dict[str, float]:
        """Seconds spent ramping (at the step's rate, or the air's measured pace when slower), waiting for
        stability (the slowest DUT's measured lag; the dwell alone without it), moving/settling and sampling
        at the measured pace (rig/planning/inputs.py)."""
        station = self.station
        lag_s = inputs.slowest_lag_s()
        ramp_s = stable_s = 0.0
        temp = inputs.chamber.start_c
        for p in points[::len(self.targets)]:
            rate = min(p.ramp_c_per_min, inputs.rate_c_per_min)
            delta = p.setpoint_c - temp
            ramp_s += abs(delta) / rate * 60.0
            stable_s += stable_after_ramp_s(delta, rate, lag_s, p.stability, inputs.overshoot_c())
            temp = p.setpoint_c
        moves_s = station.field_source.move_time_s([p.command for p in points])
        move_s = sum(p.settle_s + inputs.timing.point_overhead_s for p in points) + moves_s
        sampling_s = inputs.timing.sample_s * sum(p.samples for p in points)
        return {"ramps": ramp_s, "stability": stable_s, "moves+settle": move_s, "sampling": sampling_s}
