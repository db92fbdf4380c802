"""A continuous-ramp plan compiled against its station: legs, sweeps, their points; its `rig check` part.

The chamber ramps from range_c[0] to range_c[1] (leg U when that is upwards) and back (leg D), `cycles`
times. Meanwhile the field source sweeps the plan's field set again and again. Each sweep has a nominal
air temperature, where the air is when the sweep starts if every sweep takes the estimated sweep time;
a sweep waits for the air to reach it, never the other way round (rig/schedules/tasks.py). A leg has as
many sweeps as fit in its ramp plus its end hold, so the point list is known before the run and stable:

    R1U-S003-F07     cycle 1, leg up, sweep 3 of that leg, field 7 (O07 for a turntable's orientation)

`temp_index` numbers the sweeps across the whole plan (1-based), `setpoint_c` is the sweep's nominal air
temperature; every sample still carries its own DUT's temperature.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rig.config import Plan, RampTemperatures, Station
from rig.core.errors import ConfigError, LimitError
from rig.core.points import RampPoint
from rig.planning.inputs import planning_inputs, timing_of
from rig.planning.pace import (
    MAX_POINTS,
    MAX_SAMPLES_PER_DUT,
    MAX_SWEEP_SPAN_FRACTION,
    format_duration,
    stable_after_ramp_s,
    sweep_time_s,
)
from rig.schedules.check import ScheduleCheck, check_range_limits, plan_error

RAMP_PATH = ("temperatures", "rate_c_per_min")
DURATION_KEYS = {
    "to start": ("temperatures", "range_c"), "stability": ("temperatures", "stability"),
    "ramps": RAMP_PATH, "end holds": ("temperatures", "end_hold_s"), "last sweeps": ("fields",),
}


@dataclass(frozen=True)
class Leg:
    cycle: int
    number: int
    start_c: float
    end_c: float

    @property
    def rising(self) -> bool:
        return self.end_c > self.start_c

    @property
    def letter(self) -> str:
        return "U" if self.rising else "D"


def legs(ramp: RampTemperatures) -> list[Leg]:
    a, b = ramp.range_c
    out = []
    for cycle in range(1, ramp.cycles + 1):
        out.append(Leg(cycle, len(out) + 1, a, b))
        out.append(Leg(cycle, len(out) + 1, b, a))
    return out


def sweeps_per_leg(ramp: RampTemperatures, sweep_s: float) -> int:
    """As many as fill the ramp and the end hold, plus the one at the leg's end (the air there)."""
    leg_s = abs(ramp.range_c[1] - ramp.range_c[0]) / ramp.rate_c_per_min * 60.0 + ramp.end_hold_s
    return math.ceil(leg_s / sweep_s - 1e-9) + 1


class RampSchedule:
    """The points of a continuous-ramp plan and its part of the plan check."""

    word = "sweeps"

    def __init__(self, plan: Plan, station: Station, targets: list[tuple[float, ...]]):
        assert plan.ramp is not None
        self.plan, self.station, self.targets, self.ramp = plan, station, targets, plan.ramp
        self.sweep_parts_s = sweep_time_s(plan, station, targets, timing_of(plan, station))
        self.sweep_s = sum(self.sweep_parts_s.values())

    def points(self) -> list[RampPoint]:
        plan, ramp, targets = self.plan, self.ramp, self.targets
        source = self.station.field_source
        per_leg = sweeps_per_leg(ramp, self.sweep_s)
        all_legs = legs(ramp)
        self._check_size(per_leg * len(all_legs), len(targets))
        sw, fw = max(3, len(str(per_leg))), max(2, len(str(len(targets))))
        step_c = ramp.rate_c_per_min * self.sweep_s / 60.0
        points: list[RampPoint] = []
        for leg in all_legs:
            span = abs(leg.end_c - leg.start_c)
            sign = 1.0 if leg.rising else -1.0
            for s in range(1, per_leg + 1):
                nominal = round(leg.start_c + sign * min((s - 1) * step_c, span), 6)
                for fi, target in enumerate(targets, start=1):
                    points.append(RampPoint(
                        id=f"R{leg.cycle}{leg.letter}-S{s:0{sw}d}-{source.point_letter}{fi:0{fw}d}",
                        index=len(points), temp_index=(leg.number - 1) * per_leg + s, setpoint_c=nominal,
                        field_index=fi, command=tuple(target), target=source.record(target),
                        samples=plan.samples_per_point, settle_s=plan.settle_s,
                        ramp_c_per_min=ramp.rate_c_per_min, stability=ramp.stability,
                        cycle=leg.cycle, leg=leg.number, rising=leg.rising, sweep=s,
                        leg_start_c=leg.start_c, leg_end_c=leg.end_c,
                    ))
        return points

    def check(self) -> ScheduleCheck:
        """Chamber limits and the sweep's pace, then the points and the duration."""
        ramp = self.ramp
        span_c = self._check_limits()
        points = self.points()
        per_leg = max(p.sweep for p in points)
        inputs = planning_inputs(self.plan, self.station)
        lines = [
            f"continuous ramp {ramp.range_c[0]:g} -> {ramp.range_c[1]:g} degC and back at "
            f"{ramp.rate_c_per_min:g} degC/min, {ramp.cycles} cycle(s), {per_leg} sweeps per leg",
            f"one sweep of {len(self.targets)} fields: {format_duration(self.sweep_s)} ("
            + ", ".join(f"{k} {format_duration(v)}" for k, v in self.sweep_parts_s.items())
            + f"), spanning {span_c:.2g} degC of air temperature (at most "
            f"{MAX_SWEEP_SPAN_FRACTION:.0%} of the range)",
            *inputs.lines(),
        ]
        if not inputs.stated_rate and ramp.rate_c_per_min > inputs.rate_c_per_min:
            lines.append(f"warning: the air was measured at {inputs.rate_c_per_min:.3g} degC/min: a "
                         f"{ramp.rate_c_per_min:g} degC/min ramp lags behind its sweeps")
        return ScheduleCheck(points, per_leg * 2 * ramp.cycles, self._duration(per_leg, inputs),
                             DURATION_KEYS, lines, self.word)

    def _check_size(self, n_sweeps: int, n_fields: int) -> None:
        plan = self.plan
        n_points = n_sweeps * n_fields
        if n_points > MAX_POINTS or n_points * plan.samples_per_point > MAX_SAMPLES_PER_DUT:
            raise plan_error(ConfigError, plan, RAMP_PATH,
                             f"{n_sweeps} sweeps x {n_fields} fields x {plan.samples_per_point} samples is "
                             f"more than {MAX_POINTS} points or {MAX_SAMPLES_PER_DUT} samples per DUT")

    def _check_limits(self) -> float:
        """Chamber limits and the field source's pace; returns the temperature span of one sweep."""
        plan, ramp, sweep_s = self.plan, self.ramp, self.sweep_s
        check_range_limits(plan, self.station, ramp.range_c, ramp.rate_c_per_min, RAMP_PATH)
        span_c = ramp.rate_c_per_min * sweep_s / 60.0
        allowed_c = MAX_SWEEP_SPAN_FRACTION * abs(ramp.range_c[1] - ramp.range_c[0])
        if span_c > allowed_c:
            fastest = allowed_c / sweep_s * 60.0
            raise plan_error(LimitError, plan, RAMP_PATH,
                             f"one sweep of the field source takes {format_duration(sweep_s)} and spans "
                             f"{span_c:.2g} degC at {ramp.rate_c_per_min:g} degC/min; at most "
                             f"{MAX_SWEEP_SPAN_FRACTION:.0%} of the range ({allowed_c:.2g} degC): ramp at "
                             f"<= {fastest:.2g} degC/min, or take fewer fields or samples")
        return span_c

    def _duration(self, per_leg: int, inputs) -> dict[str, float]:
        """To the range start and stable there, then the legs: ramps (at the plan's rate, or the air's
        measured pace when slower), end holds, and the last sweep of each leg running past them (a leg ends
        with a whole sweep)."""
        ramp = self.ramp
        rate = inputs.rate_c_per_min
        delta = ramp.range_c[0] - inputs.chamber.start_c
        n_legs = 2 * ramp.cycles
        ramps_s = abs(ramp.range_c[1] - ramp.range_c[0]) / min(ramp.rate_c_per_min, rate) * 60.0 * n_legs
        sweeps_s = per_leg * self.sweep_s * n_legs
        return {
            "to start": abs(delta) / rate * 60.0,
            "stability": stable_after_ramp_s(delta, rate, inputs.slowest_lag_s(), ramp.stability,
                                             inputs.overshoot_c()),
            "ramps": ramps_s,
            "end holds": ramp.end_hold_s * n_legs,
            "last sweeps": max(0.0, sweeps_s - ramps_s - ramp.end_hold_s * n_legs),
        }
