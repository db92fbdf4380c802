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

if TYPE_CHECKING:
    from rig.config import Campaign, Plan, Stability, Station

# Bounds on every expansion, checked before anything is built (a hostile plan must not exhaust memory).
MAX_TEMPERATURES = 1_000
MAX_FIELDS = 10_000
MAX_POINTS = 100_000
MAX_SAMPLES_PER_DUT = 1_000_000  # the full campaign takes 19 200
MAX_DURATION_S = 8 * 7 * 86_400.0  # eight weeks

ASSUMED_START_C = 22.0  # a room: where the air is taken to start when nothing measured it


@dataclass(frozen=True)
class DutInput:
    """What planning knows of a DUT (rig/schedules/inputs.py): its noise per fitted sample and axis (nT, as
    the plan reads it), its temperature's first-order lag behind the air (s) and where it settles relative
    to the air (degC); None where the source does not say."""

    name: str
    noise_nt: float | None
    lag_s: float | None
    offset_c: float | None
    origin: str


@dataclass(frozen=True)
class ChamberInput:
    """The chamber as measured: the air's fastest pace (degC/min) and overshoot (degC), where the air
    starts (degC); rate None: not measured."""

    rate_c_per_min: float | None
    overshoot_c: float | None
    start_c: float
    origin: str


@dataclass(frozen=True)
class Timing:
    """The pace of a point: one sample of every DUT (with the sensors and the field source's read-back,
    interleaved as a campaign reads them) and a point's own time beyond its settle_s and samples (moving
    and settling the field source, reading the chamber), both s."""

    sample_s: float
    point_overhead_s: float
    origin: str


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


def format_duration(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else (f"{m}m{s:02d}s" if m else f"{s}s")


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
def field_targets(plan: Plan, station: Station) -> list[tuple[float, ...]]:
    """The field source's targets for the plan's field set, in plan order."""
    return station.field_source.targets(plan.fields, plan.name, station.name)


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
def stated_sample_time_s(plan: Plan, station: Station) -> float:
    """Time for one sample of every DUT from the drivers' stated conversion times, for a station whose pace
    nothing has measured (rig/schedules/inputs.py). Reading is interleaved (rig/devices/interleave.py): the
    DUTs wait for their conversions together, so a sample takes as long as the slowest DUT, except that
    DUTs sharing one serial line are polled in turn. The temperature sensors are read first, together
    likewise."""
    pair = plan.set_reset == "pair"
    groups: dict[tuple[str, str], float] = {}
    for d in station.duts:
        line, port = getattr(d.transport, "line", None), getattr(d.transport, "port", None)
        key = ("line", line) if line else ("port", port) if port else ("dut", d.name)
        groups[key] = groups.get(key, 0.0) + d.spec.sample_time_s(d.options, pair)
    sensors = [s.spec.sample_time_s(s.options, pair) for s in station.temperature_sensors]
    return max(groups.values()) + max(sensors, default=0.0)


def stable_after_ramp_s(delta_c: float, ramp_c_per_min: float, lag_s: float | None, st: Stability,
                        overshoot_c: float = 0.0) -> float:
    """A first-order mount lags a ramp by rate*lag (and the air overshoots by overshoot_c); after the ramp
    that error decays with the lag. Without a known lag only the dwell is counted."""
    if lag_s is None:
        return st.dwell_s
    lag_error_c = max(min(abs(delta_c), ramp_c_per_min / 60.0 * lag_s), overshoot_c)
    decay = lag_s * math.log(lag_error_c / st.band_c) if lag_error_c > st.band_c else 0.0
    return decay + st.dwell_s


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
