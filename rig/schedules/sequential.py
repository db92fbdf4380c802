"""A sequential schedule (`temperatures: {mode: sequential, ...}`): the campaign decides its sweeps as it goes
(rig/schedules/sequential_run.py runs it; calib/design/planner.py decides). It needs no prior: what is known
of the DUTs (measured or stated, rig/planning/inputs.py) only shapes its first leg, and the run measures each
DUT's lag and noise itself. Before the run only the first sweep is known: to the end of `range_c` the design
from the known values starts with, or, when a DUT's lag is not known, to the nearer end (the run's own
characterisation: it stays on that leg until it has measured every DUT's lag), at the fastest rate, with the
optimal exact set of `fields_per_sweep` of the plan's fields. After the last point of every sweep the run
decides the next sweep (stay, next leg, or stop) and records it in the session, in the same transaction as
that point, as a row of the `decisions` table plus the sweep's points. So the planned points of a session are
the first sweep followed by every recorded decision's sweep, and a resume rebuilds exactly them
(`decided_points`): every point is taken once, whatever moment a run stopped at.

Point ids are those of designed legs (rig/schedules/designed.py), with fixed widths so that they never change
as sweeps are added:

    L02-S0003-F07     leg 2, sweep 3 of that leg, field 7 of the plan's fields

Its part of `rig check`: the chamber's limits, one sweep's pace, the worst-case duration (max_duration_h)
and what the design from the known values expects (legs, chamber time, standard errors), or that it is not
predicted without measured lags.
"""

from __future__ import annotations

import numpy as np

from calib.design.optimal import exchange
from calib.design.planner import MAX_SWEEPS, ChamberModel, Pace, crossing_rate, design_schedule
from rig.config import Plan, SequentialTemperatures, Station
from rig.core.errors import ConfigError, LimitError, SessionError
from rig.core.points import RampPoint
from rig.planning.inputs import dut_models, planning_inputs, timing_of
from rig.planning.pace import MAX_SWEEP_SPAN_FRACTION, format_duration, sweep_time_s
from rig.schedules.check import ScheduleCheck, check_range_limits, plan_error
from rig.schedules.designed import leg_points

END_TOLERANCE_SHARE = 0.5  # as a designed plan's (rig/planning/design.py): the other half for the errors

RATE_PATH = ("temperatures", "rate_c_per_min")
WIDTHS_LEG_SWEEP = (2, len(str(MAX_SWEEPS)))


class SequentialSchedule:
    """The first sweep of a sequential plan, its part of the plan check, and the model the run decides
    with."""

    word = "sweeps"

    def __init__(self, plan: Plan, station: Station, targets: list[tuple[float, ...]]):
        assert isinstance(plan.temperatures, SequentialTemperatures)
        self.plan, self.station, self.targets, self.temps = plan, station, targets, plan.temperatures
        self.n_pick = min(self.temps.fields_per_sweep or len(targets), len(targets))
        self.sweep_parts_s = sweep_time_s(plan, station, targets[: self.n_pick], timing_of(plan, station))
        self.sweep_s = sum(self.sweep_parts_s.values())
        self.widths = (*WIDTHS_LEG_SWEEP, max(2, len(str(len(targets)))))
        self.inputs = planning_inputs(plan, station)
        self.priors = None if self.inputs.missing() else dut_models(self.inputs)  # None: characterise first

    # --- the model the decisions use ---------------------------------------------------------------------
    def nominal_fields(self) -> np.ndarray:
        return np.array([self.station.field_source.nominal_field_nt(t) for t in self.targets], float)

    def chamber(self, rate_c_per_min: float | None = None) -> ChamberModel:
        lo, hi = sorted(self.temps.range_c)
        lim = self.station.chamber.limits
        return ChamberModel((lo, hi), rate_c_per_min or self.rate(), tuple(self.temps.checks()),
                            self.temps.check_sweeps, END_TOLERANCE_SHARE * self.temps.band_c(),
                            (lim.min_setpoint_c, lim.max_setpoint_c), self.temps.end_overshoot_c)

    def rate(self) -> float:
        """The plan's rate, or the chamber's fastest if slower (measured, else the stated limit; rig check
        refuses one above the limit); without a rate of its own the plan ramps no faster than keeps one
        sweep within MAX_SWEEP_SPAN_FRACTION of the range. Decisions may ramp slower."""
        if self.temps.rate_c_per_min is not None:
            return min(self.temps.rate_c_per_min, self.inputs.rate_c_per_min)
        span = abs(self.temps.range_c[1] - self.temps.range_c[0])
        return min(self.inputs.rate_c_per_min, MAX_SWEEP_SPAN_FRACTION * span / self.sweep_s * 60.0)

    def start_c(self) -> float:
        return self.inputs.chamber.start_c

    def pace(self, picks: list[int]) -> Pace:
        """One sweep of the fields `picks` (1-based) at the estimated pace."""
        fields = self.nominal_fields()[np.asarray(picks) - 1]
        return Pace(fields, self.plan.samples_per_point, self.sweep_s / len(picks))

    def first_picks(self) -> list[int]:
        """The optimal exact set of n_pick fields (I-optimal over the plan's fields, [1, h] part)."""
        if self.n_pick == len(self.targets):
            return list(range(1, len(self.targets) + 1))
        h = self.nominal_fields()
        x = np.column_stack([np.ones(len(h)), h])
        return sorted(int(i) + 1 for i in exchange(x, self.n_pick, "I"))

    def expected(self):
        """The design from the known values: where the first leg goes, and what the run may expect (None
        when a DUT's lag is not known: the run characterises first)."""
        if self.priors is None:
            return None
        return design_schedule(self.priors, self.chamber(), self.pace(self.first_picks()),
                               self.plan.se_targets(), start_c=self.start_c(),
                               max_duration_s=self.max_duration_s())

    def max_duration_s(self) -> float:
        return self.temps.max_duration_h * 3600.0

    # --- points --------------------------------------------------------------------------------------------
    def sweep_points(self, *, leg: int, sweep: int, from_c: float, to_c: float, rate_c_per_min: float,
                     picks: list[int], first_index: int, first_temp_index: int) -> list[RampPoint]:
        return leg_points(self.plan, self.station, self.targets, leg=leg, sweeps=(sweep, sweep),
                          from_c=from_c,
                          to_c=to_c, rate_c_per_min=rate_c_per_min, sweep_s=self.sweep_s,
                          first_index=first_index, first_temp_index=first_temp_index, widths=self.widths,
                          field_indices=picks)

    def first_leg_end(self) -> float:
        """Where the design from the known values goes first; without them the nearer end of the range."""
        expected = self.expected()
        if expected is not None:
            return expected.legs[0].to_c
        lo, hi = sorted(self.temps.range_c)
        return lo if abs(self.start_c() - lo) <= abs(self.start_c() - hi) else hi

    def first_rate(self) -> float:
        """The plan's rate, no faster than the slowest DUT (when known) can follow."""
        lo, hi = sorted(self.temps.range_c)
        slowest = self.inputs.slowest_lag_s()
        return self.rate() if slowest is None else crossing_rate(self.rate(), hi - lo, slowest)

    def points(self) -> list[RampPoint]:
        """Only the first sweep is known before the run: towards the end the design starts with (or the
        nearer end), at the plan's rate or as fast as the slowest DUT (when known) can follow."""
        return self.sweep_points(leg=1, sweep=1, from_c=self.start_c(), to_c=self.first_leg_end(),
                                 rate_c_per_min=self.first_rate(), picks=self.first_picks(), first_index=0,
                                 first_temp_index=1)

    def decided_points(self, decisions: list[dict], first_index: int) -> list[RampPoint]:
        """The sweeps recorded decisions added, in order (a resume rebuilds the session's planned points)."""
        points: list[RampPoint] = []
        for k, d in enumerate(decisions):
            if d.get("stop"):
                continue
            try:
                points += self.sweep_points(
                    leg=int(d["leg"]), sweep=int(d["sweep"]), from_c=float(d["from_c"]),
                    to_c=float(d["to_c"]), rate_c_per_min=float(d["rate_c_per_min"]),
                    picks=[int(i) for i in d["picks"]],
                    first_index=first_index + len(points), first_temp_index=k + 2)
            except (KeyError, TypeError, ValueError, IndexError) as exc:
                raise SessionError(f"decision {k + 1} of the session is damaged ({exc!r}); cannot "
                                   "resume") from None
        return points

    # --- the plan check ------------------------------------------------------------------------------------
    def check(self) -> ScheduleCheck:
        self._check_limits()
        points = self.points()
        max_s = self.max_duration_s()
        expected = self.expected()
        lo, hi = sorted(self.temps.range_c)
        lines = [
            f"sequential schedule over {lo:g} .. {hi:g} degC at up to {self.rate():.3g} degC/min; checks at "
            + ", ".join(f"{c:g}" for c in self.temps.checks()) + " degC; decided after every sweep; stops "
            f"when every DUT meets stop_when, at the latest after {format_duration(max_s)}",
            f"one sweep of {self.n_pick} of the {len(self.targets)} fields: {format_duration(self.sweep_s)} ("
            + ", ".join(f"{k} {format_duration(v)}" for k, v in self.sweep_parts_s.items()) + ")",
            *self.inputs.lines(),
        ]
        if expected is None:
            lines.append(f"expected legs and time: not predicted: no measured lags; the run characterises "
                         f"each DUT on its first leg (to {self.first_leg_end():g} degC) and measures them "
                         "itself")
        else:
            legs = ", ".join(f"{leg.to_c:g} x {leg.sweeps}" for leg in expected.legs)
            lines.append(f"expected from the known values: legs {legs} sweeps, "
                         f"{format_duration(expected.duration_s)}; " + expected.message)
        n_sweeps = int(max_s // self.sweep_s)
        breakdown = {"at most": max_s}
        # the T24 design is the decisions' business (both ends, the checks): the first sweep alone is not it
        size = (f"{len(points)} points planned before the run (the first sweep); at most {n_sweeps} sweeps "
                f"of {self.n_pick} of the {len(self.targets)} fields, {self.plan.samples_per_point} samples "
                "per point, "
                f"{len(self.station.duts)} DUT(s)")
        return ScheduleCheck(points, n_sweeps, breakdown, {"at most": ("temperatures", "max_duration_h")},
                             lines, self.word, expected, design_points=[], size_line=size,
                             stop_when_line=False)

    def _check_limits(self) -> None:
        plan, temps = self.plan, self.temps
        check_range_limits(plan, self.station, temps.range_c, temps.rate_c_per_min, RATE_PATH)
        span = abs(temps.range_c[1] - temps.range_c[0])
        swept_c = self.rate() * self.sweep_s / 60.0
        if swept_c > MAX_SWEEP_SPAN_FRACTION * span * (1 + 1e-9):
            raise plan_error(LimitError, plan, RATE_PATH,
                             f"one sweep of {self.n_pick} fields takes {format_duration(self.sweep_s)} and "
                             "spans "
                             f"{swept_c:.2g} degC at {self.rate():g} degC/min; at most "
                             f"{MAX_SWEEP_SPAN_FRACTION:.0%} of the range: ramp slower, or take fewer fields "
                             "per sweep or fewer samples")
        if self.max_duration_s() // self.sweep_s > MAX_SWEEPS:
            raise plan_error(ConfigError, plan, ("temperatures", "max_duration_h"),
                             f"{temps.max_duration_h:g} h is more than {MAX_SWEEPS} sweeps of "
                             f"{format_duration(self.sweep_s)}")


def decided_points(plan: Plan, station: Station, decisions: list[dict], first_index: int) -> list[RampPoint]:
    """The points a session's recorded decisions added (none for a plan decided before the run)."""
    if not decisions:
        return []
    if not isinstance(plan.temperatures, SequentialTemperatures):
        raise SessionError("the session records decisions of a sequential schedule, but its plan has none")
    from rig.planning.pace import field_targets

    return SequentialSchedule(plan, station, field_targets(plan, station)).decided_points(decisions,
                                                                                          first_index)
