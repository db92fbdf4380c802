"""The calibration models: what each one is and how it is fitted (the registry).

The registry is the one list of models: the CLI's --model choices, the plan's allowed `fit.models`, the
campaign's fits and the report's model comparison all read it. Adding a model = its parameters and its
field in calib/equations.py, its module (fit_weighted) + its `ModelSpec` in REGISTRY + its tests.

Imports point one way: equations <- calibration <- the model modules (t24, t36, p12, scalar) <- this registry
<- calib.fit. The equations' names are re-exported here for the callers that know them from here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import calib.models.p12 as p12
import calib.models.scalar as scalar
import calib.models.scalar_choice as scalar_choice
import calib.models.t24 as t24
import calib.models.t36 as t36
from calib.equations import (  # noqa: F401 - re-exported: callers know them as calib.models.registry.*
    MODELS,
    OPTIONAL_PARAMS,
    PARAM_SHAPES,
    apply,
    needs_temperature,
    p12_angles_from_rows,
    p12_matrix,
)
from calib.errors import DataError


@dataclass(frozen=True)
class FitOptions:
    """Options of calib.fit a model may use (each model says which it takes)."""

    temp_ref_c: float | None = None
    field_norm_nt: float | None = None
    temperature_terms: bool | None = None
    balance_orientations: bool | None = None


@dataclass(frozen=True)
class ModelSpec:
    name: str
    params: dict[str, tuple[int, ...]]  # required parameters and their shapes
    fit_weighted: Callable  # (dataset, weights or None, FitOptions) -> (Calibration, residuals)
    vector: bool  # True: output in the reference frame, fitted to the reference vector; False: to |B| only
    needs_temperature: bool  # every sample must have a temperature
    optional: dict[str, tuple[int, ...]] = field(default_factory=dict)
    options: frozenset[str] = frozenset({"temp_ref_c"})  # the FitOptions it uses
    # (dataset, FitOptions, robust) -> (fit_weighted(weights), stats recording the choice): decides the
    # options the caller left open before the fit; None = the model has no open options
    choose: Callable | None = None
    # fit_weighted's residuals are the calibrated field minus the reference (T24): the fit statistics take
    # them as they are instead of applying the calibration again
    residuals_are_field_error: bool = False


def _fit_t24(ds, weights, o: FitOptions):
    return t24.fit_weighted(ds, weights, o.temp_ref_c)


def _fit_t36(ds, weights, o: FitOptions):
    return t36.fit_weighted(ds, weights, o.temp_ref_c)


def _fit_p12(ds, weights, o: FitOptions):
    return p12.fit_weighted(ds, weights)


def _fit_scalar(ds, weights, o: FitOptions):
    """The scalar fit with the options as given (None = off); calib.fit decides open ones by validation."""
    balance = None
    if o.balance_orientations:
        first, _ = scalar.fit_weighted(ds, weights, temp_ref_c=o.temp_ref_c, field_norm_nt=o.field_norm_nt,
                                       temperature_terms=bool(o.temperature_terms))
        balance = scalar.orientation_balance_weights(first.apply(ds.h_nt, ds.temp_c))
    return scalar.fit_weighted(ds, weights, temp_ref_c=o.temp_ref_c, field_norm_nt=o.field_norm_nt,
                               temperature_terms=bool(o.temperature_terms), balance=balance)


def _choose_scalar(ds, o: FitOptions, robust: bool):
    return scalar_choice.choose(ds, robust, temp_ref_c=o.temp_ref_c, field_norm_nt=o.field_norm_nt,
                                temperature_terms=o.temperature_terms,
                                balance_orientations=o.balance_orientations)


REGISTRY: dict[str, ModelSpec] = {
    spec.name: spec
    for spec in (
        ModelSpec("t24", PARAM_SHAPES["t24"], _fit_t24, vector=True, needs_temperature=True,
                  residuals_are_field_error=True),
        ModelSpec("p12", PARAM_SHAPES["p12"], _fit_p12, vector=True, needs_temperature=False,
                  options=frozenset()),
        ModelSpec("scalar", PARAM_SHAPES["scalar"], _fit_scalar, vector=False, needs_temperature=False,
                  optional=OPTIONAL_PARAMS["scalar"],
                  options=frozenset({"temp_ref_c", "field_norm_nt", "temperature_terms",
                                     "balance_orientations"}), choose=_choose_scalar),
        ModelSpec("t36", PARAM_SHAPES["t36"], _fit_t36, vector=True, needs_temperature=True,
                  residuals_are_field_error=True),
    )
}
VECTOR_MODELS = tuple(name for name, spec in REGISTRY.items() if spec.vector)


def spec(model: str) -> ModelSpec:
    """The model's entry; DataError naming the known models otherwise."""
    try:
        return REGISTRY[model]
    except KeyError:
        raise DataError(f"unknown calibration model {model!r} (known: {', '.join(MODELS)})") from None
