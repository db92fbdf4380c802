"""calib.fit: one entry point for every model, with the optional robust wrapper and the fit statistics."""

from __future__ import annotations

import numpy as np

from calib.calibration import MAGNITUDES_KEY, Calibration
from calib.dataset import Dataset
from calib.errors import DataError
from calib.models import registry
from calib.stats.directions import spread_rows, taken_directions
from calib.stats.residuals import residual_stats
from calib.stats.robust import irls


def fit(
    ds: Dataset,
    model: str = "t24",
    *,
    robust: bool = False,
    temp_ref_c: float | None = None,
    field_norm_nt: float | None = None,
    temperature_terms: bool | None = None,
    balance_orientations: bool | None = None,
    software_version: str = "unknown",
) -> Calibration:
    """Fit `model` (a name in calib.models.registry.REGISTRY: "t24", "p12", "scalar", "t36") to `ds`.

    robust: Huber IRLS; rows beyond the flag threshold are counted in stats.n_outliers, listed in
    `Calibration.outliers` and left out of the final fit. temp_ref_c: centre of the temperature terms
    (default: middle of the data's range). field_norm_nt, temperature_terms, balance_orientations:
    scalar model only (see calib.models.scalar.fit_weighted); None = chosen by validation inside `ds`
    (calib/models/scalar_choice.py), the choice and its scores recorded in stats.
    software_version: recorded in the calibration file (the application passes its own version).
    """
    check_dataset(ds)
    spec = registry.spec(model)
    options = registry.FitOptions(temp_ref_c, field_norm_nt, temperature_terms, balance_orientations)
    choice: dict = {}
    if spec.choose is not None:
        fit_weighted, choice = spec.choose(ds, options, robust)
    else:

        def fit_weighted(weights):
            return spec.fit_weighted(ds, weights, options)

    if robust:
        cal, residuals, flagged = irls(fit_weighted, len(ds))
    else:
        cal, residuals = fit_weighted(None)
        flagged = np.zeros(len(ds), bool)
    used = ~flagged
    stats = {**cal.stats, **choice}
    norm = stats.get("field_norm_nt")  # scalar model with one constant |B|
    if spec.residuals_are_field_error:
        stats.update(residual_stats(ds, None, vector=True, used=used, error_nt=residuals))
    else:
        field = cal.apply(ds.h_nt, ds.temp_c)
        stats.update(residual_stats(ds, field, vector=spec.vector, used=used, norm_nt=norm))
    stats.update(
        {"n": len(ds), "n_used": int(used.sum()), "n_outliers": int(flagged.sum()), "robust": robust}
    )
    if ds.temp_c is not None and used.any():  # the temperatures the calibration is valid between
        stats["temperature_range_c"] = [float(ds.temp_c[used].min()), float(ds.temp_c[used].max())]
    if used.any():  # the magnitudes calibrated: `rig apply` counts rows outside them, or in another unit
        stats[MAGNITUDES_KEY] = magnitude_ranges(ds, used)
    if used.any():  # and the field directions, as the calibrated field has them (calib/stats/directions.py)
        rows = np.flatnonzero(used)[spread_rows(int(used.sum()))]
        calibrated = cal.apply(ds.h_nt[rows], None if ds.temp_c is None else ds.temp_c[rows])
        stats["field_directions"] = np.round(taken_directions(calibrated), 4).tolist()
    if flagged.any():
        stats["outlier_rows_first"] = np.flatnonzero(flagged)[:20].tolist()
    cal.stats = stats
    cal.source = {
        **ds.source,
        "rows_used": int(used.sum()),
        "rows_rejected": int(ds.source.get("rows_rejected", 0)) + int(flagged.sum()),
    }
    cal.outliers = flagged
    cal.software_version = software_version
    return cal


def magnitude_ranges(ds: Dataset, used: np.ndarray) -> dict:
    """{h: [least, largest |h|], B: [least, largest |B|] of the reference (where the data has one)} over the
    rows used, nT."""
    def span(values: np.ndarray) -> list[float]:
        return [float(values.min()), float(values.max())]

    out = {"h": span(np.linalg.norm(ds.h_nt[used], axis=1))}
    if ds.ref_nt is not None:
        out["B"] = span(np.linalg.norm(ds.ref_nt[used], axis=1))
    elif ds.ref_norm_nt is not None:
        out["B"] = span(np.asarray(ds.ref_norm_nt, float)[used])
    return out


def check_dataset(ds: Dataset) -> None:
    """Shapes agree and every number is finite; a problem names the array and the first bad row."""
    n = ds.h_nt.shape[0] if ds.h_nt.ndim == 2 else -1
    if ds.h_nt.ndim != 2 or ds.h_nt.shape[1] != 3:
        raise DataError(f"raw readings must be an (N,3) array, got shape {ds.h_nt.shape}")
    if n == 0:
        raise DataError(f"{ds.source.get('path', 'dataset')}: no samples")
    arrays = {"h_nt": ds.h_nt, "temp_c": ds.temp_c, "ref_nt": ds.ref_nt, "ref_norm_nt": ds.ref_norm_nt}
    for name, arr in arrays.items():
        if arr is None:
            continue
        if arr.shape[0] != n:
            raise DataError(f"{name} has {arr.shape[0]} rows, the readings have {n}")
        bad = ~np.isfinite(arr.reshape(n, -1)).all(axis=1)
        if bad.any():
            raise DataError(f"{name} row {int(np.flatnonzero(bad)[0])}: NaN or inf")
