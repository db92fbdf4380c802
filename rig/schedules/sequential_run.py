"""Running a sequential schedule (rig/schedules/sequential.py): after the last point of each sweep, decide the
next.

A point runs as on a continuous ramp (rig/schedules/tasks.py MovingTasks: StartRamp when its leg begins,
AwaitAir, MoveField, Settle, CollectPoint, Checkpoint), without a stable start: the first leg ramps from
wherever the air is. CollectPoint carries `decide`, which the runner calls with the point's rows before
storing them; at a sweep's last point it decides the next sweep:

1. each DUT's data so far, its temperature moved to the element's (calib/thermal/lag.py, when the lag shows),
   gives its Gram, noise and standard errors; the worst ratio to the targets (calib/design/targets.py);
2. each DUT's lag behind the air and where it settles, fitted again from its temperature against the air
   the run logs, replaces the one in use when it differs (rig/schedules/sequential_estimates.py): the
   run measures what it plans with, and needs no prior. While a DUT's lag is not known yet the run stays
   on its first leg (its characterisation);
3. calib/design/sequential.py `next_leg`: stop (every DUT meets its targets, the model check's temperatures
   are done and every DUT's data covers both ends of the range; or max_duration_h is reached), stay at the
   current leg's temperature (an end until every DUT has come close enough to it), or start the next leg;
   after a leg, T24's linearity in temperature on the data so far: where it fails, interior temperatures
   are added as check legs instead of finishing (rig/schedules/sequential_checks.py);
4. a new leg ramps at the plan's rate, no faster than the slowest DUT can follow (its lag in use);
5. the sweep's fields: `fields_per_sweep` of the plan's fields, picked one by one for the largest drop
   in the variance of the worst DUT's worst parameter (calib/design/optimal.py `gain_for`), at the temperature
   its element is expected at.

The decision (with the estimates in use) and the sweep's points go into the session in the same transaction as
the point itself (rig/session/writer.py), so a resume (rig/schedules/sequential.py `decided_points`) finds
exactly the points decided so far, whenever the run stopped. After the point's Checkpoint the task yields the
new sweep's tasks (AddTasks) and the decision's Event, or the Event and RequestStop of a stop.
"""

from __future__ import annotations

import functools
import logging
import math
from pathlib import Path

import numpy as np

from calib.design.optimal import gain_for, worst_parameter
from calib.design.planner import CHECK, END, DutModel, Leg, State, crossing_rate, temp_ref_of
from calib.design.sequential import next_leg
from calib.equations import t24_regressors
from rig import config as cfg
from rig.core.errors import ERRORS
from rig.core.points import RampPoint
from rig.engine.commands import (
    AddTasks,
    Checkpoint,
    CollectPoint,
    Event,
    MoveField,
    RequestStop,
    RunView,
    Settle,
    Task,
)
from rig.planning.pace import field_targets
from rig.schedules.sequential import SequentialSchedule
from rig.schedules.sequential_checks import AddedChecks, decide_with_checks
from rig.schedules.sequential_estimates import (
    AirLog,
    DutRows,
    Estimate,
    Measured,
    adopted,
    affine_sigma_nt,
    measure,
)
from rig.schedules.tasks import Commands, MovingTasks
from rig.session.events import Kind, Reason
from rig.session.rows import Decision

log = logging.getLogger("magrig.seqrun")

class SequentialTasks(MovingTasks):
    """The ramp-like tasks of a sequential plan, and its decisions (see the module docstring)."""

    def __init__(self, plan: cfg.Plan, station: cfg.Station, points: list[RampPoint]):
        super().__init__(plan, station, points)
        self.watch = None  # a sequential plan decides its own stop
        self.plan = plan
        self.temps: cfg.SequentialTemperatures = plan.temperatures
        self.schedule = SequentialSchedule(plan, station, field_targets(plan, station))
        self.targets = plan.se_targets()
        self.temp_ref_c = temp_ref_of(self.schedule.chamber())
        self.in_use: dict[str, Estimate] = {  # what is known before the run (measured or stated), if anything
            d.name: Estimate(d.lag_s, None, d.offset_c, d.sigma_nt, self.schedule.inputs.duts[d.name].origin)
            for d in self.schedule.priors or []}
        self.air = AirLog()
        self.reached: dict[str, tuple[float, float]] = {}  # each DUT's lowest and highest element so far
        self.added = AddedChecks(self.temps.max_added_checks)  # interior temperatures the model check added
        self.rows = {dut.name: DutRows() for dut in station.duts}
        self.view: RunView | None = None  # the run as the last decision saw it

    # --- data ------------------------------------------------------------------------------------------
    def preload(self, session_path: Path) -> None:
        """On resume: the rows the session already holds."""
        from rig.session.reader import SessionReader

        with SessionReader(session_path) as reader:
            for row in reader.temperatures():
                self.air.add(row["t"], row["air_c"])
            decisions = reader.decisions()
            recorded = [d["estimates"] for d in decisions if d.get("estimates")]
            if recorded:  # the estimates the run was planning with when it stopped
                self.in_use = {dut: Estimate.from_dict(e) for dut, e in recorded[-1].items()}
            reached = [d["reached_c"] for d in decisions if d.get("reached_c")]
            if reached:
                self.reached = {dut: (float(lo), float(hi)) for dut, (lo, hi) in reached[-1].items()}
            added = [d["added_checks_c"] for d in decisions if d.get("added_checks_c")]
            if added:
                self.added.added_c = [float(c) for c in added[-1]]
            for dut, rows in self.rows.items():
                try:
                    ds = reader.dataset(dut)
                except ERRORS:
                    continue
                rows.extend(ds.columns["t"], ds.h_nt, ds.temp_c, ds.ref_nt)

    def _add(self, rows) -> None:
        for dut, buf in self.rows.items():
            mine = [r for r in rows if r.dut == dut and not r.flags]
            buf.extend([r.t for r in mine], [r.field_nt for r in mine], [r.temp_c for r in mine],
                       [r.ref_field_nt for r in mine])

    # --- the tasks: a moving schedule's, deciding as they go -------------------------------------------
    def commands(self, point: RampPoint, retake: bool) -> Commands:
        stability = yield from self.leg_commands(point, retake)
        yield MoveField(point.command)
        yield Settle(point.settle_s)
        collected = yield CollectPoint(point, None, stability, self.decide)
        yield Checkpoint(point.id)
        decision = collected.decision
        if decision is None:
            return
        data = decision.data
        if data.get("stop"):
            yield Event(Kind.RUN, data["reason"], Reason(data["code"]), point.id)
            yield RequestStop(data["reason"], Reason(data["code"]))
            return
        self.points.extend(decision.points)
        yield AddTasks(tuple(Task(p.id, functools.partial(self.commands, p)) for p in decision.points))
        yield Event(Kind.DECISION, f"after {point.id}: {data['reason']}", Reason.DECIDED, point.id,
                    {"leg": data["leg"], "sweep": data["sweep"], "to_c": data["to_c"],
                     "rate_c_per_min": data["rate_c_per_min"]})

    # --- the decision ----------------------------------------------------------------------------------
    def decide(self, point: RampPoint, rows, view: RunView) -> Decision | None:
        """Called with each point's rows before they are stored; the next sweep after a sweep's last point."""
        self.view = view
        self._add(rows)
        self.air.add(view.now_s, view.air_c)
        if point.id != self.points[-1].id:
            return None
        try:
            data, points = self._next(point)
        except ERRORS as exc:  # a decision must never end the run: go on with the same leg
            log.warning("sequential decision failed (%s); one more sweep of the same leg", exc)
            data, points = self._sweep_data(point, point.leg, point.sweep + 1, point.leg_start_c,
                                            point.leg_end_c, point.ramp_c_per_min, self._picks(None, point),
                                            f"decision failed: {exc}; one more sweep of the same leg", {})
        return Decision(data, tuple(points))

    def _elapsed_s(self) -> float:
        return self.view.now_s - self.view.started_s

    def _next(self, point: RampPoint) -> tuple[dict, list[RampPoint]]:
        targets, ref_c = self.targets, self.temp_ref_c
        measured = {d: measure(rows, targets, ref_c, point.leg) for d, rows in self.rows.items()}
        ratios = {dut: m.ratio for dut, m in measured.items()}
        noise = {dut: self._noise(dut, m) for dut, m in measured.items()}
        replanned = self._estimate(noise)
        for dut, m in measured.items():  # an end once reached stays reached (lag estimates move the data)
            if m.covered_c is not None:
                low, high = self.reached.get(dut, m.covered_c)
                self.reached[dut] = (min(low, m.covered_c[0]), max(high, m.covered_c[1]))
        info = {"ratios": {d: _num(r) for d, r in ratios.items()},
                "sigma_nt": {d: _num(n) for d, n in noise.items()},
                "lag_s": {d: _num(m.lag_s) for d, m in measured.items()},
                "estimates": {d: e.as_dict() for d, e in self.in_use.items()},
                "reached_c": {d: list(r) for d, r in self.reached.items()}}
        if replanned:
            info["replanned"] = replanned
        elapsed = self._elapsed_s()
        if elapsed + self.schedule.sweep_s > self.schedule.max_duration_s():
            worst = max(ratios, key=ratios.__getitem__)
            return {"stop": True, "code": Reason.TIME_BUDGET.value, **info,
                    "reason": f"max_duration_h {self.temps.max_duration_h:g} reached; targets not met "
                              f"({worst} at {ratios[worst]:.2f} x its target)"}, []
        unknown = [d for d in self.rows if d not in self.in_use or noise[d] is None]
        if unknown:  # the run's own characterisation: more of its first leg until every DUT is measured
            return self._sweep_data(point, point.leg, point.sweep + 1, point.leg_start_c, point.leg_end_c,
                                    point.ramp_c_per_min, self._picks(None, point),
                                    f"characterising: the lag or noise of {', '.join(unknown[:4])} is not "
                                    "measured yet", {**info, "kind": "characterise"})
        air = self.view.air_c
        air = point.setpoint_c if air is None else float(air)
        state = State(elapsed, air,
                      {d: (m.element_c if m.element_c is not None else air) for d, m in measured.items()},
                      {d: m.gram for d, m in measured.items()})
        duts = [DutModel(d, noise[d], self.in_use[d].lag_s, self.in_use[d].offset_c) for d in measured]
        legs = self._legs_done()
        rate = self._rate()
        pace = self._pace()
        decision, found = decide_with_checks(
            self.added, self.schedule.chamber(rate),
            lambda chamber: next_leg(state, legs, duts, chamber, pace, self.targets,
                                     max_duration_s=self.schedule.max_duration_s(), ratios_now=ratios,
                                     covered_c=self.reached if len(self.reached) == len(measured) else None),
            lambda: self._datasets(measured))
        if found is not None:
            info["model_check"] = found
        if self.added.added_c:
            info["added_checks_c"] = list(self.added.added_c)
        if decision.stop:
            return {"stop": True, "code": Reason.TARGETS_MET.value, "reason": decision.reason, **info}, []
        leg = decision.leg
        if decision.new_leg:
            number, sweep, from_c, rate_c = point.leg + 1, 1, air, leg.rate_c_per_min
        else:
            number, sweep = point.leg, point.sweep + 1
            from_c, rate_c = point.leg_start_c, point.ramp_c_per_min
        worst = max(ratios, key=ratios.__getitem__)
        picks = self._picks(measured[worst] if math.isfinite(ratios[worst]) else None, point, leg.to_c)
        reason = decision.reason
        if replanned:
            reason += f" (re-planned: {', '.join(replanned[:4])} measured anew)"
        return self._sweep_data(point, number, sweep, from_c, leg.to_c, rate_c, picks, reason,
                                {**info, "worst_dut": worst, "kind": leg.kind})

    def _datasets(self, measured: dict[str, Measured]) -> dict:
        """Each DUT's data so far at its element's temperatures (for the model check)."""
        from calib.dataset import Dataset

        out = {}
        for dut, m in measured.items():
            _, h, _, ref = self.rows[dut].arrays()
            if m.element_temps_c is not None and len(h):
                out[dut] = Dataset(h, m.element_temps_c, ref)
        return out

    def _noise(self, dut: str, m: Measured) -> float | None:
        """The DUT's noise per fitted sample: its T24 fit's, else the last sweep's affine residual, else
        what was known before the run."""
        if m.sigma_nt is not None:
            return m.sigma_nt
        t, h, temp, ref = self.rows[dut].arrays()
        last = self.schedule.n_pick * self.plan.samples_per_point
        sigma = affine_sigma_nt(h[-last:], temp[-last:], ref[-last:]) if len(t) >= last else None
        prior = self.in_use.get(dut)
        return sigma if sigma is not None else (None if prior is None else prior.noise_nt)

    def _estimate(self, noise: dict[str, float | None]) -> list[str]:
        """Each DUT's lag and offset fitted again; those that differ from the ones in use replace them."""
        changed = []
        for dut, rows in self.rows.items():
            t, _, temp, _ = rows.arrays()
            new = adopted(self.in_use.get(dut), self.air.fit(t, temp), noise[dut])
            if new is not None:
                self.in_use[dut] = new
                changed.append(dut)
        return changed

    def _sweep_data(self, point, leg: int, sweep: int, from_c: float, to_c: float, rate: float,
                    picks: list[int],
                    reason: str, info: dict) -> tuple[dict, list[RampPoint]]:
        data = {"stop": False, "leg": leg, "sweep": sweep, "from_c": from_c, "to_c": to_c,
                "rate_c_per_min": rate, "picks": picks, "reason": reason, **info}
        points = self.schedule.sweep_points(leg=leg, sweep=sweep, from_c=from_c, to_c=to_c,
                                            rate_c_per_min=rate,
                                            picks=picks, first_index=point.index + 1,
                                            first_temp_index=self.view.decisions + 2)
        return data, points

    def _pace(self):
        """The estimated sweep, timed as the points so far were taken once a sweep's worth are (median,
        so that a point waiting for the air does not count)."""
        from calib.design.planner import Pace

        pace = self.schedule.pace(self.schedule.first_picks())
        taken = list(self.view.point_durations_s)
        if len(taken) >= 10:
            pace = Pace(pace.fields_nt, pace.samples, float(np.median(taken)))
        return pace

    def _legs_done(self) -> list[Leg]:
        """The legs so far (from the points, all taken by now), each with its sweeps."""
        checks = {*self.temps.checks(), *self.added.added_c}
        legs: dict[int, Leg] = {}
        for p in self.points:
            legs[p.leg] = Leg(p.leg_end_c, max(p.sweep, legs[p.leg].sweeps if p.leg in legs else 0),
                              p.ramp_c_per_min, CHECK if p.leg_end_c in checks else END, p.leg_start_c)
        return [legs[k] for k in sorted(legs)]

    def _rate(self) -> float:
        """The plan's rate, no faster than the slowest DUT follows a crossing (calib/design/planner.py): the
        lag of its recorded temperature behind the air, as in use."""
        lo, hi = sorted(self.temps.range_c)
        slowest = max(e.lag_s for e in self.in_use.values())
        return crossing_rate(self.schedule.rate(), hi - lo, slowest)

    def _picks(self, worst: Measured | None, point: RampPoint, to_c: float | None = None) -> list[int]:
        """The sweep's fields: the balanced first set while no fit exists, else those that teach the worst
        DUT's worst parameter the most, chosen one by one with the Gram updated after each."""
        if worst is None or self.schedule.n_pick == len(self.schedule.targets):
            return self.schedule.first_picks()
        h = self.schedule.nominal_fields()
        temp = worst.element_c
        if temp is None:
            temp = to_c if to_c is not None else point.setpoint_c
        x = t24_regressors(h, np.full(len(h), temp), self.temp_ref_c)
        gram = worst.gram.copy()
        _, row = worst_parameter(gram, self.temp_ref_c, self.targets)
        samples = self.plan.samples_per_point
        chosen: list[int] = []
        free = np.ones(len(h), bool)
        for _ in range(self.schedule.n_pick):
            gains = np.where(free, gain_for(gram, self.temp_ref_c, row, x, samples), -np.inf)
            k = int(np.argmax(gains))
            chosen.append(k + 1)
            free[k] = False
            gram = gram + samples * np.outer(x[k], x[k])
        return sorted(chosen)

def _num(value) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)

