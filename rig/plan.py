"""A plan compiled against its station: the deterministic list of points a campaign collects.

    points = compile_plan(plan, station)       # [Point], temperature-major
    report = check_plan(plan, station)         # limits checked without hardware; raises LimitError
    report.summary_lines()                     # what `rig check` prints (sizes, duration, warnings)

Point ids are stable: `T03-F07` is temperature step 3, field 7 (coils); `T03-O07` orientation 7
(turntable). Numbers are 1-based and zero-padded to at least 2 digits (3 when there are > 99).
For coils the target is the total field (lab frame, nT) the coils must make, ambient included; for a
turntable it is (az_deg, el_deg).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from rig.config import Campaign, Plan, Stability, Station
from rig.errors import ConfigError, LimitError
from rig.yamlload import KeyPath, blamed, format_path, locate_in_text

# Bounds on every expansion, checked before anything is built (a hostile plan must not exhaust memory).
MAX_TEMPERATURES = 1_000
MAX_FIELDS = 10_000
MAX_POINTS = 100_000
MAX_SAMPLES_PER_DUT = 1_000_000  # the full campaign takes 19 200
MAX_DURATION_S = 8 * 7 * 86_400.0  # eight weeks

ASSUMED_START_C = 22.0
ASSUMED_THERMAL_LAG_S = 600.0  # for real DUT mounts, whose lag the station does not state


@dataclass(frozen=True)
class Point:
    id: str
    index: int  # 0-based position in the campaign
    temp_index: int  # 1-based
    setpoint_c: float
    field_index: int  # 1-based
    command: tuple[float, ...]  # the field source's target: a field vector (nT) or (az, el) (deg)
    target: dict  # the same as stored with the point: {"field_nt": [...]} or {"az_deg", "el_deg"}
    samples: int
    settle_s: float
    ramp_c_per_min: float
    stability: Stability

    @property
    def field_nt(self) -> tuple[float, float, float] | None:
        """The commanded field, when the target is one (coils)."""
        value = self.target.get("field_nt")
        return None if value is None else tuple(value)


def _plan_error(cls: type[Exception], plan: Plan, path: KeyPath, what: str) -> Exception:
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


def count_temperatures(plan: Plan) -> int:
    """Number of temperature steps, counted without expanding a range."""
    temps = plan.temperatures
    if temps.range is None:
        return len(temps.steps or [])
    r = temps.range
    span = (r.stop_c - r.start_c) / r.step_c
    if not math.isfinite(span) or span + 1 > MAX_TEMPERATURES:
        raise _plan_error(ConfigError, plan, ("temperatures", "range", "step_c"),
                          f"{r.start_c:g} to {r.stop_c:g} degC in steps of {r.step_c:g} is more than "
                          f"{MAX_TEMPERATURES} temperatures")
    return math.floor(span + 1e-9) + 1


def check_size(plan: Plan) -> tuple[int, int]:
    """(temperatures, fields) of the plan; ConfigError before anything big is built."""
    n_temps, n_fields = count_temperatures(plan), plan.fields.count()
    if n_fields > MAX_FIELDS:
        raise _plan_error(ConfigError, plan, ("fields",), f"{n_fields} field targets; at most {MAX_FIELDS}")
    n_points = n_temps * n_fields
    if n_points > MAX_POINTS:
        raise _plan_error(ConfigError, plan, ("fields",), f"{n_temps} temperatures x {n_fields} fields = "
                          f"{n_points} points; at most {MAX_POINTS}")
    if n_points * plan.samples_per_point > MAX_SAMPLES_PER_DUT:
        raise _plan_error(ConfigError, plan, ("samples_per_point",),
                          f"{n_points} points x {plan.samples_per_point} samples = "
                          f"{n_points * plan.samples_per_point} samples per DUT; "
                          f"at most {MAX_SAMPLES_PER_DUT}")
    return n_temps, n_fields


def field_targets(plan: Plan, station: Station) -> list[tuple[float, ...]]:
    """The field source's targets for the plan's field set, in plan order."""
    return station.field_source.targets(plan.fields, plan.name, station.name)


def point_id(temp_index: int, field_index: int, n_temps: int, n_fields: int, letter: str = "F") -> str:
    tw, fw = max(2, len(str(n_temps))), max(2, len(str(n_fields)))
    return f"T{temp_index:0{tw}d}-{letter}{field_index:0{fw}d}"


def compile_plan(plan: Plan, station: Station) -> list[Point]:
    if plan.ramp is not None:
        from rig.rampplan import compile_ramp

        return list(compile_ramp(plan, station))
    check_size(plan)
    steps = plan.temperatures.step_list()
    source = station.field_source
    targets = field_targets(plan, station)
    points = []
    for ti, step in enumerate(steps, start=1):
        stability = plan.temperatures.stability_for(step)
        ramp = step.ramp_c_per_min or plan.temperatures.ramp_c_per_min
        for fi, target in enumerate(targets, start=1):
            points.append(Point(
                id=point_id(ti, fi, len(steps), len(targets), source.point_letter),
                index=len(points),
                temp_index=ti,
                setpoint_c=step.setpoint_c,
                field_index=fi,
                command=tuple(target),
                target=source.record(target),
                samples=plan.samples_per_point,
                settle_s=plan.settle_s,
                ramp_c_per_min=ramp,
                stability=stability,
            ))
    return points


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
    source_lines: list[str] = field(default_factory=list)  # the field source's own figures
    warnings: list[str] = field(default_factory=list)
    temperatures_word: str = "temperatures"  # "sweeps" for a continuous ramp

    def summary_lines(self) -> list[str]:
        lines = [
            f"{len(self.points)} points = {self.n_temperatures} {self.temperatures_word} x {self.n_fields} "
            "fields; "
            f"{self.samples_per_dut} samples per DUT, {self.n_duts} DUT(s)",
            f"estimated duration {format_duration(self.duration_s)} ("
            + ", ".join(f"{k} {format_duration(v)}" for k, v in self.breakdown_s.items()) + ")",
        ]
        lines += self.source_lines
        lines += [f"warning: {w}" for w in self.warnings]
        return lines


def format_duration(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else (f"{m}m{s:02d}s" if m else f"{s}s")


def _step_path(plan: Plan, temp_index: int) -> KeyPath:
    temps = plan.temperatures
    return ("temperatures", "range") if temps.steps is None else ("temperatures", "steps", temp_index - 1)


def _check_setpoints(plan: Plan, station: Station, points: list[Point]) -> None:
    lim = station.chamber.limits
    for p in points:
        if not lim.min_setpoint_c <= p.setpoint_c <= lim.max_setpoint_c:
            raise _plan_error(
                LimitError, plan, _step_path(plan, p.temp_index),
                f"temperature step {p.temp_index} setpoint {p.setpoint_c:g} degC is "
                f"outside chamber.limits min_setpoint_c {lim.min_setpoint_c:g} .. "
                f"max_setpoint_c {lim.max_setpoint_c:g}"
            )
        if p.ramp_c_per_min > lim.max_ramp_c_per_min:
            step = plan.temperatures.steps[p.temp_index - 1] if plan.temperatures.steps else None
            path = ((*_step_path(plan, p.temp_index), "ramp_c_per_min") if step and step.ramp_c_per_min
                    else ("temperatures", "ramp_c_per_min"))
            raise _plan_error(
                LimitError, plan, path,
                f"temperature step {p.temp_index} ramp {p.ramp_c_per_min:g} degC/min "
                f"exceeds chamber.limits max_ramp_c_per_min {lim.max_ramp_c_per_min:g}"
            )


def _field_path(plan: Plan, field_index: int) -> KeyPath:
    """The plan key of one field target (1-based), where the plan lists them one by one."""
    keys = {"vectors": "vectors_nt", "orientations": "angles_deg", "directions": "directions"}
    key = keys.get(plan.fields.kind)
    if key is None:
        return ("fields",)
    listed = getattr(plan.fields, "listed_index", lambda i: i)(field_index - 1)
    return ("fields", key, listed)


def _check_targets(plan: Plan, station: Station, points: list[Point], warnings: list[str]) -> list[str]:
    """The field source's limits, with the error blamed on the plan key of the offending target."""
    try:
        return station.field_source.check_targets(plan.name, points, warnings)
    except LimitError as err:
        point = getattr(err, "point", None)
        if point is None:
            raise
        what = str(err).removeprefix(f"plan {plan.name}: ")
        raise blamed(err, _field_path(plan, point.field_index), what) from None


def _stated(value: float | None, assumed: float) -> float:
    return assumed if value is None else value


def _settle_after_ramp_s(delta_c: float, ramp_c_per_min: float, lag_s: float, st: Stability) -> float:
    """A first-order mount lags a ramp by rate*lag; after the ramp that error decays with the lag."""
    lag_error_c = min(abs(delta_c), ramp_c_per_min / 60.0 * lag_s)
    decay = lag_s * math.log(lag_error_c / st.band_c) if lag_error_c > st.band_c else 0.0
    return decay + st.dwell_s


def sample_time_s(plan: Plan, station: Station) -> float:
    """Time for one sample of every DUT. Reading is interleaved (rig/interleave.py): the DUTs wait for
    their conversions together, so a sample takes as long as the slowest DUT, except that DUTs sharing
    one serial line are polled in turn."""
    pair = plan.set_reset == "pair"
    groups: dict[tuple[str, str], float] = {}
    for d in station.duts:
        line, port = getattr(d.transport, "line", None), getattr(d.transport, "port", None)
        key = ("line", line) if line else ("port", port) if port else ("dut", d.name)
        groups[key] = groups.get(key, 0.0) + d.spec.sample_time_s(d.options, pair)
    return max(groups.values())


def estimate_duration(plan: Plan, station: Station, points: list[Point],
                      n_fields: int) -> dict[str, float]:
    """Seconds spent ramping, waiting for stability, moving/settling and sampling (see sample_time_s);
    real-station mounts are assumed to lag by ASSUMED_THERMAL_LAG_S."""
    lags = [_stated(station.sim.duts[d.name].thermal_lag_s if d.simulated and d.name in station.sim.duts
                    else None, ASSUMED_THERMAL_LAG_S) for d in station.duts]
    lag_s = max(lags)
    ramp_s = stable_s = 0.0
    temp = _stated(station.sim.air_c if station.chamber.simulated else None, ASSUMED_START_C)
    for p in points[::n_fields]:
        rate = min(p.ramp_c_per_min, station.chamber.limits.max_ramp_c_per_min)
        delta = p.setpoint_c - temp
        ramp_s += abs(delta) / rate * 60.0
        stable_s += _settle_after_ramp_s(delta, rate, lag_s, p.stability)
        temp = p.setpoint_c
    move_s = sum(p.settle_s for p in points) + station.field_source.move_time_s([p.command for p in points])
    sampling_s = sample_time_s(plan, station) * sum(p.samples for p in points)
    return {"ramps": ramp_s, "stability": stable_s, "moves+settle": move_s, "sampling": sampling_s}


def t24_design_problem(points: list[Point], station: Station) -> str | None:
    """What a T24 fit could not identify from this plan (None if all is fine), judged on the nominal
    fields and setpoints with calib's own Gram test: the sensor's axes are taken as the lab's."""
    from calib.gram import GramAccumulator

    fields = np.array([station.field_source.nominal_field_nt(p.command) for p in points])
    temps = np.array([p.setpoint_c for p in points])
    samples = [p.samples for p in points]
    acc = GramAccumulator(temp_ref_c=float(temps.mean()))
    repeated = np.repeat(fields, samples, axis=0)  # bounded by MAX_SAMPLES_PER_DUT
    acc.add(repeated, np.repeat(temps, samples), repeated)
    return acc.identifiability()


_DURATION_KEYS: dict[str, KeyPath] = {
    "ramps": ("temperatures", "ramp_c_per_min"),
    "stability": ("temperatures", "stability"),
    "moves+settle": ("settle_s",),
    "sampling": ("samples_per_point",),
}


def _check_duration(plan: Plan, breakdown: dict[str, float],
                    keys: dict[str, KeyPath] = _DURATION_KEYS) -> None:
    """Refuse a plan that would run for more than MAX_DURATION_S, blaming its largest part."""
    total = sum(breakdown.values())
    if math.isfinite(total) and total <= MAX_DURATION_S:
        return
    part = max(breakdown, key=lambda k: breakdown[k] if math.isfinite(breakdown[k]) else math.inf)
    days = total / 86_400.0
    raise _plan_error(ConfigError, plan, keys[part],
                      f"estimated duration {days:.3g} days (mostly {part}) is longer than the bound of "
                      f"{MAX_DURATION_S / 86_400.0:g} days")


def check_campaign(campaign: Campaign) -> PlanCheck:
    """check_plan with its errors naming the plan or station file, key and line."""
    with located_errors(campaign):
        return check_plan(campaign.plan, campaign.station)


def check_plan(plan: Plan, station: Station) -> PlanCheck:
    """Validate `plan` against `station` without touching hardware. Raises LimitError naming the limit."""
    if plan.ramp is not None:
        from rig.rampplan import check_ramp

        return check_ramp(plan, station)
    points = compile_plan(plan, station)
    n_temps, n_fields = check_size(plan)
    warnings: list[str] = []
    _check_setpoints(plan, station, points)
    source_lines = _check_targets(plan, station, points, warnings)
    if "t24" in plan.fit.models:
        problem = t24_design_problem(points, station)
        if problem:
            warnings.append(problem)
    breakdown = estimate_duration(plan, station, points, n_fields)
    _check_duration(plan, breakdown)
    if plan.stop_when:
        from rig.rampplan import stop_when_line

        source_lines = [*source_lines, stop_when_line(plan, sum(breakdown.values()))]
    return PlanCheck(
        points=points,
        n_temperatures=n_temps,
        n_fields=n_fields,
        n_duts=len(station.duts),
        samples_per_dut=len(points) * plan.samples_per_point,
        duration_s=sum(breakdown.values()),
        breakdown_s=breakdown,
        source_lines=source_lines,
        warnings=warnings,
    )
