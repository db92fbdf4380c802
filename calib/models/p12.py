"""P12: h = Q P B + h0. Three scale factors, three non-orthogonality angles, three raw offsets (`h0_nt`:
subtracted from h, B = (Q P)^-1 (h - h0_nt); not T24's `b_nt`, which is added to the field).

Q P is lower-triangular, so each raw axis i is a linear least-squares fit of h_i on (B_1..B_i, 1)
(decoupled by rows, as in the paper). The scale factor is the norm of the fitted row and the angles follow
from the normalised row. Flipping the sign of a row's scale factor together with its unit vector gives the
same matrix: with rows 2 and 3 that is the paper's four stationary points (`stationary_points`); the
physical one has every k_i > 0 and every angle within +-90 deg.
"""

from __future__ import annotations

import numpy as np

from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.equations import p12_angles_from_rows, p12_matrix
from calib.errors import DataError, FitError

RCOND_SINGULAR = 1e-12


def _row_fits(ds: Dataset, weights: np.ndarray | None):
    """Per raw axis: coefficients on (B_1..B_i, 1), their unit-variance covariance, residuals."""
    if ds.ref_nt is None:
        raise DataError(
            "P12 needs the reference field vector of every sample (columns bx,by,bz); "
            "with only |B| known use --model scalar"
        )
    n = len(ds)
    w = np.ones(n) if weights is None else np.asarray(weights, float)
    n_used = int(np.count_nonzero(w))
    if n_used <= 4:
        raise FitError(f"P12: {n_used} samples, more than 4 needed (up to 4 unknowns per axis)")
    sw = np.sqrt(w)[:, None]
    m = np.zeros((3, 3))
    b = np.zeros(3)
    covs, residuals, sigma2 = [], np.empty((n, 3)), np.empty(3)
    for i in range(3):
        x = np.column_stack([ds.ref_nt[:, : i + 1], np.ones(n)])
        scale = np.linalg.norm(x * sw, axis=0)
        xs = x * sw / np.where(scale > 0, scale, 1.0)
        u, s, vt = np.linalg.svd(xs, full_matrices=False)
        if np.any(scale == 0) or s[-1] < RCOND_SINGULAR**0.5 * s[0]:
            raise FitError(
                f"P12 axis {i + 1}: scale factor and angles are not identifiable: the reference field "
                f"does not "
                f"vary independently along B1..B{i + 1}; add field directions"
            )
        coef = (vt.T @ ((u.T @ (ds.h_nt[:, i : i + 1] * sw)) / s[:, None]))[:, 0] / scale
        inv = (vt.T / s**2) @ vt / np.outer(scale, scale)
        residuals[:, i] = ds.h_nt[:, i] - x @ coef
        sigma2[i] = np.sum(w * residuals[:, i] ** 2) / (n_used - (i + 2))
        m[i, : i + 1] = coef[:-1]
        b[i] = coef[-1]
        covs.append(inv)
    return m, b, covs, residuals, sigma2


def _k_angles(m: np.ndarray) -> np.ndarray:
    """(k1, k2, k3, e1, e2, e3 in deg) of the physical decomposition of a lower-triangular M."""
    k = np.linalg.norm(m, axis=1) * np.sign(np.diag(m))
    return np.concatenate([k, p12_angles_from_rows(m / k[:, None])])


def fit_weighted(ds: Dataset, weights: np.ndarray | None):
    """(Calibration, raw-axis residuals (N,3)) of a weighted P12 fit."""
    m, b, covs, residuals, sigma2 = _row_fits(ds, weights)
    if np.any(np.diag(m) <= 0):
        axis = int(np.flatnonzero(np.diag(m) <= 0)[0]) + 1
        raise FitError(
            f"P12 axis {axis}: the fitted scale factor is not positive (reversed axis or wrong reference)"
        )
    values = _k_angles(m)
    # propagate each row's covariance through (row of M) -> (k, angles) by central differences
    var = np.zeros(6)
    var_b = np.zeros(3)
    for i in range(3):
        idx = list(range(i + 1))
        jac = np.zeros((6, i + 1))
        for j in idx:
            step = 1e-7 * max(abs(m[i, j]), np.linalg.norm(m[i]))
            mp, mm = m.copy(), m.copy()
            mp[i, j] += step
            mm[i, j] -= step
            jac[:, j] = (_k_angles(mp) - _k_angles(mm)) / (2 * step)
        cov_row = sigma2[i] * covs[i][: i + 1, : i + 1]
        var += np.einsum("pj,jk,pk->p", jac, cov_row, jac)
        var_b[i] = sigma2[i] * covs[i][-1, -1]
    se = np.sqrt(var)
    cal = Calibration(
        model="p12",
        params={"k": values[:3], "angles_deg": values[3:], "h0_nt": b},
        std_errors={"k": se[:3], "angles_deg": se[3:], "h0_nt": np.sqrt(var_b)},
        stats={"sigma_raw_nt": {a: float(np.sqrt(s)) for a, s in zip("xyz", sigma2, strict=True)}},
        source={"kind": "dataset"},
    )
    return cal, residuals


def penalty(ds: Dataset, k: np.ndarray, angles_deg: np.ndarray, h0_nt: np.ndarray) -> float:
    """Sum of squared raw-axis residuals sum_l |h - Q P B - h0|^2."""
    r = ds.h_nt - ds.ref_nt @ p12_matrix(k, angles_deg).T - h0_nt
    return float(np.sum(r**2))


def stationary_points(ds: Dataset) -> list[dict]:
    """The four stationary points: signs (s2, s3) of rows 2 and 3, each with its penalty.

    All four give the same matrix Q P and the same penalty (the least-squares minimum); only the one
    with k > 0 and angles within +-90 deg describes a real sensor, and that is the one `fit` returns.
    """
    m, b, _, _, _ = _row_fits(ds, None)
    norms = np.linalg.norm(m, axis=1)
    points = []
    for s2 in (1, -1):
        for s3 in (1, -1):
            k = np.array([m[0, 0], s2 * norms[1], s3 * norms[2]])
            p = m / k[:, None]
            e1 = np.degrees(np.arctan2(p[1, 0], p[1, 1]))
            e3 = np.degrees(np.arcsin(np.clip(p[2, 1], -1, 1)))
            e2 = np.degrees(np.arctan2(p[2, 0], p[2, 2]))
            angles = np.array([e1, e2, e3])
            points.append(
                {
                    "signs": (s2, s3),
                    "k": k,
                    "angles_deg": angles,
                    "h0_nt": b.copy(),
                    "penalty": penalty(ds, k, angles, b),
                    "physical": bool(np.all(k > 0) and np.all(np.abs(angles) < 90)),
                }
            )
    return points
