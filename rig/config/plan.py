"""Plan files (what to do): name; station (path relative to the plan file, optional; the CLI overrides it);
mode (only `step_and_dwell` today: each point is collected at a stable temperature; every sample still
carries its own temperature so a later `continuous_ramp` mode can reuse the store and the fits);
temperatures {steps | range, ramp_c_per_min, stability} or {mode: ramp, range_c, rate_c_per_min,
cycles, end_hold_s, stability} (continuous ramp, rig/ramp.py) or {mode: designed, rate_c_per_min, legs}
(what `rig design` writes, rig/legplan.py) or {mode: sequential, range_c, ...} (decided during the run,
rig/seqplan.py); fields (see rig/fieldsets.py; which kinds a
station can make is its field source's business, rig/fieldsources/); samples_per_point, settle_s,
set_reset; fit {models, robust}; outputs {dir}; stop_when {S, K, b, kb} (optional).

A "temperature step" is one setpoint of `temperatures` (T03 in a point id); the engine runs "tasks".
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import BeforeValidator, Discriminator, Field, Tag, model_validator

from calib.models import MODELS as CALIBRATION_MODELS
from rig import fieldsets
from rig.configbase import Strict
from rig.names import SafeName
from rig.numbers import (
    ANGLE_DEG,
    DAY_S,
    MAX_SAMPLES_PER_POINT,
    NT,
    NT_MAX,
    NT_VEC,
    RAMP_C_PER_MIN,
    SECONDS,
    TEMP_C,
    Count,
    bounded,
    bounded_vec3,
)
from rig.yamlload import KeyPathError


class Stability(Strict):
    """When a temperature step counts as stable, judged on each DUT's own temperature: within band_c of
    the setpoint, changing slower than rate_c_per_min, both for dwell_s; give up after max_wait_s."""

    band_c: bounded(gt=0, hi=100.0) = 0.5
    rate_c_per_min: RAMP_C_PER_MIN = 0.1
    dwell_s: SECONDS = 300.0
    max_wait_s: bounded(gt=0, hi=7 * DAY_S) = 3 * 3600.0


def _number_to_step(value: Any) -> Any:
    """A bare setpoint (or anything else that is not a mapping) is the step's setpoint_c: its own type
    then says what is wrong with it."""
    return value if isinstance(value, dict | TempStep) else {"setpoint_c": value}


def _yaml_off(value: Any) -> Any:
    """YAML reads a bare `off` as false."""
    return "off" if value is False else value


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


class RampTemperatures(Strict):
    """Continuous ramp: the chamber ramps from range_c[0] to range_c[1] and back, `cycles` times, without
    stopping, while the field source sweeps the plan's field set again and again (rig/ramp.py). Before
    the first leg the DUTs are brought to range_c[0] and judged stable with `stability`; `end_hold_s`
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


MAX_LEG_SWEEPS = 10_000


class DesignedLeg(Strict):
    """One leg of a designed schedule: the air goes to `to_c` and stays while `sweeps` sweeps are taken."""

    to_c: TEMP_C
    sweeps: Count(MAX_LEG_SWEEPS)
    rate_c_per_min: RAMP_C_PER_MIN | None = Field(None, description="default: the schedule's")
    check: bool = Field(False, description="an interior temperature of the model check (T24's linearity)")


class AssumedDut(Strict):
    """What a design assumed of a DUT (its noise per fitted sample and axis, its lag behind the air)."""

    noise_nt: bounded(gt=0, hi=NT_MAX)
    lag_s: bounded(gt=0, hi=DAY_S)


class DesignedTemperatures(Strict):
    """A designed schedule (`rig design` writes it; rig/legplan.py): legs run back to back from wherever
    the air is, each ramping at its rate and holding while its sweeps are taken; the field source sweeps
    the plan's fields throughout. `assumed` records the DUT noise and lags the design was made for (rig
    check predicts the standard errors from them; the station's stated values otherwise)."""

    mode: Literal["designed"]
    rate_c_per_min: RAMP_C_PER_MIN
    legs: list[DesignedLeg] = Field(min_length=1)
    assumed: dict[str, AssumedDut] = {}
    stability: Stability = Stability()

    moving: ClassVar[bool] = True


class SequentialTemperatures(Strict):
    """Sequential design (rig/seqplan.py): after every sweep the campaign decides, from what it has
    measured, whether to stay at the current end of `range_c`, cross to the other (pausing `check_sweeps`
    sweeps at each of `checks_c`, the model check's interior temperatures), or stop because every DUT
    meets the plan's `stop_when` targets; each sweep takes the `fields_per_sweep` of the plan's fields that
    teach the worst DUT the most. `rate_c_per_min` is the fastest ramp (default: the chamber's; slower when
    the slowest DUT could not follow it); `max_duration_h` bounds the run."""

    mode: Literal["sequential"]
    range_c: tuple[TEMP_C, TEMP_C]
    rate_c_per_min: RAMP_C_PER_MIN | None = Field(None, description="default: the chamber's fastest")
    checks_c: list[TEMP_C] | None = Field(None, description="default: the middle of the range")
    check_sweeps: Count(100) = 1
    fields_per_sweep: Count(10_000) | None = Field(None, description="default: all the plan's fields")
    max_duration_h: bounded(gt=0, hi=24 * 56.0) = 24.0
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


MODES = {"ramp": "ramp mode", "designed": "designed mode", "sequential": "sequential mode"}


def _temperatures_mode(value: Any) -> str:
    """The schedule a `temperatures:` names: no `mode:` means temperature steps."""
    if isinstance(value, dict):
        return MODES.get(value["mode"], "unknown mode") if "mode" in value else "step mode"
    return {RampTemperatures: "ramp mode", DesignedTemperatures: "designed mode",
            SequentialTemperatures: "sequential mode"}.get(type(value), "step mode")


AnyTemperatures = Annotated[
    # tags are no key of any model, so an error's key path skips them (rig/yamlload.py)
    Annotated[Temperatures, Tag("step mode")] | Annotated[RampTemperatures, Tag("ramp mode")]
    | Annotated[DesignedTemperatures, Tag("designed mode")]
    | Annotated[SequentialTemperatures, Tag("sequential mode")],
    Discriminator(_temperatures_mode, custom_error_type="unknown_mode",
                  custom_error_message="mode must be ramp, designed or sequential (none for temperature "
                  "steps)"),
]


def _vectors(directions: np.ndarray, magnitudes_nt: list[float]) -> list[tuple[float, ...]]:
    return [tuple(float(x) for x in v) for v in fieldsets.scaled(directions, magnitudes_nt)]


class _Magnitudes(Strict):
    """A field set's `targets()` are field vectors (nT) or (az, el) pairs, deterministic, in order;
    `count()` says how many without making them (bounds are checked before anything is built)."""

    magnitude_nt: NT | None = None
    magnitudes_nt: list[NT] | None = None

    def magnitude_list(self) -> list[float]:
        if self.magnitudes_nt:
            return list(self.magnitudes_nt)
        return [self.magnitude_nt or 50_000.0]


class Cube24Fields(_Magnitudes):
    """The 24 rotations of the cube applied to one reference direction (see rig/fieldsets.py)."""

    kind: Literal["cube24"]

    def targets(self) -> list[tuple[float, ...]]:
        return _vectors(fieldsets.cube24_directions(), self.magnitude_list())

    def count(self) -> int:
        return 24 * len(self.magnitude_list())


class FibonacciFields(_Magnitudes):
    kind: Literal["fibonacci"]
    n: Count(10_000, lower=4)

    def targets(self) -> list[tuple[float, ...]]:
        return _vectors(fieldsets.fibonacci_directions(self.n), self.magnitude_list())

    def count(self) -> int:
        return self.n * len(self.magnitude_list())


class DirectionFields(_Magnitudes):
    kind: Literal["directions"]
    directions: list[bounded_vec3(NT_MAX)] = Field(min_length=1)

    def targets(self) -> list[tuple[float, ...]]:
        """ValueError for a zero direction."""
        return _vectors(fieldsets.normalised(self.directions), self.magnitude_list())

    def count(self) -> int:
        return len(self.directions) * len(self.magnitude_list())

    def listed_index(self, target_index: int) -> int:
        """0-based index in `directions` of target `target_index` (targets are magnitude-major)."""
        return target_index % len(self.directions)


class VectorFields(Strict):
    kind: Literal["vectors"]
    vectors_nt: list[NT_VEC] = Field(min_length=1)

    def targets(self) -> list[tuple[float, ...]]:
        return [tuple(float(x) for x in v) for v in self.vectors_nt]

    def count(self) -> int:
        return len(self.vectors_nt)


class GridOrientations(Strict):
    """Turntable: every azimuth at every elevation (the default is 16 of the cube's 24 rotations, all
    that a two-axis table can reach)."""

    kind: Literal["grid"]
    az_deg: list[ANGLE_DEG] = Field([-90.0, 0.0, 90.0, 180.0], min_length=1)
    el_deg: list[ANGLE_DEG] = Field([-90.0, 0.0, 90.0, 180.0], min_length=1)

    def targets(self) -> list[tuple[float, ...]]:
        return fieldsets.grid_orientations(self.az_deg, self.el_deg)

    def count(self) -> int:
        return len(self.az_deg) * len(self.el_deg)


class ListOrientations(Strict):
    kind: Literal["orientations"]
    angles_deg: list[tuple[ANGLE_DEG, ANGLE_DEG]] = Field(min_length=1, description="[az, el] pairs")

    def targets(self) -> list[tuple[float, ...]]:
        return [tuple(map(float, a)) for a in self.angles_deg]

    def count(self) -> int:
        return len(self.angles_deg)


FieldSet = Annotated[
    Cube24Fields | FibonacciFields | DirectionFields | VectorFields | GridOrientations | ListOrientations,
    Field(discriminator="kind"),
]


class Fit(Strict):
    models: list[Literal[CALIBRATION_MODELS]] = Field(["t24"], min_length=1)  # calib's model registry
    robust: bool = False


class Acceptance(Strict):
    """Per-DUT PASS/FAIL limits on the calibration of `model` (default: the first of fit.models); see
    rig/acceptance.py. Parameter names are the model's (calib.models.REGISTRY), e.g. S, b_nt for t24."""

    model: Literal[CALIBRATION_MODELS] | None = None
    max_heldout_rms_nt: NT | None = Field(None, description="RMS error on held-out points")
    max_rms_nt: NT | None = Field(None, description="RMS residual of the full fit")
    max_expanded_uncertainty_nt: NT | None = Field(
        None, description="the calibration's expanded (k = 2) vector uncertainty over the plan's fields and "
        "temperatures (its uncertainty budget, rig/budget.py)")
    max_std_error: dict[str, bounded(gt=0)] = Field({}, description="largest standard error per parameter")
    bounds: dict[str, tuple[bounded(), bounded()]] = Field({}, description="[low, high] of every element")
    max_lag_s: bounded(gt=0, hi=DAY_S) | None = Field(None, description="thermal lag (ramp data only)")

    def check_against(self, models: list[str]) -> None:
        """The judged model is fitted, the parameters named are its own, each bound is low <= high."""
        from calib.models import REGISTRY

        model = self.model or models[0]
        if model not in models:
            raise KeyPathError(("acceptance", "model"), f"{model} is not among fit.models {models}")
        spec = REGISTRY[model]
        known = {**spec.params, **spec.optional}
        for key in ("max_std_error", "bounds"):
            for name in getattr(self, key):
                if name not in known:
                    raise KeyPathError(("acceptance", key, name),
                                       f"{model} has no parameter {name!r} (it has {', '.join(known)})")
        for name, (low, high) in self.bounds.items():
            if low > high:
                raise KeyPathError(("acceptance", "bounds", name), f"low {low:g} is above high {high:g}")


class Outputs(Strict):
    dir: str = "sessions"


class Plan(Strict):
    name: SafeName
    station: str | None = Field(None, description="station file, relative to the plan file")
    mode: Literal["step_and_dwell"] = "step_and_dwell"
    temperatures: AnyTemperatures
    fields: FieldSet
    samples_per_point: Count(MAX_SAMPLES_PER_POINT)
    settle_s: SECONDS = Field(1.0, description="wait after a field change before sampling")
    set_reset: Annotated[Literal["pair", "off"], BeforeValidator(_yaml_off)] = Field(
        "pair", description="pair: SET and RESET reading per sample (offset removed); off: plain reading"
    )
    fit: Fit = Fit()
    acceptance: Acceptance | None = Field(None, description="per-DUT PASS/FAIL limits (rig/acceptance.py)")
    outputs: Outputs = Outputs()
    accuracy_ppm: bounded(gt=0, hi=1e6) | None = Field(
        None, description="the reference field's accuracy target, relative to the field: `rig check` refuses "
        "a DUT position where the coil field's non-uniformity exceeds it")
    stop_when: dict[str, bounded(gt=0)] | None = Field(
        None, description="target T24 standard errors (S, K, b nT, kb nT/degC): stop once every DUT meets "
        "them (calib/targets.py)")

    @model_validator(mode="after")
    def _stop_groups(self):
        from calib.targets import GROUP_KEYS

        for group in self.stop_when or {}:
            if group not in GROUP_KEYS:
                raise KeyPathError(("stop_when", group), "unknown parameter group (known: S, K, b, kb)")
        if self.stop_when is not None and not self.stop_when:
            raise KeyPathError(("stop_when",), "give at least one target, e.g. {K: 1e-6}")
        return self

    @property
    def moving(self) -> bool:
        """Whether samples are taken while the temperature moves (ramp, designed, sequential): the fits
        then correct each DUT's thermal lag and stop_when is judged after every sweep."""
        return self.temperatures.moving

    @property
    def ramp(self) -> RampTemperatures | None:
        """The ramp settings of a continuous-ramp plan, None for temperature steps."""
        return self.temperatures if isinstance(self.temperatures, RampTemperatures) else None

    @model_validator(mode="after")
    def _acceptance_model(self):
        if self.acceptance is not None:
            self.acceptance.check_against(list(self.fit.models))
        if isinstance(self.temperatures, SequentialTemperatures) and not self.se_targets():
            raise KeyPathError(("temperatures", "mode"),
                               "a sequential schedule stops when the DUTs meet their "
                               "targets: give stop_when (or acceptance.max_std_error for t24)")
        return self

    def se_targets(self) -> dict[str, float]:
        """The T24 standard errors the campaign aims at: `stop_when`, else the acceptance limits'
        `max_std_error` when the judged model is t24 (empty when neither states any)."""
        if self.stop_when:
            return dict(self.stop_when)
        acc = self.acceptance
        if acc is not None and (acc.model or self.fit.models[0]) == "t24" and acc.max_std_error:
            return dict(acc.max_std_error)
        return {}
