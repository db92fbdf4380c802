"""Plan files (what to do): name; station (path relative to the plan file, optional; the CLI overrides it);
mode (only `step_and_dwell` today: each point is collected at a stable temperature; every sample still
carries its own temperature so a later `continuous_ramp` mode can reuse the store and the fits);
temperatures {steps | range, ramp_c_per_min, stability}; fields (see rig/fieldsets.py; which kinds a
station can make is its field source's business, rig/fieldsources/); samples_per_point, settle_s,
set_reset; fit {models, robust}; outputs {dir}.

A "temperature step" is one setpoint of `temperatures` (T03 in a point id); the engine runs "tasks".
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BeforeValidator, Field, model_validator

from calib.models import MODELS as CALIBRATION_MODELS
from rig import fieldsets
from rig.configbase import PositiveFloat, Strict, Vec3
from rig.yamlload import KeyPathError


class Stability(Strict):
    """When a temperature step counts as stable, judged on each DUT's own temperature: within band_c of
    the setpoint, changing slower than rate_c_per_min, both for dwell_s; give up after max_wait_s."""

    band_c: PositiveFloat = 0.5
    rate_c_per_min: PositiveFloat = 0.1
    dwell_s: float = Field(300.0, ge=0)
    max_wait_s: PositiveFloat = 3 * 3600.0


def _number_to_step(value: Any) -> Any:
    return {"setpoint_c": value} if isinstance(value, int | float) and not isinstance(value, bool) else value


def _yaml_off(value: Any) -> Any:
    """YAML reads a bare `off` as false."""
    return "off" if value is False else value


class TempStep(Strict):
    setpoint_c: float
    ramp_c_per_min: PositiveFloat | None = None
    stability: Stability | None = Field(None, description="keys given here override the plan's stability")


class TempRange(Strict):
    start_c: float
    stop_c: float
    step_c: float

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
    ramp_c_per_min: PositiveFloat = 2.0
    stability: Stability = Stability()

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


def _vectors(directions: np.ndarray, magnitudes_nt: list[float]) -> list[tuple[float, ...]]:
    return [tuple(float(x) for x in v) for v in fieldsets.scaled(directions, magnitudes_nt)]


class _Magnitudes(Strict):
    """A field set's `targets()` are field vectors (nT) or (az, el) pairs, deterministic, in order;
    `count()` says how many without making them (bounds are checked before anything is built)."""

    magnitude_nt: PositiveFloat | None = None
    magnitudes_nt: list[PositiveFloat] | None = None

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
    n: int = Field(ge=4, le=10_000)

    def targets(self) -> list[tuple[float, ...]]:
        return _vectors(fieldsets.fibonacci_directions(self.n), self.magnitude_list())

    def count(self) -> int:
        return self.n * len(self.magnitude_list())


class DirectionFields(_Magnitudes):
    kind: Literal["directions"]
    directions: list[Vec3] = Field(min_length=1)

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
    vectors_nt: list[Vec3] = Field(min_length=1)

    def targets(self) -> list[tuple[float, ...]]:
        return [tuple(float(x) for x in v) for v in self.vectors_nt]

    def count(self) -> int:
        return len(self.vectors_nt)


class GridOrientations(Strict):
    """Turntable: every azimuth at every elevation (the default is 16 of the cube's 24 rotations, all
    that a two-axis table can reach)."""

    kind: Literal["grid"]
    az_deg: list[float] = Field([-90.0, 0.0, 90.0, 180.0], min_length=1)
    el_deg: list[float] = Field([-90.0, 0.0, 90.0, 180.0], min_length=1)

    def targets(self) -> list[tuple[float, ...]]:
        return fieldsets.grid_orientations(self.az_deg, self.el_deg)

    def count(self) -> int:
        return len(self.az_deg) * len(self.el_deg)


class ListOrientations(Strict):
    kind: Literal["orientations"]
    angles_deg: list[tuple[float, float]] = Field(min_length=1, description="[az, el] pairs")

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
    max_heldout_rms_nt: PositiveFloat | None = Field(None, description="RMS error on held-out points")
    max_rms_nt: PositiveFloat | None = Field(None, description="RMS residual of the full fit")
    max_std_error: dict[str, PositiveFloat] = Field({}, description="largest standard error per parameter")
    bounds: dict[str, tuple[float, float]] = Field({}, description="[low, high] of every element")
    max_lag_s: PositiveFloat | None = Field(None, description="thermal lag (judged on ramp data only)")

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
    name: str
    station: str | None = Field(None, description="station file, relative to the plan file")
    mode: Literal["step_and_dwell"] = "step_and_dwell"
    temperatures: Temperatures
    fields: FieldSet
    samples_per_point: int = Field(ge=1)
    settle_s: float = Field(1.0, ge=0, description="wait after a field change before sampling")
    set_reset: Annotated[Literal["pair", "off"], BeforeValidator(_yaml_off)] = Field(
        "pair", description="pair: SET and RESET reading per sample (offset removed); off: plain reading"
    )
    fit: Fit = Fit()
    acceptance: Acceptance | None = Field(None, description="per-DUT PASS/FAIL limits (rig/acceptance.py)")
    outputs: Outputs = Outputs()

    @model_validator(mode="after")
    def _acceptance_model(self):
        if self.acceptance is not None:
            self.acceptance.check_against(list(self.fit.models))
        return self
