"""Iteratively reweighted least squares (Huber) shared by every model; outliers flagged, never hidden."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

# Huber corner and outlier flag for the normalised residual distance d of a row with k residuals.
# With Gaussian noise d^2 is chi^2(k); the flag sits near its 2e-5 tail so clean data loses ~nothing.
HUBER_C = {1: 1.345, 2: 2.0, 3: 2.4}
FLAG_D = {1: 4.4, 2: 4.8, 3: 5.0}
MAX_ITER = 30


def robust_scale(residuals: np.ndarray) -> np.ndarray:
    """Per-column noise scale from the median absolute deviation (Gaussian-consistent)."""
    r = residuals.reshape(residuals.shape[0], -1)
    med = np.median(r, axis=0)
    scale = 1.4826 * np.median(np.abs(r - med), axis=0)
    return np.where(scale > 0, scale, np.finfo(float).tiny)


def row_distance(residuals: np.ndarray, scale: np.ndarray) -> np.ndarray:
    r = residuals.reshape(residuals.shape[0], -1)
    return np.sqrt(np.sum((r / scale) ** 2, axis=1))


def irls(fit_weighted: Callable[[np.ndarray | None], tuple[object, np.ndarray]], n_rows: int):
    """Huber IRLS, then a final fit with flagged rows at weight zero.

    `fit_weighted(weights)` returns (result, residuals (N,) or (N,k)) for all rows. Returns the final
    result, its residuals and the boolean outlier mask.
    """
    result, res = fit_weighted(None)
    k = 1 if res.ndim == 1 else res.shape[1]
    c = HUBER_C[k]
    weights = np.ones(n_rows)
    for _ in range(MAX_ITER):
        scale = robust_scale(res[weights > 0] if np.any(weights > 0) else res)
        d = row_distance(res, scale)
        new = np.minimum(1.0, c / np.maximum(d, 1e-300))
        converged = np.max(np.abs(new - weights)) < 1e-4
        weights = new
        result, res = fit_weighted(weights)
        if converged:
            break
    scale = robust_scale(res[row_distance(res, robust_scale(res)) < FLAG_D[k]])
    flagged = row_distance(res, scale) > FLAG_D[k]
    result, res = fit_weighted((~flagged).astype(float))
    return result, res, flagged
