"""The uncertainty of a calibration, by Monte Carlo over its inputs (GUM Supplement 1, JCGM 101:2008).

    budget = monte_carlo(ds, cal, sources, refit, grid, rng=rng)
    budget.expanded          # {param: array}, the same keys and shapes as cal.params (U = k u)
    budget.contributions     # [{source, contribution_nt}]: each input's share of the field error
    budget.as_dict()         # the calibration file's `uncertainty:` section

A source is one input quantity the fit rests on, as a function that draws how far the data could be from
what was recorded: changes to the reference vectors (the coil matrix, the reference magnetometer, the
ambient, a DUT's position within its tolerance, the coil geometry), to the temperatures (the probe's
accuracy, the gradient to the DUT), or to the raw readings (`statistical`: the readings' own noise,
redrawn with the fit's residual scatter; for a linear least-squares fit this reproduces sigma^2 G^-1).
Changes of several sources add up. Every draw is re-fitted; the spread of the refitted parameters is
their uncertainty.

- each source alone, `draws_per_source` times: its contribution, the RMS change of the calibrated field
  over the grid (the plan's fields and temperatures), in nT: a standard uncertainty;
- all together, `draws` times: each parameter's standard uncertainty u and expanded U = k u, and the
  calibrated field's error over the grid: its RMS (`combined_standard_nt`) and the 95th percentile of its
  length (`expanded_vector_error_nt`, the coverage interval GUM S1 reads off the draws).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.errors import FitError
from calib.models import registry
from calib.models.registry import apply

COVERAGE_FACTOR = 2.0
COVERAGE_PROBABILITY = 0.95
DRAWS = 200
DRAWS_PER_SOURCE = 60
MIN_SHARE_FITTED = 0.9  # of the draws; a fit that fails more often is too fragile to state an uncertainty


@dataclass(frozen=True)
class Draw:
    """How far the data could be from what was recorded, for one draw (None: no change)."""

    ref_nt: np.ndarray | None = None  # added to the reference vectors (N,3)
    temp_c: np.ndarray | None = None  # added to the temperatures (N,) or a scalar
    h_nt: np.ndarray | None = None  # added to the raw readings (N,3)


@dataclass(frozen=True)
class Source:
    name: str
    draw: Callable[[np.random.Generator], Draw]
    note: str = ""
    reference_only: bool = False  # its draws change the reference vectors alone


@dataclass
class Budget:
    """A calibration's uncertainty. From `monte_carlo` (this module) or calib.uncertainty.budgeting.budget,
    which adds the covariance, coverage intervals and the field error at every grid point."""

    coverage_factor: float
    standard: dict[str, np.ndarray]
    expanded: dict[str, np.ndarray]
    contributions: list[dict]
    combined_standard_nt: float
    expanded_vector_error_nt: float
    draws: int
    notes: list[str] = field(default_factory=list)
    method: str = ""
    interval: dict | None = None  # {name: (low, high)}: the 95 % coverage interval of every parameter
    covariance: np.ndarray | None = None  # (P,P) in the order of `parameter_labels`
    parameter_labels: list[str] | None = None
    vector_error_nt: dict | None = None  # the 95 % radius at every grid point, its maximum and percentile
    failed_draws: int = 0
    stated: bool = True  # False: too many refits failed; as_dict refuses
    monte_carlo: dict | None = None
    linear: object | None = field(default=None, repr=False)  # calib.uncertainty.propagation.LinearBudget
    # per parameter (the shapes of `expanded`): k from its effective degrees of freedom, and those (inf:
    # every input known); None: one coverage_factor for all
    coverage_factors: dict[str, np.ndarray] | None = None
    effective_dof: dict[str, np.ndarray] | None = None
    field_dof: float = float("inf")  # the calibrated field's effective degrees of freedom (coverage_factor's)

    def as_dict(self) -> dict:
        """Plain values for the calibration file; FitError when the uncertainty cannot be stated."""
        if not self.stated:
            raise FitError("the uncertainty cannot be stated: " + "; ".join(self.notes))
        out = {
            "coverage_factor": self.coverage_factor,
            "method": self.method or f"Monte Carlo (GUM S1), {self.draws} draws of every input together",
            "expanded": {k: np.asarray(v, float).tolist() for k, v in self.expanded.items()},
            "budget": [dict(c) for c in self.contributions],
            "combined_standard_nt": self.combined_standard_nt,
            "expanded_vector_error_nt": self.expanded_vector_error_nt,
            "coverage_probability": COVERAGE_PROBABILITY,
            "failed_draws": self.failed_draws,
            "notes": list(self.notes),
        }
        if self.coverage_factors is not None:
            out["coverage_factors"] = {k: np.asarray(v, float).tolist()
                                       for k, v in self.coverage_factors.items()}
        if self.effective_dof is not None:  # null: infinite (every input known)
            out["effective_dof"] = {k: _finite_or_none(v) for k, v in self.effective_dof.items()}
            out["field_effective_dof"] = _finite_or_none(self.field_dof)
        if self.interval is not None:
            out["interval"] = {k: [np.asarray(lo, float).tolist(), np.asarray(hi, float).tolist()]
                               for k, (lo, hi) in self.interval.items()}
        if self.covariance is not None:
            cov = np.asarray(self.covariance, float)
            out["covariance"] = {"parameters": list(self.parameter_labels),
                                 "matrix": ((cov + cov.T) / 2).tolist()}  # symmetric as written
        if self.vector_error_nt is not None:
            out["vector_error_nt"] = dict(self.vector_error_nt)
        if self.monte_carlo is not None:
            out["monte_carlo"] = dict(self.monte_carlo)
        return out


def _finite_or_none(values):
    """An array as nested lists, None where it is not finite (YAML and JSON alike)."""
    a = np.asarray(values, float)
    out = np.where(np.isfinite(a), a, np.nan).astype(object)
    out[~np.isfinite(a)] = None
    return out.tolist()


def with_draw(ds: Dataset, d: Draw) -> Dataset:
    """The dataset with a draw's changes added."""
    return replace(ds, h_nt=ds.h_nt if d.h_nt is None else ds.h_nt + d.h_nt,
                   ref_nt=ds.ref_nt if d.ref_nt is None else ds.ref_nt + d.ref_nt,
                   temp_c=ds.temp_c if d.temp_c is None else ds.temp_c + d.temp_c)


def statistical(ds: Dataset, sigma_nt) -> Source:
    """The readings' own noise: raw readings redrawn around the measured ones with the fit's residual
    scatter per axis (a parametric bootstrap)."""
    sigma = np.broadcast_to(np.asarray(sigma_nt, float), (3,))

    def draw(rng: np.random.Generator) -> Draw:
        return Draw(h_nt=rng.normal(0.0, 1.0, ds.h_nt.shape) * sigma)

    return Source("fit (statistical)", draw, f"residual scatter {', '.join(f'{s:.3g}' for s in sigma)} nT")


def raw_for(cal: Calibration, field_nt: np.ndarray, temp_c: np.ndarray | None) -> np.ndarray:
    """The raw readings the calibration maps to `field_nt` at `temp_c`: every model is affine in h at a
    given temperature, so its map is solved exactly from its values at h = 0 and at the unit vectors."""
    field_nt = np.atleast_2d(np.asarray(field_nt, float))
    n = len(field_nt)
    t = None if temp_c is None else np.asarray(temp_c, float)
    h = np.zeros((4 * n, 3))
    h[n:2 * n, 0] = h[2 * n:3 * n, 1] = h[3 * n:, 2] = 1.0
    out = apply(cal.model, cal.params, h, None if t is None else np.tile(t, 4), cal.temp_ref_c)
    offset = out[:n]
    slope = np.stack([out[n:2 * n] - offset, out[2 * n:3 * n] - offset, out[3 * n:] - offset], axis=2)
    return np.linalg.solve(slope, (field_nt - offset)[:, :, None])[:, :, 0]


def monte_carlo(ds: Dataset, cal: Calibration, sources: list[Source], refit: Callable[[Dataset], Calibration],
                grid: tuple[np.ndarray, np.ndarray | None], *, rng: np.random.Generator,
                draws: int = DRAWS, draws_per_source: int = DRAWS_PER_SOURCE,
                coverage_factor: float = COVERAGE_FACTOR, reference_map=None) -> Budget:
    """The budget of `cal` (fitted to `ds`) over `sources`; `grid` = (fields (G,3) nT, temperatures (G,)
    or None) where the calibrated field's error is judged; `refit(ds)` fits the same model the same way.
    `reference_map` (a model linear in the reference, e.g. calib.models.t24.reference_map) gives the
    parameters' change for a change of the references alone, so those draws need no refit."""
    grid_field, grid_temp = grid
    grid_h = raw_for(cal, grid_field, grid_temp)
    nominal = cal.apply(grid_h, grid_temp)

    failures: list[str] = []
    failed: list[int] = []

    def run(chosen: list[Source], n: int) -> tuple[np.ndarray, dict[str, list[np.ndarray]]]:
        errors = []
        params: dict[str, list[np.ndarray]] = {k: [] for k in cal.params}
        for _ in range(n):
            if reference_map is not None and all(source.reference_only for source in chosen):
                change = sum(source.draw(rng).ref_nt for source in chosen)
                fitted = replace(cal, params={k: cal.params[k] + d for k, d in reference_map(change).items()})
            else:
                data = ds
                for source in chosen:
                    data = with_draw(data, source.draw(rng))
                try:
                    fitted = refit(data)
                except FitError:  # a draw the model cannot fit at all: counted, not used
                    continue
            errors.append(fitted.apply(grid_h, grid_temp) - nominal)
            for k in params:
                params[k].append(np.asarray(fitted.params[k], float))
        names = ", ".join(s.name for s in chosen)
        if len(errors) < MIN_SHARE_FITTED * n:
            raise FitError(f"{cal.model}: only {len(errors)} of {n} Monte Carlo draws ({names}) could be "
                           "fitted: the fit is too close to unidentifiable for an uncertainty")
        if len(errors) < n:
            failures.append(f"{n - len(errors)} of {n} refits failed ({names}) and are not in the figures")
            failed.append(n - len(errors))
        return np.array(errors), params

    contributions = []
    for source in sources:
        errors, _ = run([source], draws_per_source)
        contributions.append({"source": source.name, "contribution_nt": _rms_length(errors),
                              **({"note": source.note} if source.note else {})})
    errors, params = run(sources, draws)
    standard = {k: np.std(np.array(v), axis=0, ddof=1) for k, v in params.items()}
    lengths = np.linalg.norm(errors, axis=2)
    return Budget(
        coverage_factor=coverage_factor, standard=standard,
        expanded={k: coverage_factor * v for k, v in standard.items()},
        contributions=contributions, combined_standard_nt=_rms_length(errors),
        expanded_vector_error_nt=float(np.quantile(lengths, COVERAGE_PROBABILITY)), draws=draws,
        notes=failures, failed_draws=sum(failed))


def _rms_length(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(errors**2, axis=-1))))


def residual_sigma_nt(ds, cal: Calibration) -> np.ndarray:
    """The scatter of the fit's residuals per axis (vector models) or of |B| (scalar, on every axis)."""
    used = np.ones(len(ds), bool) if cal.outliers is None else ~cal.outliers
    out = cal.apply(ds.h_nt[used], None if ds.temp_c is None else ds.temp_c[used])
    if registry.spec(cal.model).vector:
        return np.sqrt(np.mean((out - ds.ref_nt[used]) ** 2, axis=0))
    if ds.ref_nt is not None:
        norm = np.linalg.norm(ds.ref_nt[used], axis=1)
    elif ds.ref_norm_nt is not None:
        norm = ds.ref_norm_nt[used]
    else:  # a constant |B| given to the fit, or the raw readings' radius it scaled to
        return np.full(3, float(cal.stats.get("sigma_nt", np.nan)))
    return np.full(3, np.sqrt(np.mean((np.linalg.norm(out, axis=1) - norm) ** 2)))


def statistical_only(ds, cal: Calibration) -> dict:
    """The budget of a calibration fitted to data without a reference chain (a CSV): its statistical part
    alone, from its standard errors (k = 2), and the field error it leaves on average over the data's own
    points (sigma sqrt(p / N) per axis: the mean leverage of a least-squares fit is p / N)."""
    sigma = residual_sigma_nt(ds, cal)
    p = sum(int(np.size(v)) for v in cal.params.values()) / (3 if registry.spec(cal.model).vector else 1)
    used = len(ds) if cal.outliers is None else int((~cal.outliers).sum())
    contribution = float(np.sqrt(np.sum(sigma**2) * p / max(used, 1)))
    k = COVERAGE_FACTOR
    return {
        "coverage_factor": k, "method": "standard errors of the fit",
        "expanded": {name: (k * np.asarray(cal.std_errors[name], float)).tolist() for name in cal.params},
        "budget": [{"source": "fit (statistical)", "contribution_nt": contribution}],
        "combined_standard_nt": contribution, "expanded_vector_error_nt": k * contribution,
        "coverage_probability": COVERAGE_PROBABILITY,
        "notes": ["no reference chain with these data (a CSV): the reference's own uncertainty is not in "
                  "this budget"],
    }
