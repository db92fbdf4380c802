"""Plan files (what to do): name; station (path relative to the plan file, optional; the CLI overrides
it); temperatures (the schedule: rig/config/temperatures.py); fields (rig/config/fields.py);
samples_per_point, settle_s, set_reset; fit {models, robust}; acceptance (PASS/FAIL limits per DUT);
outputs {dir}; accuracy_ppm; stop_when {S, K, b, kb} (target standard errors); notify (word to the
operator: rig/config/notify.py); customer, received, condition (what a certificate states of the items and
for whom they were calibrated: rig/config/lab.py).

A "temperature step" is one setpoint of a step schedule (T03 in a point id); the engine runs "tasks".
"""

from __future__ import annotations

import datetime as dt
from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, model_validator

from calib.models.registry import MODELS as CALIBRATION_MODELS
from rig.config.fields import FieldSet
from rig.config.lab import Customer, Text
from rig.config.notify import Notify
from rig.config.temperatures import AnyTemperatures, RampTemperatures, SequentialTemperatures
from rig.core.configbase import Strict
from rig.core.names import SafeName
from rig.core.numbers import DAY_S, MAX_SAMPLES_PER_POINT, NT, SECONDS, Count, bounded
from rig.core.yamlload import KeyPathError


def _yaml_off(value: Any) -> Any:
    """YAML reads a bare `off` as false."""
    return "off" if value is False else value


class Fit(Strict):
    models: list[Literal[CALIBRATION_MODELS]] = Field(["t24"], min_length=1)  # calib's model registry
    robust: bool = False


class Acceptance(Strict):
    """Per-DUT PASS/FAIL limits on the calibration of `model` (default: the first of fit.models); see
    rig/analysis/acceptance.py. Parameter names are the model's (calib.models.registry.REGISTRY), e.g. S, b_nt
    for t24."""

    model: Literal[CALIBRATION_MODELS] | None = None
    max_heldout_rms_nt: NT | None = Field(None, description="RMS error on held-out points")
    max_rms_nt: NT | None = Field(None, description="RMS residual of the full fit")
    max_expanded_uncertainty_nt: NT | None = Field(
        None, description="the calibration's expanded (95 %) vector uncertainty over the plan's fields and "
        "temperatures (its uncertainty budget, rig/budget/run_inputs.py)")
    max_std_error: dict[str, bounded(gt=0)] = Field({}, description="largest standard error per parameter")
    bounds: dict[str, tuple[bounded(), bounded()]] = Field({}, description="[low, high] of every element")
    max_lag_s: bounded(gt=0, hi=DAY_S) | None = Field(None, description="thermal lag (ramp data only)")
    model_checks: bool = Field(
        True, description="fail a DUT whose T24 model check (linearity in temperature, thermal hysteresis, "
        "linearity in the field) fails where the judged model does not capture it")

    def check_against(self, models: list[str]) -> None:
        """The judged model is fitted, the parameters named are its own (a name it had before, such as P12's
        b_nt, counts as the one it has now: calib/equations.py RENAMED_PARAMS), each bound is low <= high."""
        from calib.equations import renamed
        from calib.models.registry import REGISTRY

        model = self.model or models[0]
        if model not in models:
            raise KeyPathError(("acceptance", "model"), f"{model} is not among fit.models {models}")
        spec = REGISTRY[model]
        known = {**spec.params, **spec.optional}
        for key in ("max_std_error", "bounds"):
            for name in getattr(self, key):
                if renamed(model, name) not in known:
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
    mode: Literal["step_and_dwell"] | None = Field(
        None, description="read from plans written before the schedule moved to `temperatures.mode`; a "
        "plan's schedule is its temperatures' mode")
    temperatures: AnyTemperatures
    fields: FieldSet
    samples_per_point: Count(MAX_SAMPLES_PER_POINT)
    settle_s: SECONDS = Field(1.0, description="wait after a field change before sampling")
    field_order: Literal["shuffled", "listed"] | None = Field(
        None, description="the order of the field targets at each temperature step: shuffled (a fresh order "
        "at every step, the same on every run of the plan; the default) or listed (the plan's order). A "
        "fixed order turns whatever drifts through a step (the lab field, the chamber's heater) into an "
        "error that follows the targets, which the fit cannot tell from a calibration; a shuffled one turns "
        "it into scatter that the fit sees. A moving schedule sweeps in the listed order")
    set_reset: Annotated[Literal["pair", "off"], BeforeValidator(_yaml_off)] = Field(
        "pair", description="pair: SET and RESET reading per sample (offset removed); off: plain reading"
    )
    fit: Fit = Fit()
    acceptance: Acceptance | None = Field(
        None, description="per-DUT PASS/FAIL limits (rig/analysis/acceptance.py)")
    outputs: Outputs = Outputs()
    accuracy_ppm: bounded(gt=0, hi=1e6) | None = Field(
        None, description="the reference field's accuracy target, relative to the field: `rig check` refuses "
        "a DUT position where the coil field's non-uniformity exceeds it")
    notify: Notify | None = Field(
        None, description="word to the operator (rig/config/notify.py); replaces the station's notify:")
    stop_when: dict[str, bounded(gt=0)] | None = Field(
        None, description="target T24 standard errors (S, K, b nT, kb nT/degC): stop once every DUT meets "
        "them (calib/design/targets.py)")
    customer: Customer | None = Field(None, description="for whom the items are calibrated")
    received: dt.date | None = Field(None, description="the date the items were received")
    condition: Text | None = Field(None, description="the items' condition when received")

    @model_validator(mode="after")
    def _stop_groups(self):
        from calib.design.targets import GROUP_KEYS

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
    def judged_model(self) -> str:
        """The calibration the plan judges and every listing names: acceptance.model, else the first of
        fit.models."""
        return (self.acceptance.model if self.acceptance is not None and self.acceptance.model
                else self.fit.models[0])

    @property
    def ramp(self) -> RampTemperatures | None:
        """The ramp settings of a continuous-ramp plan, None for temperature steps."""
        return self.temperatures if isinstance(self.temperatures, RampTemperatures) else None

    @model_validator(mode="after")
    def _acceptance_model(self):
        if self.acceptance is not None:
            self.acceptance.check_against(list(self.fit.models))
        if self.field_order == "shuffled" and self.moving:
            raise KeyPathError(("field_order",), "a moving schedule sweeps the fields in the listed order "
                               "(ramp, designed, sequential); shuffled applies to temperature steps")
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
