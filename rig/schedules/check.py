"""What every temperature schedule's plan check shares: bounds on expansions, located errors, the field
source's limits blamed on the plan key, sample, move and stability times, the T24 design test, the
duration bound, and the summary `rig check` prints (PlanCheck).

Every schedule (steps, ramp, designed, sequential: rig/schedules/) builds on this; rig/schedules/compile.py
asks the plan's schedule once.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from rig.core.errors import ConfigError, LimitError
from rig.core.points import Point
from rig.core.yamlload import KeyPath, blamed, format_path, locate_in_text
from rig.planning.pace import (
    MAX_DURATION_S,
    format_duration,
)

if TYPE_CHECKING:
    from rig.config import Campaign, Plan, Station

# Bounds on every expansion, checked before anything is built (a hostile plan must not exhaust memory).
def plan_error(cls: type[Exception], plan: Plan, path: KeyPath, what: str) -> Exception:
    """An error of the plan, blamed on its key so that located_errors can name the line."""
    return blamed(cls(f"plan {plan.name}: {format_path(path)}: {what}"), path, what)


@contextlib.contextmanager
def located_errors(campaign: Campaign | None) -> Iterator[None]:
    """Re-raise blamed errors as `FILE: key.path: what (line N)` of the plan or station file."""
    try:
        yield
    except (ConfigError, LimitError) as err:
        blame = getattr(err, "blame", None)
        if blame is None or campaign is None:
            raise
        document, path, what = blame
        source, text = ((campaign.plan_path, campaign.plan_text) if document == "plan"
                        else (campaign.station_path, campaign.station_text))
        raise type(err)(locate_in_text(str(source), text, path, what)) from None


@dataclass
class PlanCheck:
    """What `rig check` prints: sizes, the duration estimate with its parts, and warnings."""

    points: list[Point]
    n_temperatures: int
    n_fields: int
    n_duts: int
    samples_per_dut: int
    duration_s: float
    breakdown_s: dict[str, float]
    source_lines: list[str] = field(default_factory=list)  # the schedule's and field source's figures
    warnings: list[str] = field(default_factory=list)
    temperatures_word: str = "temperatures"  # "sweeps" for a continuous ramp
    prediction: Any = None  # a designed schedule's predicted errors (calib.design.planner.Schedule), for
                            # figures
    size_line: str | None = None  # the schedule's own first line, when points x fields does not say it

    def duration_text(self) -> str:
        """`1h29m (to and at the ends 49m48s, ...)`: the estimate and its parts."""
        return (f"{format_duration(self.duration_s)} ("
                + ", ".join(f"{k} {format_duration(v)}" for k, v in self.breakdown_s.items()) + ")")

    def summary_lines(self) -> list[str]:
        lines = [
            self.size_line or
            f"{len(self.points)} points = {self.n_temperatures} {self.temperatures_word} x {self.n_fields} "
            "fields; "
            f"{self.samples_per_dut} samples per DUT, {self.n_duts} DUT(s)",
            f"estimated duration {self.duration_text()}",
        ]
        lines += self.source_lines
        lines += [f"warning: {w}" for w in self.warnings]
        return lines


@dataclass
class ScheduleCheck:
    """A temperature schedule's own part of the plan check: its points (limits checked), how many
    temperatures (steps or sweeps), its duration estimate by part and the plan key each part blames."""

    points: list[Point]
    n_temperatures: int
    breakdown_s: dict[str, float]
    duration_keys: dict[str, KeyPath]
    lines: list[str] = field(default_factory=list)
    temperatures_word: str = "temperatures"
    prediction: Any = None  # calib.design.planner.Schedule of a designed schedule
    design_points: list[Point] | None = None  # judged by the T24 design test (default: points; [] skips it)
    size_line: str | None = None  # replaces "N points = temperatures x fields"
    stop_when_line: bool = True  # False: the schedule's own lines say how it stops


# --- the field source -----------------------------------------------------------------------------------
def _field_path(plan: Plan, field_index: int) -> KeyPath:
    """The plan key of one field target (1-based), where the plan lists them one by one."""
    keys = {"vectors": "vectors_nt", "orientations": "angles_deg", "directions": "directions"}
    key = keys.get(plan.fields.kind)
    if key is None:
        return ("fields",)
    listed = getattr(plan.fields, "listed_index", lambda i: i)(field_index - 1)
    return ("fields", key, listed)


def check_field_limits(plan: Plan, station: Station, points: list[Point], warnings: list[str]) -> list[str]:
    """The field source's limits, with the error blamed on the plan key of the offending target (the first
    in the plan's own order, whatever order the steps take them in)."""
    listed = sorted(points, key=lambda p: (p.temp_index, p.field_index))
    try:
        return station.field_source.check_targets(plan.name, listed, warnings)
    except LimitError as err:
        point = getattr(err, "point", None)
        if point is None:
            raise
        what = str(err).removeprefix(f"plan {plan.name}: ")
        raise blamed(err, _field_path(plan, point.field_index), what) from None


# --- times ----------------------------------------------------------------------------------------------
def check_range_limits(plan: Plan, station: Station, range_c, rate_c_per_min: float | None,
                       rate_path: KeyPath) -> None:
    """A moving schedule's range and rate against the chamber's limits (LimitError naming the plan key)."""
    lim = station.chamber.limits
    for i, value in enumerate(range_c):
        if not lim.min_setpoint_c <= value <= lim.max_setpoint_c:
            raise plan_error(LimitError, plan, ("temperatures", "range_c", i),
                             f"{value:g} degC is outside chamber.limits min_setpoint_c "
                             f"{lim.min_setpoint_c:g} .. max_setpoint_c {lim.max_setpoint_c:g}")
    if rate_c_per_min is not None and rate_c_per_min > lim.max_ramp_c_per_min:
        raise plan_error(LimitError, plan, rate_path, f"{rate_c_per_min:g} degC/min exceeds chamber.limits "
                         f"max_ramp_c_per_min {lim.max_ramp_c_per_min:g}")


def check_duration(plan: Plan, breakdown: dict[str, float], keys: dict[str, KeyPath]) -> None:
    """Refuse a plan that would run for more than MAX_DURATION_S, blaming its largest part."""
    total = sum(breakdown.values())
    if math.isfinite(total) and total <= MAX_DURATION_S:
        return
    part = max(breakdown, key=lambda k: breakdown[k] if math.isfinite(breakdown[k]) else math.inf)
    days = total / 86_400.0
    raise plan_error(ConfigError, plan, keys[part],
                     f"estimated duration {days:.3g} days (mostly {part}) is longer than the bound of "
                     f"{MAX_DURATION_S / 86_400.0:g} days")


# --- the design -----------------------------------------------------------------------------------------
def t24_design_problem(points: list[Point], station: Station) -> str | None:
    """What a T24 fit could not identify from this plan (None if all is fine), judged on the nominal
    fields and setpoints with calib's own Gram test: the sensor's axes are taken as the lab's."""
    from calib.models.gram import GramAccumulator

    fields = np.array([station.field_source.nominal_field_nt(p.command) for p in points])
    temps = np.array([p.setpoint_c for p in points])
    samples = [p.samples for p in points]
    acc = GramAccumulator(temp_ref_c=float(temps.mean()))
    repeated = np.repeat(fields, samples, axis=0)  # bounded by MAX_SAMPLES_PER_DUT
    acc.add(repeated, np.repeat(temps, samples), repeated)
    return acc.identifiability()


def stop_when_line(plan: Plan, duration_s: float) -> str:
    """What `stop_when` means for the plan's chamber time: only the best case is shorter."""
    targets = ", ".join(f"{k} {v:g}" for k, v in (plan.stop_when or {}).items())
    where = "sweep" if plan.moving else "temperature step"
    return (f"stop_when {targets}: checked after every {where} on each DUT's live T24 fit; stops once "
            f"every DUT meets them; worst case the whole plan, {format_duration(duration_s)}")
