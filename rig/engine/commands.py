"""The engine's command vocabulary: what a task yields, and what a handler may raise instead of a result.

A task (one point of the plan) is a generator; each command it yields is run by the handler registered for
its type and the result is sent back. Schedules (rig/schedules/) yield these and nothing else: every effect
on the run is a command, so the engine sees, logs and can pause at each. Schedules import this vocabulary,
never the executor (rig/engine/executor.py) or the runner (rig/run/).

What the rig does (handlers in rig/run/runner.py and rig/run/ramping.py):

    SetChamber(temp_c, ramp_c_per_min)   chamber set point (and its ramp rate, where the chamber has one)
    WaitStable(target_c, criteria)       until every DUT's own temperature is stable (engine/stability.py);
                                         returns the stability statistics the points of the step record
    StartRamp(end_c, rate_c_per_min)     ramp towards end_c from wherever the air is (moving schedules)
    AwaitAir(nominal_c, rising, max_s)   until the air has passed a sweep's nominal temperature; returns its
                                         statistics as WaitStable does
    MoveField(target)                    field vector (coils) or table angles (turntable)
    Settle(seconds)                      the field source's wait_settled, then a fixed delay
    CollectPoint(point, temp_band_c,     every DUT and sensor read, stored in one transaction with the
                 stability, decide)      stability statistics and what `decide` made of the rows; returns
                                         a Collected
    Checkpoint(point_id)                 the point is recorded: a safe place to pause
    ReadTargets(targets)                 each DUT's live T24 fit against standard-error targets

What the engine does itself (rig/engine/executor.py):

    AddTasks(tasks)                      points decided during the run (a sequential schedule's next sweep)
    Event(kind, message, code, ...)      an event in the session and the live status
    RequestStop(message, code)           end the run as completed after this point (targets met)
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from typing import Any

from rig.core.errors import MagrigError
from rig.engine.stability import StabilityCriteria
from rig.session.events import Kind, Reason

# how a run ends (its exit status in the session)
COMPLETED = "completed"
ABORTED = "aborted"
FAILED = "failed"


@dataclass(frozen=True)
class SetChamber:
    temp_c: float
    ramp_c_per_min: float | None = None


@dataclass(frozen=True)
class WaitStable:
    """Wait until every DUT temperature is stable around target_c (rig/engine/stability.py)."""

    target_c: float
    criteria: StabilityCriteria


@dataclass(frozen=True)
class MoveField:
    """Command the field source: a field vector in nT (coils) or table angles in degrees (turntable)."""

    target: tuple[float, ...]


@dataclass(frozen=True)
class Settle:
    """Let the field source settle (wait_settled, then a fixed delay)."""

    seconds: float


@dataclass(frozen=True)
class RunView:
    """What a schedule's decision may know of the run when a point is collected (read-only data)."""

    now_s: float  # the run's clock
    air_c: float | None  # the chamber air, as last read
    started_s: float  # when the session began (clock seconds)
    decisions: int  # decisions the session holds so far
    point_durations_s: tuple[float, ...]  # the recent points' durations


@dataclass(frozen=True)
class CollectPoint:
    """Collect the point's samples from every DUT and temperature sensor and store them in one go, with the
    stability statistics of the wait before it and what `decide(point, rows, view)` returns of them (a
    sequential schedule's next sweep: stored in the same transaction as the point)."""

    point: Any
    temp_band_c: float | None = None  # hold if a DUT temperature leaves target +- band during the point
    stability: dict | None = None  # what WaitStable / AwaitAir returned
    decide: Callable[[Any, list, RunView], Any] | None = None


@dataclass(frozen=True)
class Collected:
    """What CollectPoint stored: each DUT's last temperature, and the decision stored with the point."""

    temps_c: dict[str, float]
    decision: Any = None


@dataclass(frozen=True)
class ReadTargets:
    """Each DUT's live T24 fit checked against standard-error targets (calib.design.targets.TargetStatus)."""

    targets: dict[str, float]


@dataclass(frozen=True)
class Checkpoint:
    """The point is complete and recorded: a safe place to pause."""

    point_id: str


@dataclass(frozen=True)
class StartRamp:
    """Ramp the chamber towards end_c at rate_c_per_min, from where the air is now."""

    end_c: float
    rate_c_per_min: float


AIR_TOLERANCE_C = 0.2  # the air counts as at a sweep's nominal temperature this close to it


@dataclass(frozen=True)
class AwaitAir:
    """Wait until the chamber air has reached nominal_c in the ramp's direction (Hold after max_wait_s)."""

    nominal_c: float
    rising: bool
    max_wait_s: float


@dataclass(frozen=True)
class Task:
    """One point of the plan as the engine runs it ("step" is kept for temperature steps)."""

    point_id: str
    make: Callable[[bool], Generator[Any, Any, None]]


@dataclass(frozen=True)
class AddTasks:
    """Points decided during the run, appended to the engine's list."""

    tasks: tuple[Task, ...]


@dataclass(frozen=True)
class Event:
    """An event of the run (rig.session.events: kind, reason code, point, device, message, data)."""

    kind: Kind
    message: str
    code: Reason
    point_id: str | None = None
    data: dict = field(default_factory=dict)


@dataclass(frozen=True)
class RequestStop:
    """End the run as completed after the current point although points remain (good enough)."""

    message: str
    code: Reason


Command = (SetChamber | WaitStable | MoveField | Settle | CollectPoint | Checkpoint | StartRamp | AwaitAir
           | ReadTargets | AddTasks | Event | RequestStop)


class Hold(MagrigError):
    """Raised by a handler: the point cannot be taken as it is (alarm, temperature out of band).
    `code` says why (rig.session.events.Reason), `device` which device it concerns."""

    def __init__(self, message: str, *, code: Reason = Reason.UNKNOWN, device: str | None = None):
        super().__init__(message)
        self.code = code
        self.device = device
