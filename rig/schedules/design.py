"""`rig design`: a plan's targets, its station's DUTs and chamber, turned into the least-time plan.

    inputs = design_inputs(plan, station, session=None)     # targets, each DUT's noise and lag, the range
    designed = design_plan(plan, station, inputs)            # fields, samples, legs (calib/planner.py)
    text = designed_plan_text(plan_text, designed, ...)      # a normal plan file: rig check / rig run take it

Where the numbers come from, in order:
- targets: the plan's `stop_when`, else its `acceptance.max_std_error` (t24);
- each DUT's noise (one fitted sample, per axis) and lag behind the air: an earlier session given with
  --from (the T24 fit's residual sigma; the lag from the temperature settling in its longest hold,
  calib/lag.py), else a designed plan's `assumed:`, else the station's simulated values (a SET/RESET pair
  halves the variance), else ASSUMED_NOISE_NT and plancheck's ASSUMED_THERMAL_LAG_S for a real DUT;
- the range: the plan's temperatures (steps: lowest and highest; ramp or sequential: range_c);
- the chamber's maximum ramp rate, the field source's move and settle times and the sample time.
The field set is the I-optimal (or D-optimal) exact design over the plan's own fields (calib/design.py,
Fedorov exchange on the [1, h] part of T24, which separates from the temperatures); the samples per point
are as many as keep one sweep within the ramp check's span; the legs come from calib/planner.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from calib.design import exchange
from calib.planner import (
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
from rig.config import (
    DesignedTemperatures,
    Plan,
    RampTemperatures,
    SequentialTemperatures,
    Station,
    VectorFields,
)
from rig.core.errors import ConfigError, DataError
from rig.schedules.check import (
    ASSUMED_THERMAL_LAG_S,
    MAX_DURATION_S,
    fastest_ramp_c_per_min,
    field_targets,
    format_duration,
    start_air_c,
)

ASSUMED_NOISE_NT = 50.0  # a real DUT's noise per fitted sample and axis when nothing says otherwise
MAX_SAMPLES = 100  # per point; beyond this a sweep gains little and spans more temperature
MIN_SWEEP_FIELDS = 8  # [1, h] has 4 parameters; twice that keeps a sweep balanced
MAX_SWEEP_FIELDS = 24
DEFAULT_CHECKS = 3  # interior temperatures of the model check
DESIGN_HORIZON_S = 7 * 86_400.0  # the search looks no further than this


@dataclass
class DesignInputs:
    targets: dict[str, float]
    duts: list[DutModel]
    origins: dict[str, str]  # DUT -> where its noise and lag came from
    range_c: tuple[float, float]
    rate_c_per_min: float
    start_c: float
    notes: list[str] = field(default_factory=list)


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
    temps = plan.temperatures
    if isinstance(temps, RampTemperatures | SequentialTemperatures):
        values = list(temps.range_c)
    elif isinstance(temps, DesignedTemperatures):
        values = [leg.to_c for leg in temps.legs if not leg.check]
    else:
        values = [s.setpoint_c for s in temps.step_list()]
    lo, hi = min(values), max(values)
    if hi - lo < 1.0:
        raise ConfigError(f"plan {plan.name}: temperatures span {hi - lo:g} degC; a T24 design needs a range")
    return lo, hi


def station_duts(plan: Plan, station: Station) -> tuple[list[DutModel], dict[str, str]]:
    """Each DUT's noise and lag as the station states them (simulated), or assumed (real)."""
    from rig.devices.bench import dut_truths

    truths = dut_truths(station)
    duts, origins = [], {}
    for d in station.duts:
        truth = truths.get(d.name)
        if truth is None:
            duts.append(DutModel(d.name, ASSUMED_NOISE_NT, ASSUMED_THERMAL_LAG_S))
            origins[d.name] = (f"assumed (real DUT): noise {ASSUMED_NOISE_NT:g} nT, lag "
                               f"{ASSUMED_THERMAL_LAG_S:g} s; design --from a session to measure them")
            continue
        pair = plan.set_reset == "pair" and bool(getattr(d.options, "set_reset", False))
        sigma = truth.noise_nt / (math.sqrt(2.0) if pair else 1.0)
        duts.append(DutModel(d.name, max(sigma, 1e-3), truth.thermal_lag_s))
        origins[d.name] = "the station's simulated values"
    return duts, origins


def session_duts(session: Path, base: list[DutModel]) -> tuple[list[DutModel], dict[str, str], list[str]]:
    """Noise and lag measured by an earlier session: the residual sigma of each DUT's T24 fit (lag-corrected
    for a ramp), and its lag from the temperature settling in the session's holds (calib/lag.py)."""
    import calib
    from rig.analysis.lagfit import lag_corrected, session_is_ramp
    from rig.session.reader import read_dataset

    moving = session_is_ramp(session)
    out, origins, notes = [], {}, []
    for prior in base:
        try:
            ds = read_dataset(session, prior.name)
        except DataError as exc:
            raise DataError(f"--from {session}: {exc}") from None
        lag_info = None
        if moving:
            ds, lag_info = lag_corrected(ds)
        cal = calib.fit(ds, "t24")
        sigma = max(cal.stats["sigma_nt"].values())
        lag = _hold_lag(ds)
        origin = f"session {session.name}: noise from the fit residual"
        if lag is None:
            lag = prior.lag_s
            origin += f"; lag {lag:g} s as before (no hold at one temperature shows it)"
        else:
            origin += ", lag from its holds at one temperature"
        if lag_info and lag_info.get("tau_s") is not None:
            notes.append(f"{prior.name}: recorded temperature lags the element by {lag_info['tau_s']:.0f} "
                         f"+- {lag_info['tau_se_s']:.0f} s (calib/lag.py); corrected by the fit")
        out.append(DutModel(prior.name, sigma, lag))
        origins[prior.name] = origin
    return out, origins, notes


def _hold_lag(ds) -> float | None:
    """Settling time constant in the session's longest hold: a run of two or more sweeps at one nominal
    air temperature (a ramp's end hold, a designed leg's end), the longest showing the most decay. A single
    sweep's nominal is only where the air was when it began, and a step's dwell starts once the DUT has
    settled: neither shows it."""
    from calib.lag import settling_lag_s

    t, setpoint = ds.columns["t"], ds.columns["setpoint_c"]
    order = np.argsort(t, kind="stable")
    t, temp, setpoint, sweep = t[order], ds.temp_c[order], setpoint[order], ds.group[order]
    starts = np.flatnonzero(np.concatenate([[True], np.diff(setpoint) != 0, [True]]))
    holds = [(t[b - 1] - t[a], a, b) for a, b in zip(starts[:-1], starts[1:], strict=True)
             if len(set(sweep[a:b])) >= 2]
    for _, a, b in sorted(holds, reverse=True):
        lag = settling_lag_s(t[a:b], temp[a:b], float(setpoint[a]))
        if lag is not None and lag < 0.5 * DESIGN_HORIZON_S:
            return lag
    return None


def design_inputs(plan: Plan, station: Station, session: Path | None = None) -> DesignInputs:
    targets = plan_targets(plan)
    duts, origins = station_duts(plan, station)
    notes: list[str] = []
    temps = plan.temperatures
    if session is not None:
        duts, origins, notes = session_duts(session, duts)
    elif isinstance(temps, DesignedTemperatures) and temps.assumed:
        by_name = {d.name: d for d in duts}
        for name, a in temps.assumed.items():
            if name in by_name:
                by_name[name] = DutModel(name, a.noise_nt, a.lag_s)
                origins[name] = "the plan's assumed values"
        duts = list(by_name.values())
    lo, hi = plan_range(plan)
    return DesignInputs(targets, duts, origins, (lo, hi), fastest_ramp_c_per_min(station),
                        start_air_c(station), notes)


# --- the design ----------------------------------------------------------------------------------------
def design_fields(plan: Plan, station: Station, criterion: str) -> list[tuple[float, ...]]:
    """The sweep: an exact optimal design over the plan's own field targets, in the plan's order."""
    targets = field_targets(plan, station)
    h = np.array([station.field_source.nominal_field_nt(t) for t in targets], float)
    x = np.column_stack([np.ones(len(h)), h])
    if len(targets) <= MIN_SWEEP_FIELDS:
        return list(targets)
    from calib.design import optimal_weights

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


def pace_for(plan: Plan, station: Station, fields: list[tuple[float, ...]], samples: int) -> Pace:
    """One sweep of `fields` with `samples` per point, timed as rig check times it."""
    from rig.schedules.ramp import sweep_time_s

    sweep_s = sum(sweep_time_s(_with(plan, fields, samples, station), station, fields).values())
    nominal = np.array([station.field_source.nominal_field_nt(f) for f in fields], float)
    return Pace(nominal, samples, sweep_s / len(fields))


def design_plan(plan: Plan, station: Station, inputs: DesignInputs, *, criterion: str = "I",
                n_checks: int = DEFAULT_CHECKS, check_sweeps: int = 1) -> Designed:
    from rig.schedules.ramp import MAX_SWEEP_SPAN_FRACTION

    fields = design_fields(plan, station, criterion)
    lo, hi = inputs.range_c
    rate = crossing_rate(inputs.rate_c_per_min, hi - lo, max(d.lag_s for d in inputs.duts))
    allowed_s = MAX_SWEEP_SPAN_FRACTION * (hi - lo) / rate * 60.0  # one sweep may span this much
    one = pace_for(plan, station, fields, 1)
    two = pace_for(plan, station, fields, 2)
    per_sample_s = two.sweep_s - one.sweep_s
    samples = int((allowed_s - one.sweep_s) // per_sample_s) + 1 if per_sample_s > 0 else MAX_SAMPLES
    samples = min(max(samples, 1), MAX_SAMPLES)
    pace = pace_for(plan, station, fields, samples)
    if pace.sweep_s > allowed_s:  # even one sample is too slow for the chamber's rate: ramp slower
        rate = MAX_SWEEP_SPAN_FRACTION * (hi - lo) / pace.sweep_s * 60.0
    checks = tuple(round((lo + (hi - lo) * (k + 1) / (n_checks + 1)) * 2) / 2 for k in range(n_checks))
    chamber = ChamberModel((lo, hi), rate, checks, check_sweeps)
    schedule = design_schedule(inputs.duts, chamber, pace, inputs.targets, start_c=inputs.start_c,
                               max_duration_s=min(DESIGN_HORIZON_S, MAX_DURATION_S))
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
    temps = {"mode": "designed", "rate_c_per_min": _round(designed.rate_c_per_min), "legs": legs,
             "assumed": {d.name: _FlowMap(noise_nt=_round(d.sigma_nt), lag_s=_round(d.lag_s))
                         for d in designed.inputs.duts}}
    data["temperatures"] = temps
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
    inputs = design_inputs(plan, station)
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
    for d in inputs.duts:
        lines.append(f"  {d.name}: noise {d.sigma_nt:.3g} nT, lag {d.lag_s:.0f} s ({inputs.origins[d.name]})")
    return lines
