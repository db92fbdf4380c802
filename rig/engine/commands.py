"""The engine's command vocabulary: what a task yields, and what a handler may raise instead of a result.

A task (one point of the plan) is a generator; each command it yields is run by the handler registered for
its type (rig/run/campaign.py for most, rig/schedules/moving_tasks.py for StartRamp and AwaitAir) and the
result is sent back. Schedules import this vocabulary, never the executor (rig/engine/executor.py).

    SetChamber(temp_c, ramp_c_per_min)   chamber set point (and its ramp rate, where the chamber has one)
    WaitStable(target_c, criteria)       until every DUT's own temperature is stable (rig/engine/stability.py)
    StartRamp(end_c, rate_c_per_min)     ramp towards end_c from wherever the air is (moving schedules)
    AwaitAir(nominal_c, rising, max_s)   until the air has passed a sweep's nominal temperature
    MoveField(target)                    field vector (coils) or table angles (turntable)
    Settle(seconds)                      the field source's wait_settled, then a fixed delay
    CollectPoint(point, temp_band_c)     every DUT and sensor read, stored in one transaction
    Checkpoint(point_id)                 the point is recorded: a safe place to pause
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Any

from rig.core.errors import MagrigError
from rig.engine.stability import StabilityCriteria
from rig.session.events import Reason

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
class CollectPoint:
    """Collect the point's samples from every DUT and temperature sensor and store them in one go."""

    point: Any
    temp_band_c: float | None = None  # hold if a DUT temperature leaves target +- band during the point


@dataclass(frozen=True)
class Checkpoint:
    """The point is complete and recorded: a safe place to pause."""

    point_id: str


@dataclass(frozen=True)
class StartRamp:
    """Ramp the chamber towards end_c at rate_c_per_min, from where the air is now."""

    end_c: float
    rate_c_per_min: float


@dataclass(frozen=True)
class AwaitAir:
    """Wait until the chamber air has reached nominal_c in the ramp's direction (Hold after max_wait_s)."""

    nominal_c: float
    rising: bool
    max_wait_s: float


Command = SetChamber | WaitStable | MoveField | Settle | CollectPoint | Checkpoint | StartRamp | AwaitAir


@dataclass(frozen=True)
class Task:
    """One point of the plan as the engine runs it ("step" is kept for temperature steps)."""

    point_id: str
    make: Callable[[bool], Generator[Any, Any, None]]


class Hold(MagrigError):
    """Raised by a handler: the point cannot be taken as it is (alarm, temperature out of band).
    `code` says why (rig.session.events.Reason), `device` which device it concerns."""

    def __init__(self, message: str, *, code: Reason = Reason.UNKNOWN, device: str | None = None):
        super().__init__(message)
        self.code = code
        self.device = device
