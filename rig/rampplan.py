"""A continuous-ramp plan compiled against its station: legs, sweeps and their points; `rig check` for it.

The chamber ramps from range_c[0] to range_c[1] (leg U when that is upwards) and back (leg D), `cycles`
times. Meanwhile the field source sweeps the plan's field set again and again. Each sweep has a nominal
air temperature, where the air is when the sweep starts if every sweep takes the estimated sweep time;
a sweep waits for the air to reach it, never the other way round (rig/ramp.py). A leg has as many sweeps
as fit in its ramp plus its end hold, so the point list is known before the run and stable:

    R1U-S003-F07     cycle 1, leg up, sweep 3 of that leg, field 7 (O07 for a turntable's orientation)

`temp_index` numbers the sweeps across the whole plan (1-based), `setpoint_c` is the sweep's nominal air
temperature; every sample still carries its own DUT's temperature.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rig.config import Plan, RampTemperatures, Station
from rig.errors import ConfigError, LimitError
from rig.plan import (
    ASSUMED_START_C,
    ASSUMED_THERMAL_LAG_S,
    MAX_POINTS,
    MAX_SAMPLES_PER_DUT,
    PlanCheck,
    Point,
    _check_duration,
    _check_targets,
    _plan_error,
    _settle_after_ramp_s,
    _stated,
    field_targets,
    format_duration,
    sample_time_s,
    t24_design_problem,
)

RAMP_PATH = ("temperatures", "rate_c_per_min")
DURATION_KEYS = {
    "to start": ("temperatures", "range_c"), "stability": ("temperatures", "stability"),
    "ramps": RAMP_PATH, "end holds": ("temperatures", "end_hold_s"), "last sweeps": ("fields",),
}
MAX_SWEEP_SPAN_FRACTION = 0.1  # one sweep may span at most this fraction of the ramp's range


@dataclass(frozen=True)
class RampPoint(Point):
    cycle: int = 1
    leg: int = 1  # 1-based over the whole plan
    rising: bool = True
    sweep: int = 1  # 1-based within its leg
    leg_start_c: float = 0.0
    leg_end_c: float = 0.0


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


def sweep_time_s(plan: Plan, station: Station, targets: list[tuple[float, ...]]) -> dict[str, float]:
    """One sweep of the field set: moves (back to the first target included), settling and sampling."""
    moves = station.field_source.move_time_s([*targets, targets[0]])
    return {"moves+settle": moves + plan.settle_s * len(targets),
            "sampling": sample_time_s(plan, station) * plan.samples_per_point * len(targets)}


def sweeps_per_leg(ramp: RampTemperatures, sweep_s: float) -> int:
    """As many as fill the ramp and the end hold, plus the one at the leg's end (the air there)."""
    leg_s = abs(ramp.range_c[1] - ramp.range_c[0]) / ramp.rate_c_per_min * 60.0 + ramp.end_hold_s
    return math.ceil(leg_s / sweep_s - 1e-9) + 1


def _check_size(plan: Plan, n_sweeps: int, n_fields: int) -> None:
    n_points = n_sweeps * n_fields
    if n_points > MAX_POINTS or n_points * plan.samples_per_point > MAX_SAMPLES_PER_DUT:
        raise _plan_error(ConfigError, plan, RAMP_PATH,
                          f"{n_sweeps} sweeps x {n_fields} fields x {plan.samples_per_point} samples is "
                          f"more than {MAX_POINTS} points or {MAX_SAMPLES_PER_DUT} samples per DUT")


def compile_ramp(plan: Plan, station: Station) -> list[RampPoint]:
    ramp = plan.ramp
    assert ramp is not None
    source = station.field_source
    targets = field_targets(plan, station)
    sweep_s = sum(sweep_time_s(plan, station, targets).values())
    per_leg = sweeps_per_leg(ramp, sweep_s)
    all_legs = legs(ramp)
    _check_size(plan, per_leg * len(all_legs), len(targets))
    sw, fw = max(3, len(str(per_leg))), max(2, len(str(len(targets))))
    step_c = ramp.rate_c_per_min * sweep_s / 60.0
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


def _check_ramp_limits(plan: Plan, station: Station, ramp: RampTemperatures, sweep_s: float) -> float:
    """Chamber limits and the field source's pace; returns the temperature span of one sweep."""
    lim = station.chamber.limits
    for i, value in enumerate(ramp.range_c):
        if not lim.min_setpoint_c <= value <= lim.max_setpoint_c:
            raise _plan_error(LimitError, plan, ("temperatures", "range_c", i),
                              f"{value:g} degC is outside chamber.limits min_setpoint_c "
                              f"{lim.min_setpoint_c:g} .. max_setpoint_c {lim.max_setpoint_c:g}")
    if ramp.rate_c_per_min > lim.max_ramp_c_per_min:
        raise _plan_error(LimitError, plan, RAMP_PATH,
                          f"{ramp.rate_c_per_min:g} degC/min exceeds chamber.limits max_ramp_c_per_min "
                          f"{lim.max_ramp_c_per_min:g}")
    span_c = ramp.rate_c_per_min * sweep_s / 60.0
    allowed_c = MAX_SWEEP_SPAN_FRACTION * abs(ramp.range_c[1] - ramp.range_c[0])
    if span_c > allowed_c:
        fastest = allowed_c / sweep_s * 60.0
        raise _plan_error(LimitError, plan, RAMP_PATH,
                          f"one sweep of the field source takes {format_duration(sweep_s)} and spans "
                          f"{span_c:.2g} degC at {ramp.rate_c_per_min:g} degC/min; at most "
                          f"{MAX_SWEEP_SPAN_FRACTION:.0%} of the range ({allowed_c:.2g} degC): ramp at "
                          f"<= {fastest:.2g} degC/min, or take fewer fields or samples")
    return span_c


def estimate_ramp_duration(plan: Plan, station: Station, points: list[RampPoint],
                           sweep_s: float) -> dict[str, float]:
    """To the range start and stable there, then the legs: ramps, end holds, and the last sweep of each
    leg running past them (a leg ends with a whole sweep)."""
    ramp = plan.ramp
    assert ramp is not None
    lags = [_stated(station.sim.duts[d.name].thermal_lag_s if d.simulated and d.name in station.sim.duts
                    else None, ASSUMED_THERMAL_LAG_S) for d in station.duts]
    start_air = _stated(station.sim.air_c if station.chamber.simulated else None, ASSUMED_START_C)
    rate = station.chamber.limits.max_ramp_c_per_min
    delta = ramp.range_c[0] - start_air
    n_legs = 2 * ramp.cycles
    ramps_s = abs(ramp.range_c[1] - ramp.range_c[0]) / ramp.rate_c_per_min * 60.0 * n_legs
    per_leg = max(p.sweep for p in points)
    sweeps_s = per_leg * sweep_s * n_legs
    return {
        "to start": abs(delta) / rate * 60.0,
        "stability": _settle_after_ramp_s(delta, rate, max(lags), ramp.stability),
        "ramps": ramps_s,
        "end holds": ramp.end_hold_s * n_legs,
        "last sweeps": max(0.0, sweeps_s - ramps_s - ramp.end_hold_s * n_legs),
    }


def check_ramp(plan: Plan, station: Station) -> PlanCheck:
    """`rig check` of a ramp plan: chamber limits, the sweep's pace, field limits, T24 design, duration."""
    ramp = plan.ramp
    assert ramp is not None
    targets = field_targets(plan, station)
    parts = sweep_time_s(plan, station, targets)
    sweep_s = sum(parts.values())
    span_c = _check_ramp_limits(plan, station, ramp, sweep_s)
    points = compile_ramp(plan, station)
    warnings: list[str] = []
    source_lines = _check_targets(plan, station, points, warnings)
    if "t24" in plan.fit.models:
        problem = t24_design_problem(points, station)
        if problem:
            warnings.append(problem)
    breakdown = estimate_ramp_duration(plan, station, points, sweep_s)
    _check_duration(plan, breakdown, DURATION_KEYS)
    per_leg = max(p.sweep for p in points)
    source_lines = [
        f"continuous ramp {ramp.range_c[0]:g} -> {ramp.range_c[1]:g} degC and back at "
        f"{ramp.rate_c_per_min:g} degC/min, {ramp.cycles} cycle(s), {per_leg} sweeps per leg",
        f"one sweep of {len(targets)} fields: {format_duration(sweep_s)} ("
        + ", ".join(f"{k} {format_duration(v)}" for k, v in parts.items())
        + f"), spanning {span_c:.2g} degC of air temperature (at most "
        f"{MAX_SWEEP_SPAN_FRACTION:.0%} of the range)",
        *source_lines,
    ]
    if plan.stop_when:
        source_lines.append(stop_when_line(plan, sum(breakdown.values())))
    return PlanCheck(
        points=points, n_temperatures=per_leg * 2 * ramp.cycles, n_fields=len(targets),
        n_duts=len(station.duts), samples_per_dut=len(points) * plan.samples_per_point,
        duration_s=sum(breakdown.values()), breakdown_s=breakdown, source_lines=source_lines,
        warnings=warnings, temperatures_word="sweeps",
    )


def stop_when_line(plan: Plan, duration_s: float) -> str:
    """What `stop_when` means for the plan's chamber time: only the best case is shorter."""
    targets = ", ".join(f"{k} {v:g}" for k, v in (plan.stop_when or {}).items())
    where = "sweep" if plan.ramp is not None else "temperature step"
    return (f"stop_when {targets}: checked after every {where} on each DUT's live T24 fit; stops once "
            f"every DUT meets them; worst case the whole plan, {format_duration(duration_s)}")
