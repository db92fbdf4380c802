"""The points a campaign collects: what the plan compiles to, what the engine runs and the session stores.

    T03-F07          temperature step 3, field 7 (coils); T03-O07: orientation 7 (turntable)
    R1U-S003-F07     continuous ramp: cycle 1, leg up, sweep 3 of that leg, field 7
    L02-S003-F07     designed schedule: leg 2, sweep 3 of that leg, field 7
    L02-S0003-F07    sequential schedule: leg 2, sweep 3 of the run (sweeps are decided as it goes)

Numbers are 1-based and zero-padded to at least 2 digits (3 when there are more than 99). Plain data:
the schedules (rig/schedules/) make them, everything else reads them.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Point:
    id: str
    index: int  # 0-based position in the campaign
    temp_index: int  # 1-based: the temperature step, or the sweep of a ramp
    setpoint_c: float  # the step's setpoint, or the sweep's nominal air temperature
    field_index: int  # 1-based
    command: tuple[float, ...]  # the field source's target: a field vector (nT) or (az, el) (deg)
    target: dict  # the same as stored with the point: {"field_nt": [...]} or {"az_deg", "el_deg"}
    samples: int
    settle_s: float
    ramp_c_per_min: float
    stability: object  # the plan's Stability for this point (rig/config/temperatures.py)

    @property
    def field_nt(self) -> tuple[float, float, float] | None:
        """The commanded field, when the target is one (coils)."""
        value = self.target.get("field_nt")
        return None if value is None else tuple(value)


@dataclass(frozen=True)
class RampPoint(Point):
    """A point of a continuous ramp: its sweep is taken while the chamber air moves along its leg."""

    cycle: int = 1
    leg: int = 1  # 1-based over the whole plan
    rising: bool = True
    sweep: int = 1  # 1-based within its leg
    leg_start_c: float = 0.0
    leg_end_c: float = 0.0


def point_id(temp_index: int, field_index: int, n_temps: int, n_fields: int, letter: str = "F") -> str:
    tw, fw = max(2, len(str(n_temps))), max(2, len(str(n_fields)))
    return f"T{temp_index:0{tw}d}-{letter}{field_index:0{fw}d}"
