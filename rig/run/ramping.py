"""The handlers of StartRamp and AwaitAir: the chamber ramped towards a leg's end, and the wait for the air to
reach a sweep's nominal temperature (the tasks that yield them: rig/schedules/tasks.py MovingTasks).

A chamber that ramps its set point itself (`ramps_setpoint`, the F4T) gets one ramp command per leg; any
other chamber gets its set point stepped by STEP_C at the ramp's pace, ahead of the air, at every AwaitAir
(which every point passes through every few seconds). These handlers raise Hold like the others; only the
engine pauses, holds, retakes and ends safe.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from rig.engine.commands import AIR_TOLERANCE_C, AwaitAir, Hold, StartRamp
from rig.session.events import Reason

log = logging.getLogger("magrig.ramp")

STEP_C = 0.5  # set point increment for a chamber that cannot ramp by itself
MAX_POLL_S = 10.0


@dataclass
class _Stepping:
    """A set point moved by hand at the ramp's pace (chambers without a ramp of their own)."""

    t0: float
    from_c: float
    end_c: float
    rate_c_per_min: float
    written_c: float

    def due_c(self, t: float) -> float:
        span = abs(self.end_c - self.from_c)
        sign = 1.0 if self.end_c > self.from_c else -1.0
        return self.from_c + sign * min(self.rate_c_per_min * (t - self.t0) / 60.0 + STEP_C, span)


class RampHandlers:
    """StartRamp and AwaitAir for a CampaignRunner (rig/run/runner.py)."""

    def __init__(self, runner):
        self.runner = runner
        self.stepping: _Stepping | None = None
        self.rate_c_per_min = 1.0  # of the leg being ramped

    def handlers(self) -> dict:
        return {StartRamp: self.start_ramp, AwaitAir: self.await_air}

    def start_ramp(self, cmd: StartRamp) -> None:
        chamber, clock = self.runner.rig.chamber, self.runner.rig.clock
        air_c = chamber.read().air_c
        self.rate_c_per_min = cmd.rate_c_per_min
        if getattr(chamber, "ramps_setpoint", False):
            chamber.set_ramp_rate(cmd.rate_c_per_min)
            chamber.set(cmd.end_c)
            self.stepping = None
        else:
            self.stepping = _Stepping(clock.now(), air_c, cmd.end_c, cmd.rate_c_per_min, air_c)
            self._step_setpoint()
        self.runner.status.thermal = f"ramp {air_c:.1f} -> {cmd.end_c:g} degC at {cmd.rate_c_per_min:g}/min"
        log.info("ramp from %.2f to %g degC at %g degC/min", air_c, cmd.end_c, cmd.rate_c_per_min)

    def _step_setpoint(self) -> None:
        s = self.stepping
        if s is None:
            return
        due = s.due_c(self.runner.rig.clock.now())
        if abs(due - s.written_c) >= STEP_C or (due == s.end_c and s.written_c != s.end_c):
            self.runner.rig.chamber.set(due)
            s.written_c = due

    def await_air(self, cmd: AwaitAir) -> dict:
        runner, clock = self.runner, self.runner.rig.clock
        start = clock.now()
        while True:
            self._step_setpoint()
            air = float(runner.check_chamber().air_c)  # Hold on an alarm
            off = cmd.nominal_c - air if cmd.rising else air - cmd.nominal_c  # > 0: not there yet
            if off <= AIR_TOLERANCE_C:
                return {"nominal_c": cmd.nominal_c, "air_c": air, "waited_s": clock.now() - start}
            if clock.now() - start > cmd.max_wait_s:
                raise Hold(f"chamber air {air:.2f} degC did not reach {cmd.nominal_c:g} degC within "
                           f"{cmd.max_wait_s:g} s", code=Reason.STABILITY_TIMEOUT,
                           device=runner.rig.chamber.name)
            runner.status.thermal = f"ramp: air {air:.2f} degC, next sweep at {cmd.nominal_c:g} degC"
            poll = min(MAX_POLL_S, max(1.0, off / self.rate_c_per_min * 60.0))
            runner.engine.wait(poll, poll)
