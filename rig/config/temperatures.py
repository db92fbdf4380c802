"""The `temperatures:` of a plan: its temperature schedule, one model per mode.

    (no mode)          temperature steps: `steps` or `range`, each held until the DUTs are stable
                       (rig/schedules/steps.py)
    mode: ramp         a continuous ramp over `range_c`, swept while the air moves (rig/schedules/ramp.py)
    mode: designed     legs to chosen temperatures, each held while its sweeps are taken; `rig design`
                       writes it (rig/schedules/designed.py)
    mode: sequential   sweeps decided during the run until every DUT meets its targets
                       (rig/schedules/sequential.py)

`moving` says whether samples are taken while the temperature moves (every mode but steps): the fits then
correct each DUT's thermal lag.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import BeforeValidator, Discriminator, Field, Tag, model_validator

from rig.core.configbase import Strict
from rig.core.numbers import DAY_S, NT_MAX, RAMP_C_PER_MIN, SECONDS, TEMP_C, Count, bounded
from rig.core.yamlload import KeyPathError


class Stability(Strict):
    """When a temperature step counts as stable, judged on each DUT's own temperature against where it
    settles (rig/engine/stability.py): changing slower than rate_c_per_min and holding within band_c of its
    own level, both for dwell_s, what is left of its approach within band_c and its level within
    max_offset_c of the set point (a DUT's place may be warmer or colder than the air); give up after
    max_wait_s."""

    band_c: bounded(gt=0, hi=100.0) = 0.5
    rate_c_per_min: RAMP_C_PER_MIN = 0.1
    dwell_s: SECONDS = 300.0
    max_wait_s: bounded(gt=0, hi=7 * DAY_S) = 3 * 3600.0
    max_offset_c: bounded(gt=0, hi=100.0) = Field(
        2.0, description="a DUT settling further than this from the set point is a fault (hardware-notes "
        "§9.5: places in a chamber differ from its air by up to 2 degC)")


def _number_to_step(value: Any) -> Any:
    """A bare setpoint (or anything else that is not a mapping) is the step's setpoint_c: its own type
    then says what is wrong with it."""
    return value if isinstance(value, dict | TempStep) else {"setpoint_c": value}


class TempStep(Strict):
    setpoint_c: TEMP_C
    ramp_c_per_min: RAMP_C_PER_MIN | None = None
    stability: Stability | None = Field(None, description="keys given here override the plan's stability")


class TempRange(Strict):
    start_c: TEMP_C
    stop_c: TEMP_C
    step_c: bounded(lo=-1_000.0, hi=1_000.0)

    @model_validator(mode="after")
    def _direction(self):
        if self.step_c == 0 or (self.stop_c - self.start_c) * self.step_c < 0:
            raise KeyPathError(("step_c",), "must be non-zero and point from start_c towards stop_c")
        return self

    def setpoints(self) -> list[float]:
        n = int(np.floor((self.stop_c - self.start_c) / self.step_c + 1e-9)) + 1
        return [round(self.start_c + i * self.step_c, 6) for i in range(n)]


class Temperatures(Strict):
    steps: list[Annotated[TempStep, BeforeValidator(_number_to_step)]] | None = None
    range: TempRange | None = None
    ramp_c_per_min: RAMP_C_PER_MIN = 2.0
    stability: Stability = Stability()

    moving: ClassVar[bool] = False  # samples are taken at stable temperatures

    @model_validator(mode="after")
    def _one_source(self):
        if (self.steps is None) == (self.range is None):
            raise KeyPathError(("steps",), "give either steps (a list of setpoints) or range, not both")
        if self.steps is not None and not self.steps:
            raise KeyPathError(("steps",), "needs at least one setpoint")
        return self

    def step_list(self) -> list[TempStep]:
        if self.steps is not None:
            return list(self.steps)
        return [TempStep(setpoint_c=t) for t in self.range.setpoints()]  # type: ignore[union-attr]

    def stability_for(self, step: TempStep) -> Stability:
        if step.stability is None:
            return self.stability
        return self.stability.model_copy(update=step.stability.model_dump(exclude_unset=True))

    def covered_c(self) -> tuple[float, float]:
        """The DUT temperatures the plan covers: its lowest and highest setpoint."""
        setpoints = [s.setpoint_c for s in self.step_list()]
        return min(setpoints), max(setpoints)

    def band_c(self) -> float:
        """How close to each end of the range the DUTs' data must come (the widest stability band)."""
        return max(self.stability_for(s).band_c for s in self.step_list())


class RampTemperatures(Strict):
    """Continuous ramp: the chamber ramps from range_c[0] to range_c[1] and back, `cycles` times, without
    stopping, while the field source sweeps the plan's field set again and again
    (rig/schedules/tasks.py). Before the first leg the DUTs are brought to range_c[0] and judged stable
    with `stability`; `end_hold_s`
    keeps sweeping at each leg's end while the DUTs catch up with the air."""

    mode: Literal["ramp"]
    range_c: tuple[TEMP_C, TEMP_C]
    rate_c_per_min: RAMP_C_PER_MIN
    cycles: Count(100) = 1
    end_hold_s: SECONDS = 0.0
    stability: Stability = Stability()

    moving: ClassVar[bool] = True  # samples are taken while the temperature moves: each DUT's lag is fitted

    @model_validator(mode="after")
    def _span(self):
        if self.range_c[0] == self.range_c[1]:
            raise KeyPathError(("range_c",), "start and end must differ")
        return self

    def covered_c(self) -> tuple[float, float]:
        """The DUT temperatures the plan covers."""
        return min(self.range_c), max(self.range_c)

    def band_c(self) -> float:
        return self.stability.band_c


MAX_LEG_SWEEPS = 10_000


class DesignedLeg(Strict):
    """One leg of a designed schedule: the air goes to `to_c` and stays while `sweeps` sweeps are taken."""

    to_c: TEMP_C
    sweeps: Count(MAX_LEG_SWEEPS)
    rate_c_per_min: RAMP_C_PER_MIN | None = Field(None, description="default: the schedule's")
    check: bool = Field(False, description="an interior temperature of the model check (T24's linearity)")


class AssumedDut(Strict):
    """What a design assumed of a DUT (its noise per fitted sample and axis, its lag behind the air, where
    it settles relative to the air): what was measured when the plan was designed."""

    noise_nt: bounded(gt=0, hi=NT_MAX)
    lag_s: bounded(gt=0, hi=DAY_S)
    offset_c: bounded(lo=-50.0, hi=50.0) | None = None


class DesignedTiming(Strict):
    """The pace a design was made with, as measured (rig/planning/inputs.py): one sample of every DUT, a
    point's own time beyond settle_s and its samples, and what measured them."""

    sample_s: bounded(gt=0, hi=3600.0)
    point_overhead_s: bounded(lo=0, hi=3600.0)
    measured_by: str = Field(max_length=200)


class DesignedTemperatures(Strict):
    """A designed schedule (`rig design` writes it; rig/schedules/designed.py): legs run back to back from
    wherever the air is, each ramping at its rate and holding while its sweeps are taken; the field source
    sweeps the plan's fields throughout. `assumed` records the DUT noise and lags the design was made for (rig
    check predicts the standard errors from them; the station's stated values otherwise)."""

    mode: Literal["designed"]
    rate_c_per_min: RAMP_C_PER_MIN
    legs: list[DesignedLeg] = Field(min_length=1)
    assumed: dict[str, AssumedDut] = {}
    timing: DesignedTiming | None = Field(None, description="the measured pace `rig check` times it by")
    range_c: tuple[TEMP_C, TEMP_C] | None = Field(
        None, description="the DUT temperatures the design covers (default: the legs' lowest and highest)")
    stability: Stability = Stability()

    moving: ClassVar[bool] = True

    def covered_c(self) -> tuple[float, float]:
        """The DUT temperatures the plan covers: its `range_c`, else its end legs' lowest and highest."""
        if self.range_c is not None:
            return min(self.range_c), max(self.range_c)
        ends = [leg.to_c for leg in self.legs if not leg.check] or [leg.to_c for leg in self.legs]
        return min(ends), max(ends)

    def band_c(self) -> float:
        return self.stability.band_c


class SequentialTemperatures(Strict):
    """Sequential design (rig/schedules/sequential.py): after every sweep the campaign decides, from what it
    has measured, whether to stay at the current end of `range_c`, cross to the other (pausing `check_sweeps`
    sweeps at each of `checks_c`, the model check's interior temperatures), or stop because every DUT meets
    the plan's `stop_when` targets; each sweep takes the `fields_per_sweep` of the plan's fields that teach
    the worst DUT the most. `rate_c_per_min` is the fastest ramp (default: the chamber's; slower when
    the slowest DUT could not follow it); `max_duration_h` bounds the run."""

    mode: Literal["sequential"]
    range_c: tuple[TEMP_C, TEMP_C]
    rate_c_per_min: RAMP_C_PER_MIN | None = Field(None, description="default: the chamber's fastest")
    checks_c: list[TEMP_C] | None = Field(None, description="default: the middle of the range")
    check_sweeps: Count(100) = 1
    fields_per_sweep: Count(10_000) | None = Field(None, description="default: all the plan's fields")
    max_duration_h: bounded(gt=0, hi=24 * 56.0) = 24.0
    max_added_checks: Count(20, 0) = Field(
        2, description="interior temperatures the run may add when T24's linearity in temperature fails on "
        "its data (0: none)")
    end_overshoot_c: bounded(lo=0.0, hi=20.0) = Field(
        0.0, description="how far beyond each end of range_c the air may go while the slowest DUT catches up "
        "(its DUTs that follow fastest then go up to this far beyond the range: only as far as they are "
        "rated); `rig design` keeps it")
    stability: Stability = Stability()

    moving: ClassVar[bool] = True

    @model_validator(mode="after")
    def _range(self):
        lo, hi = sorted(self.range_c)
        if lo == hi:
            raise KeyPathError(("range_c",), "the two ends must differ")
        for i, c in enumerate(self.checks_c or []):
            if not lo < c < hi:
                raise KeyPathError(("checks_c", i), f"{c:g} degC is not inside range_c {lo:g} .. {hi:g}")
        return self

    def checks(self) -> list[float]:
        lo, hi = sorted(self.range_c)
        return list(self.checks_c) if self.checks_c is not None else [round(0.5 * (lo + hi), 3)]

    def covered_c(self) -> tuple[float, float]:
        """The DUT temperatures the plan covers."""
        return min(self.range_c), max(self.range_c)

    def band_c(self) -> float:
        return self.stability.band_c


MODES = {"ramp": "ramp mode", "designed": "designed mode", "sequential": "sequential mode"}


def _temperatures_mode(value: Any) -> str:
    """The schedule a `temperatures:` names: no `mode:` means temperature steps."""
    if isinstance(value, dict):
        return MODES.get(value["mode"], "unknown mode") if "mode" in value else "step mode"
    return {RampTemperatures: "ramp mode", DesignedTemperatures: "designed mode",
            SequentialTemperatures: "sequential mode"}.get(type(value), "step mode")


AnyTemperatures = Annotated[
    # tags are no key of any model, so an error's key path skips them (rig/core/yamlload.py)
    Annotated[Temperatures, Tag("step mode")] | Annotated[RampTemperatures, Tag("ramp mode")]
    | Annotated[DesignedTemperatures, Tag("designed mode")]
    | Annotated[SequentialTemperatures, Tag("sequential mode")],
    Discriminator(_temperatures_mode, custom_error_type="unknown_mode",
                  custom_error_message="mode must be ramp, designed or sequential (none for temperature "
                  "steps)"),
]
