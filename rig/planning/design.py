"""`rig design`: a plan's targets, its station's DUTs and chamber, turned into the least-time plan.

    inputs = design_inputs(plan, station, session=None)     # targets, each DUT's noise and lag, the range
    designed = design_plan(plan, station, inputs)            # fields, samples, legs (calib/design/planner.py)
    text = designed_plan_text(plan_text, designed, ...)      # a normal plan file: rig check / rig run take it

Where the numbers come from (rig/planning/inputs.py, each with its origin printed):
- targets: the plan's `stop_when`, else its `acceptance.max_std_error` (t24);
- each DUT's noise (one fitted sample, per axis), its lag behind the air and where it settles relative to
  it: an earlier session given with --from (rig/planning/measured.py), a designed plan's `assumed:`, the
  station's thermal commissioning, the station's `duts[].expect`; with none of them the design stops in one
  line naming the three ways. The simulated world's own values are never read: a design --from a session
  is the same whatever the station's `sim:` says;
- the range: the plan's temperatures (steps: lowest and highest; ramp or sequential: range_c), at the DUTs;
- the chamber's pace and starting air, the pace of a point: measured (--from, the thermal commissioning),
  else the station's stated limit and the drivers' stated conversion times, said so.
The field set is the I-optimal (or D-optimal) exact design over the plan's own fields
(calib/design/optimal.py, Fedorov exchange on the [1, h] part of T24, which separates from the temperatures);
the samples per point are as many as keep one sweep within the ramp check's span; the legs come from
calib/design/planner.py, each end held until the slowest DUT is within END_TOLERANCE_SHARE of the plan's
stability band of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from calib.design.optimal import exchange
from calib.design.planner import (
    CHECK,
    ChamberModel,
    DutModel,
    Leg,
    Pace,
    Schedule,
    crossing_rate,
    design_schedule,
    summarise,
    temp_ref_of,
)
from rig.config import DesignedTemperatures, Plan, Station, VectorFields
from rig.core.errors import ConfigError
from rig.planning.facts import Timing
from rig.planning.inputs import PlanningInputs, dut_models, planning_inputs, require_duts
from rig.planning.pace import (
    MAX_DURATION_S,
    MAX_POINTS,
    MAX_SAMPLES_PER_DUT,
    MAX_SWEEP_SPAN_FRACTION,
    field_targets,
    format_duration,
    sweep_time_s,
)

MAX_SAMPLES = 100  # per point; beyond this a sweep gains little and spans more temperature
MIN_SWEEP_FIELDS = 8  # [1, h] has 4 parameters; twice that keeps a sweep balanced
MAX_SWEEP_FIELDS = 24
DEFAULT_CHECKS = 3  # interior temperatures of the model check
DESIGN_HORIZON_S = 7 * 86_400.0  # the search looks no further than this
# a designed end is held until the slowest DUT is predicted within this share of the plan's stability band
# of it; the rest is left for the error of its measured lag and offset (acceptance judges the whole band)
END_TOLERANCE_SHARE = 0.5


@dataclass
class DesignInputs:
    targets: dict[str, float]
    planning: PlanningInputs
    duts: list[DutModel]
    range_c: tuple[float, float]
    band_c: float

    @property
    def origins(self) -> dict[str, str]:
        return {name: d.origin for name, d in self.planning.duts.items()}

    @property
    def notes(self) -> list[str]:
        return self.planning.notes

    @property
    def rate_c_per_min(self) -> float:
        return self.planning.rate_c_per_min

    @property
    def start_c(self) -> float:
        return self.planning.chamber.start_c


@dataclass
class Designed:
    """The designed plan's pieces: its fields, samples per point, legs and their prediction."""

    targets_nt: list[tuple[float, ...]]
    samples: int
    rate_c_per_min: float
    schedule: Schedule
    inputs: DesignInputs
    criterion: str
    sweep_s: float


# --- inputs -------------------------------------------------------------------------------------------
def plan_targets(plan: Plan) -> dict[str, float]:
    targets = plan.se_targets()
    if not targets:
        raise ConfigError(f"plan {plan.name}: nothing to design for: give stop_when (target standard errors "
                          "S, K, b, kb) or acceptance.max_std_error for t24")
    return targets


def plan_range(plan: Plan) -> tuple[float, float]:
    lo, hi = plan.temperatures.covered_c()
    if hi - lo < 1.0:
        raise ConfigError(f"plan {plan.name}: temperatures span {hi - lo:g} degC; a T24 design needs a range")
    return lo, hi


def design_inputs(plan: Plan, station: Station, session: Path | None = None) -> DesignInputs:
    """The targets, and every DUT's noise and lag from a measurement or the station's statement (ConfigError
    naming the three ways when a DUT has neither)."""
    targets, range_c = plan_targets(plan), plan_range(plan)
    planning = planning_inputs(plan, station, session)
    require_duts(planning, station)
    return DesignInputs(targets, planning, dut_models(planning), range_c, plan.temperatures.band_c())


# --- the design ----------------------------------------------------------------------------------------
def design_fields(plan: Plan, station: Station, criterion: str) -> list[tuple[float, ...]]:
    """The sweep: an exact optimal design over the plan's own field targets, in the plan's order."""
    targets = field_targets(plan, station)
    h = np.array([station.field_source.nominal_field_nt(t) for t in targets], float)
    x = np.column_stack([np.ones(len(h)), h])
    if len(targets) <= MIN_SWEEP_FIELDS:
        return list(targets)
    from calib.design.optimal import optimal_weights

    w, _ = optimal_weights(x, criterion, tol=1e-3)
    support = int(np.sum(w >= 1e-3 * w.max()))
    n = min(max(support, MIN_SWEEP_FIELDS), MAX_SWEEP_FIELDS, len(targets))
    chosen = exchange(x, n, criterion)
    return [targets[i] for i in sorted(chosen)]


def _with(plan: Plan, fields: list[tuple[float, ...]], samples: int, station: Station) -> Plan:
    if "vectors" in station.field_source.field_kinds:
        fieldset = VectorFields(kind="vectors", vectors_nt=[tuple(f) for f in fields])
    else:
        from rig.config import ListOrientations

        fieldset = ListOrientations(kind="orientations", angles_deg=[tuple(f) for f in fields])
    return plan.model_copy(update={"fields": fieldset, "samples_per_point": samples})


def pace_for(plan: Plan, station: Station, fields: list[tuple[float, ...]], samples: int,
             timing: Timing | None = None) -> Pace:
    """One sweep of `fields` with `samples` per point, timed as rig check times it (at `timing`'s pace)."""
    sweep_s = sum(sweep_time_s(_with(plan, fields, samples, station), station, fields, timing).values())
    nominal = np.array([station.field_source.nominal_field_nt(f) for f in fields], float)
    return Pace(nominal, samples, sweep_s / len(fields))


def design_plan(plan: Plan, station: Station, inputs: DesignInputs, *, criterion: str = "I",
                n_checks: int = DEFAULT_CHECKS, check_sweeps: int = 1) -> Designed:
    fields = design_fields(plan, station, criterion)
    lo, hi = inputs.range_c
    timing = inputs.planning.timing
    rate = crossing_rate(inputs.rate_c_per_min, hi - lo, max(d.lag_s for d in inputs.duts))
    allowed_s = MAX_SWEEP_SPAN_FRACTION * (hi - lo) / rate * 60.0  # one sweep may span this much
    one = pace_for(plan, station, fields, 1, timing)
    two = pace_for(plan, station, fields, 2, timing)
    per_sample_s = two.sweep_s - one.sweep_s
    samples = int((allowed_s - one.sweep_s) // per_sample_s) + 1 if per_sample_s > 0 else MAX_SAMPLES
    samples = min(max(samples, 1), MAX_SAMPLES)
    pace = pace_for(plan, station, fields, samples, timing)
    if pace.sweep_s > allowed_s:  # even one sample is too slow for the chamber's rate: ramp slower
        rate = MAX_SWEEP_SPAN_FRACTION * (hi - lo) / pace.sweep_s * 60.0
    checks = tuple(round((lo + (hi - lo) * (k + 1) / (n_checks + 1)) * 2) / 2 for k in range(n_checks))
    lim = station.chamber.limits
    chamber = ChamberModel((lo, hi), rate, checks, check_sweeps, END_TOLERANCE_SHARE * inputs.band_c,
                           (lim.min_setpoint_c, lim.max_setpoint_c),
                           getattr(plan.temperatures, "end_overshoot_c", 0.0))
    most_sweeps = min(MAX_POINTS // len(fields), MAX_SAMPLES_PER_DUT // (len(fields) * samples))
    longest_s = min(DESIGN_HORIZON_S, MAX_DURATION_S, most_sweeps * pace.sweep_s)  # a plan rig check takes
    schedule = design_schedule(inputs.duts, chamber, pace, inputs.targets, start_c=inputs.start_c,
                               max_duration_s=longest_s)
    return Designed(fields, samples, rate, schedule, inputs, criterion, pace.sweep_s)


# --- the output plan ------------------------------------------------------------------------------------
def designed_plan_dict(plan_text: str, designed: Designed, station: Station, name: str) -> dict:
    """The plan file's content with the designed temperatures, fields and samples (all else kept)."""
    data = yaml.safe_load(plan_text) or {}
    data["name"] = name
    legs = []
    for leg in designed.schedule.legs:
        entry = {"to_c": float(leg.to_c), "sweeps": int(leg.sweeps)}
        if leg.kind == CHECK:
            entry["check"] = True
        legs.append(_FlowMap(entry))
    planning = designed.inputs.planning
    assumed = {}
    for d in designed.inputs.duts:
        entry = {"noise_nt": _round(d.sigma_nt), "lag_s": _round(d.lag_s)}
        if planning.duts[d.name].offset_c is not None:
            entry["offset_c"] = round(float(d.offset_c), 3)
        assumed[d.name] = _FlowMap(entry)
    temps = {"mode": "designed", "rate_c_per_min": _round(designed.rate_c_per_min), "legs": legs,
             "range_c": _Flow(float(v) for v in designed.inputs.range_c), "assumed": assumed}
    if not planning.timing.origin.startswith("the drivers'"):
        temps["timing"] = _FlowMap(sample_s=_round(planning.timing.sample_s),
                                   point_overhead_s=_round(planning.timing.point_overhead_s),
                                   measured_by=planning.timing.origin.split(":")[0])
    stability = (data.get("temperatures") or {}).get("stability")
    if stability is not None:
        temps["stability"] = stability
    data["temperatures"] = temps
    data.pop("field_order", None)  # a step plan's: the designed sweeps go in their own order
    if "vectors" in station.field_source.field_kinds:
        data["fields"] = {"kind": "vectors",
                          "vectors_nt": [_Flow(_round(v) for v in f) for f in designed.targets_nt]}
    else:
        data["fields"] = {"kind": "orientations",
                          "angles_deg": [_Flow(_round(v) for v in f) for f in designed.targets_nt]}
    data["samples_per_point"] = designed.samples
    return data


def _round(value: float) -> float:
    return float(f"{value:.6g}")


def designed_plan_text(plan_text: str, designed: Designed, station: Station, *, name: str,
                       station_ref: str | None, made_for: str) -> str:
    data = designed_plan_dict(plan_text, designed, station, name)
    if station_ref is not None:
        data["station"] = station_ref
    else:
        data.pop("station", None)
    s = designed.schedule
    head = [f"# Designed by `rig design` for station {station.name}, {made_for}.",
            f"# Targets: {', '.join(f'{k} {v:g}' for k, v in designed.inputs.targets.items())}; "
            f"{designed.criterion}-optimal fields; predicted chamber time {format_duration(s.duration_s)}; "
            f"{s.message}.",
            "# `rig check` prints the predicted standard errors against chamber time (--figure FILE.png)."]
    return "\n".join(head) + "\n" + yaml.dump(data, Dumper=_PlanDumper, sort_keys=False, width=110)


class _Flow(list):
    """A list written on one line ([a, b, c]) in the plan file."""


class _FlowMap(dict):
    """A mapping written on one line ({to_c: -30, sweeps: 12})."""


class _PlanDumper(yaml.SafeDumper):
    pass


_PlanDumper.add_representer(_Flow, lambda d, v: d.represent_sequence("tag:yaml.org,2002:seq", v,
                                                                     flow_style=True))
_PlanDumper.add_representer(_FlowMap, lambda d, v: d.represent_mapping("tag:yaml.org,2002:map", v.items(),
                                                                        flow_style=True))


# --- rig check of a designed plan ---------------------------------------------------------------------
def predicted_lines(plan: Plan, station: Station, targets_nt: list[tuple[float, ...]],
                    sweep_s: float) -> tuple[Schedule | None, list[str]]:
    """The standard errors a designed plan's legs predict, against chamber time (one line per leg), for
    rig check; none when the plan states no targets."""
    temps = plan.temperatures
    assert isinstance(temps, DesignedTemperatures)
    targets = plan.se_targets()
    if not targets:
        return None, ["predicted standard errors: give stop_when or acceptance.max_std_error to see them"]
    planning = planning_inputs(plan, station)
    if planning.missing():
        return None, [f"predicted standard errors: not predicted: no measured lags and noise for "
                      f"{', '.join(planning.missing()[:4])}"]
    inputs = DesignInputs(targets, planning, dut_models(planning), plan_range(plan), temps.band_c())
    nominal = np.array([station.field_source.nominal_field_nt(t) for t in targets_nt], float)
    pace = Pace(nominal, plan.samples_per_point, sweep_s / len(targets_nt))
    legs = [Leg(leg.to_c, leg.sweeps, leg.rate_c_per_min or temps.rate_c_per_min,
                CHECK if leg.check else "end")
            for leg in temps.legs]
    lo, hi = inputs.range_c
    schedule = summarise(legs, inputs.duts, pace, targets, temp_ref_of(ChamberModel((lo, hi), 1.0)),
                         inputs.start_c)
    return schedule, schedule_lines(schedule, inputs)


# the units of the T24 parameter groups a design aims at (S is a ratio: no unit)
TARGET_UNITS = {"S": "", "K": " /degC", "b": " nT", "kb": " nT/degC"}


def schedule_lines(schedule: Schedule, inputs: DesignInputs) -> list[str]:
    """Largest predicted standard error over the DUTs per group at the end of every leg, and which DUT."""
    groups = schedule.groups
    targets = inputs.targets
    lines = ["predicted standard errors (largest over the DUTs) against chamber time; targets "
             + ", ".join(f"{g} {targets[g]:g}{TARGET_UNITS.get(g, '')}" for g in groups) + ":"]
    ends = np.cumsum([leg.sweeps for leg in schedule.legs]) - 1
    for j, end in enumerate(ends):
        worst = {g: max(schedule.ratios[d][end][i] for d in schedule.ratios) for i, g in enumerate(groups)}
        leg = schedule.legs[j]
        what = f"leg {j + 1} ({leg.to_c:g} degC{', check' if leg.kind == CHECK else ''})"
        lines.append(f"  {format_duration(schedule.sweep_end_s[end]):>7} after {what}: "
                     + ", ".join(f"{g} {worst[g] * targets[g]:.3g}{TARGET_UNITS.get(g, '')}" for g in groups))
    lines.append(f"  {schedule.message}")
    if schedule.element_c:
        low = max(float(np.min(e)) for e in schedule.element_c.values())
        high = min(float(np.max(e)) for e in schedule.element_c.values())
        lo, hi = inputs.range_c
        lines.append(f"  every DUT's element reaches {low:.1f} and {high:.1f} degC (predicted; the range "
                     f"{lo:g} .. {hi:g} degC, stability band {inputs.band_c:g})")
    for d in inputs.duts:
        offset = "" if d.offset_c == 0 else f", settles {d.offset_c:+.2f} degC from the air"
        lines.append(f"  {d.name}: noise {d.sigma_nt:.3g} nT, lag {d.lag_s:.0f} s{offset} "
                     f"({inputs.origins[d.name]})")
    return lines
