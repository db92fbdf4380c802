"""A plan compiled against its station: the deterministic list of points a campaign collects.

    points = compile_plan(plan, station)       # [Point], temperature-major
    report = check_plan(plan, station)         # limits checked without hardware; raises LimitError
    report.summary_lines()                     # what `rig check` prints (sizes, duration, warnings)

Point ids are stable: `T03-F07` is temperature step 3, field 7 (coils); `T03-O07` orientation 7
(turntable). Numbers are 1-based and zero-padded to at least 2 digits (3 when there are > 99).
Sizes are counted before anything is expanded: a plan over MAX_POINTS points, MAX_SAMPLES_PER_DUT
samples per DUT or MAX_DURATION_S is refused (ConfigError) before memory is allocated for it.
Errors found here carry `blame = (document, key path, what)`; `located_errors(campaign)` turns them
into the `FILE: key.path: what (line N)` form of every config error.
For coils the target is the total field (lab frame, nT) the coils must make, ambient included; for a
turntable it is (az_deg, el_deg).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from rig import fieldsets
from rig.config import (
    COIL_FIELD_KINDS,
    TABLE_FIELD_KINDS,
    TYPICAL_FIELD_NT,
    Campaign,
    Coils,
    Cube24Fields,
    DirectionFields,
    FibonacciFields,
    GridOrientations,
    ListOrientations,
    Plan,
    Stability,
    Station,
    Turntable,
    VectorFields,
)
from rig.errors import ConfigError, LimitError
from rig.reference import currents_for_field, station_site_field_nt, table_field_nt
from rig.yamlload import KeyPath, format_path, locate_in_text

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
    field_nt: tuple[float, float, float] | None  # coils: total field to make, lab frame
    angles_deg: tuple[float, float] | None  # turntable: (az, el)
    samples: int
    settle_s: float
    ramp_c_per_min: float
    stability: Stability

    @property
    def target(self) -> dict:
        """The commanded target as plain data (stored with the point)."""
        if self.field_nt is not None:
            return {"field_nt": list(self.field_nt)}
        return {"az_deg": self.angles_deg[0], "el_deg": self.angles_deg[1]}  # type: ignore[index]


def blamed(err: Exception, path: KeyPath, what: str, document: str = "plan") -> Exception:
    """Mark an error with the config key it is about (see located_errors)."""
    err.blame = (document, tuple(path), what)  # type: ignore[attr-defined]
    return err


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


def count_fields(plan: Plan) -> int:
    """Number of field targets, counted without making them."""
    fs = plan.fields
    if isinstance(fs, GridOrientations):
        n = len(fs.az_deg) * len(fs.el_deg)
    elif isinstance(fs, ListOrientations):
        n = len(fs.angles_deg)
    elif isinstance(fs, VectorFields):
        n = len(fs.vectors_nt)
    else:
        if isinstance(fs, Cube24Fields):
            per = 24
        else:
            per = fs.n if isinstance(fs, FibonacciFields) else len(fs.directions)
        n = per * len(fs.magnitude_list())
    if n > MAX_FIELDS:
        raise _plan_error(ConfigError, plan, ("fields",), f"{n} field targets; at most {MAX_FIELDS}")
    return n


def check_size(plan: Plan, station: Station) -> tuple[int, int]:
    """(temperatures, fields) of the plan; ConfigError before anything big is built."""
    n_temps, n_fields = count_temperatures(plan), count_fields(plan)
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
    """Field vectors (nT) for coils or (az, el) pairs for a turntable, in plan order."""
    fs = plan.fields
    source = station.field_source
    if isinstance(source, Coils) and fs.kind not in COIL_FIELD_KINDS:
        raise _plan_error(ConfigError, plan, ("fields", "kind"),
                          f"{fs.kind!r} needs a turntable; station {station.name} has coils "
                          f"(use one of {', '.join(sorted(COIL_FIELD_KINDS))})")
    if isinstance(source, Turntable) and fs.kind not in TABLE_FIELD_KINDS:
        raise _plan_error(ConfigError, plan, ("fields", "kind"),
                          f"{fs.kind!r} needs coils; station {station.name} has a turntable "
                          f"(use one of {', '.join(sorted(TABLE_FIELD_KINDS))})")
    if isinstance(fs, GridOrientations):
        return fieldsets.grid_orientations(fs.az_deg, fs.el_deg)
    if isinstance(fs, ListOrientations):
        return [tuple(map(float, a)) for a in fs.angles_deg]
    if isinstance(fs, Cube24Fields | FibonacciFields | DirectionFields):
        if isinstance(fs, Cube24Fields):
            directions = fieldsets.cube24_directions()
        elif isinstance(fs, FibonacciFields):
            directions = fieldsets.fibonacci_directions(fs.n)
        else:
            try:
                directions = fieldsets.normalised(fs.directions)
            except ValueError as exc:
                raise _plan_error(ConfigError, plan, ("fields", "directions"), str(exc)) from None
        vectors = fieldsets.scaled(directions, fs.magnitude_list())
    else:
        vectors = np.asarray(fs.vectors_nt, float)
    return [tuple(float(x) for x in v) for v in vectors]


def point_id(temp_index: int, field_index: int, n_temps: int, n_fields: int, letter: str = "F") -> str:
    tw, fw = max(2, len(str(n_temps))), max(2, len(str(n_fields)))
    return f"T{temp_index:0{tw}d}-{letter}{field_index:0{fw}d}"


def compile_plan(plan: Plan, station: Station) -> list[Point]:
    check_size(plan, station)
    steps = plan.temperatures.step_list()
    targets = field_targets(plan, station)
    coils = isinstance(station.field_source, Coils)
    letter = "F" if coils else "O"
    points = []
    for ti, step in enumerate(steps, start=1):
        stability = plan.temperatures.stability_for(step)
        ramp = step.ramp_c_per_min or plan.temperatures.ramp_c_per_min
        for fi, target in enumerate(targets, start=1):
            points.append(Point(
                id=point_id(ti, fi, len(steps), len(targets), letter),
                index=len(points),
                temp_index=ti,
                setpoint_c=step.setpoint_c,
                field_index=fi,
                field_nt=target if coils else None,  # type: ignore[arg-type]
                angles_deg=None if coils else target,  # type: ignore[arg-type]
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
    max_current_a: float | None = None
    warnings: list[str] = field(default_factory=list)

    def summary_lines(self) -> list[str]:
        lines = [
            f"{len(self.points)} points = {self.n_temperatures} temperatures x {self.n_fields} fields; "
            f"{self.samples_per_dut} samples per DUT, {self.n_duts} DUT(s)",
            f"estimated duration {format_duration(self.duration_s)} ("
            + ", ".join(f"{k} {format_duration(v)}" for k, v in self.breakdown_s.items()) + ")",
        ]
        if self.max_current_a is not None:
            lines.append(f"largest coil current {self.max_current_a:.3f} A")
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
    """The plan key of one field target, where the plan lists them one by one."""
    keys = {"vectors": "vectors_nt", "orientations": "angles_deg", "directions": "directions"}
    key = keys.get(plan.fields.kind)
    return ("fields", key, field_index - 1) if key else ("fields",)


def _check_coils(plan: Plan, coils: Coils, points: list[Point], warnings: list[str]) -> float:
    """Largest current magnitude over all points; LimitError when one exceeds max_current_a."""
    inv = np.linalg.inv(coils.constants)
    if isinstance(coils.ambient_nt, str):
        ambient = np.zeros(3)
        margin = np.linalg.norm(inv, axis=1) * coils.ambient_max_nt  # worst case over |ambient| <= max
        assumption = (f"any ambient up to {coils.ambient_max_nt:g} nT (field_source.ambient_max_nt; "
                      "ambient_nt is 'measure')")
        warnings.append(f"ambient field not yet measured: currents checked for {assumption}")
    else:
        ambient, margin = np.asarray(coils.ambient_nt, float), np.zeros(3)
        assumption = "the station's ambient_nt"
    largest = 0.0
    for p in points:
        worst = np.abs(currents_for_field(p.field_nt, coils.constants, ambient)) + margin
        axis = int(np.argmax(worst))
        if worst[axis] > coils.max_current_a:
            n_dirs = len(plan.fields.directions) if isinstance(plan.fields, DirectionFields) else 0
            index = (p.field_index - 1) % n_dirs + 1 if n_dirs else p.field_index  # magnitude-major
            path = _field_path(plan, index)
            raise _plan_error(
                LimitError, plan, path,
                f"point {p.id} field {_fmt_vec(p.field_nt)} nT needs {worst[axis]:.3f} A "
                f"in coil {'xyz'[axis]} with {assumption}, above field_source.max_current_a "
                f"{coils.max_current_a:g} A"
            )
        largest = max(largest, float(worst[axis]))
    return largest


def _check_angles(plan: Plan, table: Turntable, points: list[Point]) -> None:
    for p in points:
        for value, key, (lo, hi) in zip(p.angles_deg, ("az_limits_deg", "el_limits_deg"),  # type: ignore[arg-type]
                                        (table.az_limits_deg, table.el_limits_deg), strict=True):
            if not lo <= value <= hi:
                raise _plan_error(LimitError, plan, _field_path(plan, p.field_index),
                                  f"point {p.id} angle {value:g} deg is outside "
                                  f"field_source.{key} [{lo:g}, {hi:g}]")


def _fmt_vec(v) -> str:
    return "(" + ", ".join(f"{x:.0f}" for x in v) + ")"


def _settle_after_ramp_s(delta_c: float, ramp_c_per_min: float, lag_s: float, st: Stability) -> float:
    """A first-order mount lags a ramp by rate*lag; after the ramp that error decays with the lag."""
    lag_error_c = min(abs(delta_c), ramp_c_per_min / 60.0 * lag_s)
    decay = lag_s * math.log(lag_error_c / st.band_c) if lag_error_c > st.band_c else 0.0
    return decay + st.dwell_s


def estimate_duration(plan: Plan, station: Station, points: list[Point],
                      n_fields: int) -> dict[str, float]:
    """Seconds spent ramping, waiting for stability, moving/settling and sampling. DUTs are assumed to
    be read one after another; real-station mounts are assumed to lag by ASSUMED_THERMAL_LAG_S."""
    lags = [station.sim.duts[d.name].thermal_lag_s if d.simulated and d.name in station.sim.duts
            else ASSUMED_THERMAL_LAG_S for d in station.duts]
    lag_s = max(lags)
    ramp_s = stable_s = 0.0
    temp = station.sim.air_c if station.chamber.simulated else ASSUMED_START_C
    for p in points[::n_fields]:
        rate = min(p.ramp_c_per_min, station.chamber.limits.max_ramp_c_per_min)
        delta = p.setpoint_c - temp
        ramp_s += abs(delta) / rate * 60.0
        stable_s += _settle_after_ramp_s(delta, rate, lag_s, p.stability)
        temp = p.setpoint_c
    move_s = sum(p.settle_s for p in points)
    source = station.field_source
    if isinstance(source, Turntable):
        angles = np.array([(0.0, 0.0)] + [p.angles_deg for p in points])
        travel = float(np.abs(np.diff(angles, axis=0)).max(axis=1).sum())  # both axes move at once
        move_s += travel / source.rate_deg_s
    pair = plan.set_reset == "pair"
    per_sample = sum(d.sample_time_s(pair and d.type in ("mmc5983ma", "serialmag")) for d in station.duts)
    sampling_s = per_sample * sum(p.samples for p in points)
    return {"ramps": ramp_s, "stability": stable_s, "moves+settle": move_s, "sampling": sampling_s}


def t24_design_problem(points: list[Point], station: Station) -> str | None:
    """What a T24 fit could not identify from this plan (None if all is fine), judged on the nominal
    fields and setpoints with calib's own Gram test: the sensor's axes are taken as the lab's."""
    from calib.gram import GramAccumulator

    if isinstance(station.field_source, Coils):
        fields = np.array([p.field_nt for p in points])
    else:
        site = station_site_field_nt(station.field_source)
        site = np.asarray(TYPICAL_FIELD_NT) if site is None else site
        fields = np.array([table_field_nt(site, *p.angles_deg) for p in points])
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


def _check_duration(plan: Plan, breakdown: dict[str, float]) -> None:
    """Refuse a plan that would run for more than MAX_DURATION_S, blaming its largest part."""
    total = sum(breakdown.values())
    if math.isfinite(total) and total <= MAX_DURATION_S:
        return
    part = max(breakdown, key=lambda k: breakdown[k] if math.isfinite(breakdown[k]) else math.inf)
    days = total / 86_400.0
    raise _plan_error(ConfigError, plan, _DURATION_KEYS[part],
                      f"estimated duration {days:.3g} days (mostly {part}) is longer than the bound of "
                      f"{MAX_DURATION_S / 86_400.0:g} days")


def check_campaign(campaign: Campaign) -> PlanCheck:
    """check_plan with its errors naming the plan or station file, key and line."""
    with located_errors(campaign):
        return check_plan(campaign.plan, campaign.station)


def check_plan(plan: Plan, station: Station) -> PlanCheck:
    """Validate `plan` against `station` without touching hardware. Raises LimitError naming the limit."""
    points = compile_plan(plan, station)
    n_temps, n_fields = check_size(plan, station)
    warnings: list[str] = []
    _check_setpoints(plan, station, points)
    largest = None
    source = station.field_source
    if isinstance(source, Coils):
        largest = _check_coils(plan, source, points, warnings)
        span = fieldsets.span_ratio(np.array([p.field_nt for p in points[:n_fields]]))
        if span < 0.2:
            warnings.append(f"field directions barely span 3-D (ratio {span:.2f}): the scale and cross-axis "
                            "terms will be poorly determined")
    else:
        _check_angles(plan, source, points)
    if "t24" in plan.fit.models:
        problem = t24_design_problem(points, station)
        if problem:
            warnings.append(problem)
    breakdown = estimate_duration(plan, station, points, n_fields)
    _check_duration(plan, breakdown)
    return PlanCheck(
        points=points,
        n_temperatures=n_temps,
        n_fields=n_fields,
        n_duts=len(station.duts),
        samples_per_dut=len(points) * plan.samples_per_point,
        duration_s=sum(breakdown.values()),
        breakdown_s=breakdown,
        max_current_a=largest,
        warnings=warnings,
    )
