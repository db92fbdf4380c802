"""Commissioning maths for a three-axis coil set: its 3x3 matrix and the ambient from reference readings.

    fit = fit_coil_matrix(currents_a, readings_nt)      # (K,3) each: one row per current setting
    fit.matrix_nt_per_a, fit.ambient_nt, fit.covariance, fit.std_errors(), fit.nonlinearity

A reference magnetometer at the centre reads r_k = M I_k + a + e_k: 12 unknowns, linear in them, and the
same design for the three output axes (one 4-column least-squares problem per axis). Currents are scaled
to their largest value before solving. The residual scatter (which includes drift and hysteresis, not
only the reference's noise) sets each axis' variance, so the covariance states what the data show.

Linearity: the same fit with I^2 and I^3 terms per coil shows saturation (odd) or heating and nearby
soft iron (even); `nonlinearity[j]` is the largest of those terms over the driven range of coil j, as a
fraction of coil j's linear field at its largest current.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.errors import FitError

AXES = "xyz"
RCOND_SINGULAR = 1e-10
MIN_RESPONSE_SE = 10.0  # a coil whose column is within this many standard errors of zero does not respond
PARAM_NAMES = [f"M[{i}][{j}]" for i in range(3) for j in range(3)] + ["ambient_x", "ambient_y", "ambient_z"]


@dataclass
class CoilFit:
    matrix_nt_per_a: np.ndarray  # 3x3, column j: field per ampere of coil j
    ambient_nt: np.ndarray  # 3
    covariance: np.ndarray  # 12x12, PARAM_NAMES order (matrix row-major, then the ambient)
    residuals_nt: np.ndarray  # (K,3)
    sigma_nt: np.ndarray  # 3: residual scatter per output axis
    nonlinearity: np.ndarray  # 3: per coil, relative to its linear field at its largest current
    rcond: float

    def std_errors(self) -> tuple[np.ndarray, np.ndarray]:
        """(matrix 3x3, ambient 3) standard errors."""
        se = np.sqrt(np.diag(self.covariance))
        return se[:9].reshape(3, 3), se[9:]

    @property
    def residual_rms_nt(self) -> np.ndarray:
        return np.sqrt(np.mean(self.residuals_nt**2, axis=0))


def _solve(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Least squares of y (K,3) on x (K,p), columns scaled: (coefficients (p,3), unscaled (X'X)^-1, rcond)."""
    scale = np.linalg.norm(x, axis=0)
    if np.any(scale == 0):
        raise FitError("coil commissioning: a regressor is zero for every setting")
    xs = x / scale
    u, s, vt = np.linalg.svd(xs, full_matrices=False)
    rcond = float(s[-1] / s[0])
    if rcond < RCOND_SINGULAR:
        raise FitError("coil commissioning: the current settings do not separate the three coils and the "
                       "ambient; drive each coil on its own at both polarities")
    coef = (vt.T @ ((u.T @ y) / s[:, None])) / scale[:, None]
    inv = (vt.T / s**2) @ vt / np.outer(scale, scale)
    return coef, inv, rcond**2


def fit_coil_matrix(currents_a, readings_nt, reading_se_nt=None) -> CoilFit:
    """Fit r = M I + a to K settings. `reading_se_nt` (K,3), the standard error of each mean reading,
    sets a floor under the residual scatter (a perfect-looking fit of few settings is not trusted more
    than the readings themselves)."""
    currents = np.asarray(currents_a, float).reshape(-1, 3)
    readings = np.asarray(readings_nt, float).reshape(-1, 3)
    k = len(currents)
    if k < 6:
        raise FitError(f"coil commissioning: {k} settings; at least 6 needed (each coil at both polarities)")
    x = np.column_stack([currents, np.ones(k)])
    coef, inv, rcond = _solve(x, readings)
    residuals = readings - x @ coef
    sigma2 = np.sum(residuals**2, axis=0) / max(k - 4, 1)
    if reading_se_nt is not None:
        floor = np.mean(np.asarray(reading_se_nt, float).reshape(-1, 3) ** 2, axis=0)
        sigma2 = np.maximum(sigma2, floor)
    matrix, ambient = coef[:3].T.copy(), coef[3].copy()
    cov = np.zeros((12, 12))
    for i in range(3):  # axis i's four unknowns: M[i][0..2] and ambient_i
        idx = [3 * i, 3 * i + 1, 3 * i + 2, 9 + i]
        cov[np.ix_(idx, idx)] = sigma2[i] * inv
    fit = CoilFit(matrix, ambient, cov, residuals, np.sqrt(sigma2), _nonlinearity(currents, readings, matrix),
                  rcond)
    _check_response(fit)
    return fit


def _nonlinearity(currents: np.ndarray, readings: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Per coil: the largest |quadratic + cubic| term over its driven currents, relative to its linear
    field at its largest current (0 where too few distinct currents show it)."""
    out = np.zeros(3)
    cols = [currents, currents**2, currents**3, np.ones((len(currents), 1))]
    x = np.column_stack(cols)
    distinct = [len(np.unique(np.round(currents[:, j], 9))) for j in range(3)]
    if len(currents) <= x.shape[1] or min(distinct) < 4:
        return out
    try:
        coef, _, _ = _solve(x, readings)
    except FitError:
        return out
    for j in range(3):
        levels = np.unique(currents[:, j])
        bend = np.outer(levels**2, coef[3 + j]) + np.outer(levels**3, coef[6 + j])
        full = np.max(np.abs(levels)) * np.linalg.norm(matrix[:, j])
        out[j] = float(np.max(np.linalg.norm(bend, axis=1)) / full) if full > 0 else 0.0
    return out


def _check_response(fit: CoilFit) -> None:
    """A coil whose field does not rise above its own uncertainty is not connected or not driven."""
    se, _ = fit.std_errors()
    for j in range(3):
        size = float(np.linalg.norm(fit.matrix_nt_per_a[:, j]))
        if size < MIN_RESPONSE_SE * float(np.linalg.norm(se[:, j])):
            raise FitError(f"coil {AXES[j]} does not respond: its field changes by {size:.3g} nT/A, "
                           f"within {MIN_RESPONSE_SE:g} standard errors of nothing", axis=AXES[j])
