"""Least chamber time for T24 targets: where the chamber air goes, how long it stays, and when to stop.

    duts = [DutModel("dut1", sigma_nt=21.0, lag_s=300.0), ...]
    chamber = ChamberModel(range_c=(-30, 70), rate_c_per_min=5.0, checks_c=(20.0,), check_sweeps=1)
    schedule = design_schedule(duts, chamber, Pace(one_sweep, 20, 4.4), {"K": 2e-6}, start_c=22.0)
    schedule.legs, schedule.duration_s, schedule.met, schedule.history    # legs and predicted errors

## Physics

The air ramps towards a leg's temperature at the leg's rate and holds there; each DUT's element follows
its place (the air plus its measured offset) with its own first-order lag (calib/thermal/response.py); the
fields are swept back to back (`Pace.sweep_s` a sweep), each sample at its element's temperature
(lag-corrected after the run, calib/thermal/lag.py). So a schedule predicts each DUT's Gram and standard
errors after every sweep.

## The schedule

T24 is linear in temperature, so its temperature information lies at the two ends of the range
(calib/design/optimal.py: the D- and I-optimal temperatures split between the ends). The least-time schedule
is: to the nearer end (or the other, whichever is faster) at the chamber's rate and hold there while sweeping,
cross to the other end, pausing `check_sweeps` sweeps at each interior check temperature (the points that
show whether T24's linearity holds), and hold at the other end until every DUT meets its targets. The
slowest DUT sets how long the holds are: it needs a few of its lags at each end. The free numbers are the
sweeps spent at the first end and at the second; `design_schedule` searches them for the least total
time (both orders of the ends). The calibration must cover the range at the DUTs, not in the air: with
`end_tolerance_c` each end is held at least until every DUT's element is within that of it (the slowest
DUT sets how long), and the air goes to the end shifted by the DUTs' offsets and the plan's overshoot
(`air_end`, within `air_limits_c`) so that every DUT gets there, and sooner. calib/design/sequential.py
`next_leg` is the same search run during a campaign from the Grams measured so far (a receding horizon):
after each sweep it says stay, go on to the next leg, or stop.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from calib.design.optimal import target_ratios
from calib.equations import t24_regressors
from calib.errors import DataError
from calib.thermal.lag import lag_filter

MAX_SWEEPS = 2000  # bound on the sweeps a schedule may predict (also bounds the search's cost)
END, CHECK = "end", "check"


@dataclass(frozen=True)
class DutModel:
    """What the design knows of a DUT: its noise (one fitted sample, per axis, nT), its thermal lag behind
    the air and where its place settles relative to the air (degC)."""

    name: str
    sigma_nt: float
    lag_s: float
    offset_c: float = 0.0


@dataclass(frozen=True)
class ChamberModel:
    """The range's two ends (at the DUTs), the ramp rate between legs, the interior temperatures of the
    model check, how close to each end every DUT must come (None: not required), the air's limits, and how
    far beyond an end the air may go while the DUTs catch up (the plan's `end_overshoot_c`)."""

    range_c: tuple[float, float]
    rate_c_per_min: float
    checks_c: tuple[float, ...] = ()
    check_sweeps: int = 1
    end_tolerance_c: float | None = None
    air_limits_c: tuple[float, float] | None = None
    overshoot_c: float = 0.0


def air_end(chamber: ChamberModel, duts: Sequence[DutModel], end_c: float) -> float:
    """Where the air goes for the DUTs to reach `end_c`: shifted by the offset of the DUT furthest back (the
    warmest at the low end, the coldest at the high end) and by the chamber's overshoot beyond the end,
    within the air's limits. An overshoot brings the slowest DUT within its tolerance of the end sooner
    (from D degC behind: within tol after tau ln((D + o) / (o + tol)), not tau ln(D / tol))."""
    low = end_c <= 0.5 * sum(chamber.range_c)
    offsets = [0.0, *(d.offset_c for d in duts)]
    target = end_c - max(offsets) - chamber.overshoot_c if low else end_c - min(offsets) + chamber.overshoot_c
    if chamber.air_limits_c is not None:
        target = min(max(target, chamber.air_limits_c[0]), chamber.air_limits_c[1])
    return round(target, 1)  # a set point to a tenth of a degree


def covered_at(chamber: ChamberModel, element_c: Mapping[str, float], end_c: float) -> bool:
    """Whether every DUT's element is within end_tolerance_c of the range end `end_c` (or beyond it)."""
    tol = chamber.end_tolerance_c
    if tol is None:
        return True
    low = end_c <= 0.5 * (chamber.range_c[0] + chamber.range_c[1])
    values = list(element_c.values())
    return max(values) <= end_c + tol if low else min(values) >= end_c - tol


def range_end_of(chamber: ChamberModel, air_c: float) -> float:
    """The range end a leg's air target serves."""
    lo, hi = chamber.range_c
    return lo if abs(air_c - lo) <= abs(air_c - hi) else hi


@dataclass(frozen=True)
class Pace:
    """One sweep: its fields (n, 3) nT in order, samples per point, seconds per point (move, settle, read)."""

    fields_nt: np.ndarray
    samples: int
    point_s: float

    @property
    def sweep_s(self) -> float:
        return self.point_s * len(self.fields_nt)


@dataclass(frozen=True)
class Leg:
    """The air goes to `to_c` at `rate_c_per_min` and stays; `sweeps` sweeps are taken meanwhile."""

    to_c: float
    sweeps: int
    rate_c_per_min: float
    kind: str = END  # END (one of the range's ends) or CHECK (an interior check temperature)
    from_c: float | None = None  # where the air was when the leg began (when known)


@dataclass
class State:
    """Where a campaign stands: time, air, each DUT's element temperature and Gram so far."""

    t_s: float
    air_c: float
    element_c: dict[str, float]
    grams: dict[str, np.ndarray]

    @classmethod
    def start(cls, duts: Sequence[DutModel], air_c: float) -> State:
        """Every DUT settled where its place puts it, the air at air_c."""
        return cls(0.0, air_c, {d.name: air_c + d.offset_c for d in duts},
                   {d.name: np.zeros((8, 8)) for d in duts})


@dataclass
class Prediction:
    """After each sweep of some legs: the time, each DUT's Gram, air and element temperatures."""

    t_s: np.ndarray  # (n_sweeps,) end of each sweep
    grams: dict[str, np.ndarray]  # name -> (n_sweeps, 8, 8) cumulative
    air_c: np.ndarray  # (n_sweeps,) at the end of each sweep
    element_c: dict[str, np.ndarray]  # name -> (n_sweeps,)
    leg_of_sweep: np.ndarray  # (n_sweeps,) index of the leg

    def state(self, sweep: int) -> State:
        """The state after sweep `sweep` (0-based)."""
        return State(float(self.t_s[sweep]), float(self.air_c[sweep]),
                     {n: float(e[sweep]) for n, e in self.element_c.items()},
                     {n: g[sweep] for n, g in self.grams.items()})


@dataclass
class Schedule:
    """A designed schedule: its legs, chamber time, whether the targets are met, and the predicted worst
    ratio (standard error / target) of each DUT and group after each sweep (for rig check's table)."""

    legs: list[Leg]
    duration_s: float
    met: bool
    sweep_end_s: np.ndarray
    ratios: dict[str, np.ndarray]  # DUT -> (n_sweeps, n_groups), groups in the targets' order
    groups: list[str]
    message: str = ""
    std_errors: dict[str, dict] = field(default_factory=dict)  # DUT -> group -> se at the end
    air_c: np.ndarray | None = None  # (n_sweeps,) at the end of each sweep
    element_c: dict[str, np.ndarray] = field(default_factory=dict)  # DUT -> (n_sweeps,)


# --- the thermal prediction ------------------------------------------------------------------------------
def air_path(t_s: np.ndarray, start_t_s: float, start_c: float, legs: Sequence[Leg], sweep_s: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """Air temperature at times t_s (sorted) and the leg index of each, for legs run back to back."""
    air = np.empty_like(t_s)
    leg_index = np.empty(t_s.shape, int)
    t0, a0 = start_t_s, start_c
    for j, leg in enumerate(legs):
        t1 = t0 + leg.sweeps * sweep_s
        sel = (t_s >= t0) & ((t_s < t1) | (j == len(legs) - 1))
        span = leg.to_c - a0
        moved = np.minimum(leg.rate_c_per_min / 60.0 * (t_s[sel] - t0), abs(span))
        air[sel] = a0 + math.copysign(1.0, span) * moved
        leg_index[sel] = j
        a0 = a0 + math.copysign(min(leg.rate_c_per_min / 60.0 * (t1 - t0), abs(span)), span)
        t0 = t1
    return air, leg_index


def element_path(t_s: np.ndarray, air_c: np.ndarray, lag_s: float, start_element_c: float) -> np.ndarray:
    """First-order response to the air (linear between rows) from the element's temperature at t_s[0]."""
    seg = np.zeros(len(t_s), int)
    return lag_filter(t_s, air_c, lag_s, seg) + (start_element_c - air_c[0]) * np.exp(-(t_s - t_s[0]) / lag_s)


def predict(state: State, legs: Sequence[Leg], pace: Pace, duts: Sequence[DutModel], temp_ref_c: float
            ) -> Prediction:
    """Run `legs` from `state` on paper: each DUT's cumulative Gram after every sweep."""
    n_sweeps = sum(leg.sweeps for leg in legs)
    n_f = len(pace.fields_nt)
    if n_sweeps == 0:
        raise DataError("predict: no sweeps")
    if n_sweeps > MAX_SWEEPS:
        raise DataError(f"predict: {n_sweeps} sweeps; at most {MAX_SWEEPS}")
    k = np.arange(n_sweeps * n_f)
    t_points = state.t_s + (k + 0.5) * pace.point_s
    t_all = np.concatenate([[state.t_s], t_points])
    air_all, _ = air_path(t_all, state.t_s, state.air_c, legs, pace.sweep_s)
    sweep_end = state.t_s + (np.arange(n_sweeps) + 1) * pace.sweep_s
    air_end, leg_index = air_path(sweep_end - 1e-9, state.t_s, state.air_c, legs, pace.sweep_s)
    fields = np.tile(pace.fields_nt, (n_sweeps, 1))
    grams, elements = {}, {}
    for dut in duts:
        temp = element_path(t_all, air_all + dut.offset_c, dut.lag_s, state.element_c[dut.name])
        x = t24_regressors(fields, temp[1:], temp_ref_c)
        per_point = pace.samples * np.einsum("ni,nj->nij", x, x)
        per_sweep = per_point.reshape(n_sweeps, n_f, 8, 8).sum(axis=1)
        grams[dut.name] = state.grams[dut.name] + np.cumsum(per_sweep, axis=0)
        elements[dut.name] = temp[1:][n_f - 1 :: n_f]
    return Prediction(sweep_end, grams, air_end, elements, leg_index)


def worst_ratios(prediction: Prediction, duts: Sequence[DutModel], targets: Mapping[str, float],
                 temp_ref_c: float) -> dict[str, np.ndarray]:
    """DUT -> (n_sweeps, n_groups) standard error over target after each predicted sweep."""
    return {d.name: target_ratios(prediction.grams[d.name], d.sigma_nt, temp_ref_c, targets) for d in duts}


def _first_met(ratios: dict[str, np.ndarray], from_sweep: int, covered: np.ndarray | None = None
               ) -> int | None:
    """First sweep (0-based, >= from_sweep) after which every DUT's every ratio is <= 1 (and, with
    `covered`, the end is covered)."""
    ok = np.all([np.all(r <= 1.0, axis=1) for r in ratios.values()], axis=0)
    if covered is not None:
        ok &= covered
    ok[:from_sweep] = False
    hits = np.flatnonzero(ok)
    return int(hits[0]) if hits.size else None


# --- the least-time schedule ----------------------------------------------------------------------------
def sweeps_to_reach(from_c: float, to_c: float, rate_c_per_min: float, sweep_s: float) -> int:
    """Sweeps taken while the air ramps from from_c to to_c (at least one)."""
    return max(1, math.ceil(abs(to_c - from_c) / rate_c_per_min * 60.0 / sweep_s - 1e-9))


def sweeps_with_hold(from_c: float, to_c: float, rate_c_per_min: float, sweep_s: float, hold: int) -> int:
    """Sweeps of a leg that ramps from from_c to to_c and then takes `hold` sweeps with the air there (a
    sweep's nominal air is where the air is when it starts)."""
    span = abs(to_c - from_c)
    return (math.ceil(span / rate_c_per_min * 60.0 / sweep_s - 1e-9) if span > 0 else 0) + hold


def crossing(chamber: ChamberModel, from_c: float, to_c: float, sweep_s: float,
             done_checks: Sequence[float] = ()) -> list[Leg]:
    """The check legs met on the way from one end to the other (those not yet done), in travel order,
    each long enough to reach its temperature and take check_sweeps sweeps there."""
    lo, hi = sorted((from_c, to_c))
    todo = [c for c in chamber.checks_c if lo < c < hi and c not in done_checks]
    todo.sort(reverse=to_c < from_c)
    legs, at = [], from_c
    for c in todo:
        n = sweeps_with_hold(at, c, chamber.rate_c_per_min, sweep_s, chamber.check_sweeps)
        legs.append(Leg(c, n, chamber.rate_c_per_min, CHECK, at))
        at = c
    return legs


def crossing_rate(max_rate_c_per_min: float, span_c: float, slowest_lag_s: float) -> float:
    """The ramp rate for a crossing of span_c: the chamber's fastest, but no faster than the slowest DUT can
    follow. Reaching within delta of the far end takes span/r + tau ln(r tau / delta), least at
    r = span / tau: a faster ramp only leaves that DUT further behind (and leans harder on the lag
    correction of every sample taken on the way)."""
    return min(max_rate_c_per_min, 60.0 * abs(span_c) / slowest_lag_s)


def temp_ref_of(chamber: ChamberModel) -> float:
    """Centre of the range: where the design's temperatures are centred (the absolute errors do not care)."""
    return round(0.5 * (chamber.range_c[0] + chamber.range_c[1]), 1)


def covered_sweeps(pred: Prediction, chamber: ChamberModel | None, end_c: float | None) -> np.ndarray | None:
    """Per predicted sweep: whether every DUT's element is within the chamber's end tolerance of end_c."""
    if chamber is None or end_c is None or chamber.end_tolerance_c is None:
        return None
    names = list(pred.element_c)
    return np.array([covered_at(chamber, {n: pred.element_c[n][k] for n in names}, end_c)
                     for k in range(len(pred.t_s))])


def hold_until_met(state: State, legs_before: list[Leg], last: Leg, pace: Pace, duts, targets,
                   temp_ref_c: float, max_sweeps: int, *, chamber: ChamberModel | None = None
                   ) -> tuple[int | None, Prediction, dict]:
    """Run legs_before, then `last` for as long as needed, up to max_sweeps in all: the sweeps of `last`
    that bring every DUT to its targets and, with `chamber`, every DUT within its end tolerance of the end
    `last` serves (None: not within max_sweeps), with the prediction and ratios. The horizon doubles until
    the targets are met, so a short answer costs a short prediction."""
    end_c = None if chamber is None or last.kind != END else range_end_of(chamber, last.to_c)
    before = sum(leg.sweeps for leg in legs_before)
    horizon = max(32, 2 * before)
    while True:
        total = min(horizon, max(max_sweeps, before + 1))
        pred = predict(state, [*legs_before, replace(last, sweeps=total - before)], pace, duts, temp_ref_c)
        ratios = worst_ratios(pred, duts, targets, temp_ref_c)
        start_air = pred.air_c[before - 1] if before else state.air_c
        reach = sweeps_to_reach(start_air, last.to_c, last.rate_c_per_min, pace.sweep_s)
        hit = _first_met(ratios, min(before + reach, total) - 1, covered_sweeps(pred, chamber, end_c))
        if hit is not None or total >= max_sweeps:
            return (None if hit is None else hit - before + 1), pred, ratios
        horizon *= 2


def design_schedule(duts: Sequence[DutModel], chamber: ChamberModel, pace: Pace, targets: Mapping[str, float],
                    *, start_c: float, max_duration_s: float) -> Schedule:
    """The least-time schedule of the module's shape meeting every DUT's targets (see the docstring); when
    no schedule within max_duration_s meets them, the one that comes closest, with met=False."""
    _check_inputs(duts, chamber, pace)
    temp_ref = temp_ref_of(chamber)
    max_sweeps = min(MAX_SWEEPS, max(2, int(max_duration_s // pace.sweep_s)))
    best = None
    for end1, end2 in (chamber.range_c, chamber.range_c[::-1]):
        first, second = air_end(chamber, duts, end1), air_end(chamber, duts, end2)
        reach1 = sweeps_to_reach(start_c, first, chamber.rate_c_per_min, pace.sweep_s)
        checks = crossing(chamber, first, second, pace.sweep_s)
        n_checks = sum(c.sweeps for c in checks)
        if reach1 + n_checks + 1 > max_sweeps:
            continue
        start = State.start(duts, start_c)
        prefix = predict(start, [Leg(first, max_sweeps, chamber.rate_c_per_min)], pace, duts, temp_ref)
        covered = covered_sweeps(prefix, chamber, end1)
        held = reach1 if covered is None else int(np.argmax(covered)) + 1 if covered.any() else None
        if held is None:
            continue  # a DUT never gets within the tolerance of this end
        for n1 in range(max(reach1, held), max_sweeps - n_checks):
            if best is not None and not best[0][0] and n1 + n_checks + 1 >= best[0][1]:
                break  # a longer first hold cannot make the whole shorter
            budget = max_sweeps - n1
            n2, _, ratios = hold_until_met(prefix.state(n1 - 1), checks,
                                           Leg(second, 1, chamber.rate_c_per_min), pace, duts, targets,
                                           temp_ref, budget, chamber=chamber)
            total = n1 + n_checks + (n2 if n2 is not None else budget)
            score = (n2 is None, total if n2 is not None else _closeness(ratios), n1)
            if best is None or score < best[0]:
                best = (score, first, second, n1, checks, n2)
    if best is None:
        raise DataError(f"design: not even one crossing of the range fits in {max_duration_s / 3600:.3g} h"
                        + ("" if chamber.end_tolerance_c is None else
                           f" with every DUT within {chamber.end_tolerance_c:g} degC of each end"))
    _, first, second, n1, checks, n2 = best
    met = n2 is not None
    legs = [Leg(first, n1, chamber.rate_c_per_min), *checks,
            Leg(second, n2 if met else max_sweeps - n1 - sum(c.sweeps for c in checks),
                chamber.rate_c_per_min)]
    return summarise(legs, duts, pace, targets, temp_ref, start_c, met)


def _closeness(ratios: dict[str, np.ndarray]) -> float:
    """How far the end of a prediction stays from the targets (the largest final ratio)."""
    return float(max(r[-1].max() for r in ratios.values()))


def summarise(legs: list[Leg], duts: Sequence[DutModel], pace: Pace, targets: Mapping[str, float],
              temp_ref_c: float, start_c: float, met: bool | None = None) -> Schedule:
    """The predicted errors of a given list of legs (rig check of a designed plan uses it as it is)."""
    pred = predict(State.start(duts, start_c), legs, pace, duts, temp_ref_c)
    ratios = worst_ratios(pred, duts, targets, temp_ref_c)
    final = {n: r[-1] for n, r in ratios.items()}
    if met is None:
        met = all(np.all(r <= 1.0) for r in final.values())
    worst = max(final, key=lambda n: final[n].max())
    groups = list(targets)
    g = groups[int(np.argmax(final[worst]))]
    message = (f"targets met by every DUT (closest: {worst} {g} at {final[worst].max():.2f} of its target)"
               if met else f"targets not met: {worst} {g} at {final[worst].max():.2f} x its target")
    se = {n: {grp: float(final[n][i] * targets[grp]) for i, grp in enumerate(groups)} for n in final}
    return Schedule(legs, float(pred.t_s[-1]), met, pred.t_s, ratios, groups, message, se, pred.air_c,
                    pred.element_c)


def _check_inputs(duts: Sequence[DutModel], chamber: ChamberModel, pace: Pace) -> None:
    if not duts:
        raise DataError("design: no DUTs")
    for d in duts:
        if not (d.sigma_nt > 0 and math.isfinite(d.sigma_nt)):
            raise DataError(f"design: DUT {d.name}: noise {d.sigma_nt!r} nT must be a positive number")
        if not (d.lag_s > 0 and math.isfinite(d.lag_s)):
            raise DataError(f"design: DUT {d.name}: thermal lag {d.lag_s!r} s must be a positive number")
    lo, hi = chamber.range_c
    if not lo < hi:
        raise DataError(f"design: range {lo:g} .. {hi:g} degC must go from low to high")
    if not chamber.rate_c_per_min > 0:
        raise DataError(f"design: ramp rate {chamber.rate_c_per_min!r} degC/min must be positive")
    if not (pace.point_s > 0 and pace.samples >= 1 and len(pace.fields_nt) >= 1):
        raise DataError("design: a sweep needs fields, samples and a positive time per point")
