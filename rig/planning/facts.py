"""What planning knows of a DUT, of the chamber and of the pace of a point: the quantities a plan is made
with, each with where it came from (`origin`: stated by the station, measured by `rig commission --thermal`
or by an earlier session, rig/planning/inputs.py and measured.py)."""

from __future__ import annotations

from dataclasses import dataclass

ASSUMED_START_C = 22.0  # a room: where the air is taken to start when nothing measured it


@dataclass(frozen=True)
class DutInput:
    """What planning knows of a DUT (rig/planning/inputs.py): its noise per fitted sample and axis (nT, as
    the plan reads it), its temperature's first-order lag behind the air (s) and where it settles relative
    to the air (degC); None where the source does not say."""

    name: str
    noise_nt: float | None
    lag_s: float | None
    offset_c: float | None
    origin: str


@dataclass(frozen=True)
class ChamberInput:
    """The chamber as measured: the air's fastest pace (degC/min) and overshoot (degC), where the air
    starts (degC); rate None: not measured."""

    rate_c_per_min: float | None
    overshoot_c: float | None
    start_c: float
    origin: str


@dataclass(frozen=True)
class Timing:
    """The pace of a point: one sample of every DUT (with the sensors and the field source's read-back,
    interleaved as a campaign reads them) and a point's own time beyond its settle_s and samples (moving
    and settling the field source, reading the chamber), both s."""

    sample_s: float
    point_overhead_s: float
    origin: str
