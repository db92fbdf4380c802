"""What a coil commissioning measured beyond the matrix, as the budget's input quantities: the coils'
non-linearity, their hysteresis, the matrix's drift between the repeats, and the current source's
read-back error. Each is fitted from the settings the commissioning file records (every setting's
commanded currents, the reference's mean reading and, in files that have them, the read-back currents),
with its covariance; an effect the rig does not correct enters the budget as u^2 + b^2 (its estimate b
as a bias of unknown sign, its standard uncertainty u: GUM F.2.4.5), so a real effect is covered by its
size and one that is only noise by its noise.

    fit = fit_readback(settings)                 # commissioning: read-back against commanded currents
    terms = nonlinearity(settings)               # (estimate (3,6), covariance (18,18), absorbed (4,6))
    h, cov = hysteresis(settings)                # (3 coils x 3 axes) field step between up and down
    excess = repeat_drift(settings, repeats)     # (9,) variance of the matrix between repeats beyond noise
"""

from __future__ import annotations

import numpy as np

from calib.errors import FitError

MIN_SETTINGS = 12
RCOND_SINGULAR = 1e-10


def _arrays(settings) -> tuple[np.ndarray, np.ndarray]:
    currents = np.array([s.setting for s in settings], float).reshape(-1, 3)
    readings = np.array([s.mean_nt for s in settings], float).reshape(-1, 3)
    return currents, readings


def _fit(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(coefficients (p,k), covariance per output column (k,p,p)) of y on x: least squares by SVD with the
    columns scaled; FitError when the settings do not separate the terms."""
    scale = np.linalg.norm(x, axis=0)
    if np.any(scale == 0):
        raise FitError("a term is zero at every setting")
    u, s, vt = np.linalg.svd(x / scale, full_matrices=False)
    if s[-1] < RCOND_SINGULAR * s[0]:
        raise FitError("the settings do not separate the terms")
    coef = (vt.T @ ((u.T @ y) / s[:, None])) / scale[:, None]
    inv = (vt.T / s**2) @ vt / np.outer(scale, scale)
    dof = max(len(x) - x.shape[1], 1)
    sigma2 = np.sum((y - x @ coef) ** 2, axis=0) / dof
    return coef, sigma2[:, None, None] * inv[None]


def _bias_covariance(estimate: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """u^2 + b^2 for an uncorrected estimate b with covariance u^2: cov + b b^T."""
    return cov + np.outer(estimate, estimate)


def fit_readback(settings) -> dict | None:
    """Per coil, the read-back currents against the commanded ones, I_rb = (1 + g) I + o: g in ppm, o in
    mA, with their standard errors; None when there are no read-backs (or too few settings). `settings`:
    anything with `setting` and `readback` (the commissioning's readings, or its file's settings)."""
    if len(settings) < MIN_SETTINGS or any(getattr(s, "readback", None) is None for s in settings):
        return None
    commanded = np.array([s.setting for s in settings], float).reshape(-1, 3)
    readback = np.array([s.readback for s in settings], float).reshape(-1, 3)
    gain, offset, se_gain, se_offset = [], [], [], []
    for j in range(3):
        x = np.column_stack([commanded[:, j], np.ones(len(commanded))])
        try:
            coef, cov = _fit(x, readback[:, j:j + 1])
        except FitError:
            return None
        gain.append(1e6 * float(coef[0, 0] - 1.0))
        offset.append(1e3 * float(coef[1, 0]))
        se_gain.append(1e6 * float(np.sqrt(cov[0, 0, 0])))
        se_offset.append(1e3 * float(np.sqrt(cov[0, 1, 1])))
    return {"gain_ppm": gain, "offset_ma": offset, "std_errors_gain_ppm": se_gain,
            "std_errors_offset_ma": se_offset}


def readback_covariance(readback: dict) -> np.ndarray:
    """(6,6) over (gain ppm x 3, offset mA x 3): the measured error, uncorrected, as u^2 + b^2."""
    estimate = np.concatenate([readback["gain_ppm"], readback["offset_ma"]])
    se = np.concatenate([readback["std_errors_gain_ppm"], readback["std_errors_offset_ma"]])
    return np.diag(se**2 + estimate**2)


def nonlinearity(settings) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(c (3 axes, 6), Sigma (18,18), absorbed (4,6)): the quadratic and cubic terms of every coil
    [I_x^2, I_y^2, I_z^2, I_x^3, I_y^3, I_z^3] per output axis, fitted with the linear model; their
    covariance as u^2 + b^2 per axis (index axis * 6 + term); and the part of each term the linear fit of
    the commissioning absorbed ([I, 1] coefficients): a field error z(I) - [I, 1] absorbed at current I."""
    if len(settings) < MIN_SETTINGS:
        return None
    currents, readings = _arrays(settings)
    z = np.column_stack([currents**2, currents**3])
    x_lin = np.column_stack([currents, np.ones(len(currents))])
    try:
        coef, cov = _fit(np.column_stack([x_lin, z]), readings)
        absorbed = np.linalg.lstsq(x_lin, z, rcond=None)[0]
    except (FitError, np.linalg.LinAlgError):
        return None
    c = coef[4:].T  # (3 axes, 6 terms)
    sigma = np.zeros((18, 18))
    for i in range(3):
        block = slice(6 * i, 6 * i + 6)
        sigma[block, block] = _bias_covariance(c[i], cov[i][4:, 4:])
    return c, sigma, absorbed


def nonlinearity_sensitivity(currents_a: np.ndarray, absorbed: np.ndarray) -> np.ndarray:
    """(N,3,18): the reference error per unit of each term (index axis * 6 + term) at the run's currents."""
    z = np.column_stack([currents_a**2, currents_a**3])
    w = z - np.column_stack([currents_a, np.ones(len(currents_a))]) @ absorbed  # (N,6)
    out = np.zeros((len(currents_a), 3, 18))
    for i in range(3):
        out[:, i, 6 * i:6 * i + 6] = w
    return out


def directions(currents_a: np.ndarray) -> np.ndarray:
    """(K,3): the sign of each coil's last current change into every setting (0: unchanged; the coils
    start at 0 A)."""
    before = np.vstack([np.zeros((1, 3)), currents_a[:-1]])
    change = currents_a - before
    return np.where(np.abs(change) > 1e-6, np.sign(change), 0.0)


def hysteresis(settings) -> tuple[np.ndarray, np.ndarray] | None:
    """(h (3 coils, 3 axes), Sigma (9,9)): the field step between a setting approached with a rising and
    with a falling current in coil j, fitted as r = M I + a + sum_j s_j h_j / 2 (s_j the direction of
    coil j's last change); Sigma over index j * 3 + axis as u^2 + b^2 per axis."""
    if len(settings) < MIN_SETTINGS:
        return None
    currents, readings = _arrays(settings)
    s = directions(currents)
    x = np.column_stack([currents, 0.5 * s, np.ones(len(currents))])
    try:
        coef, cov = _fit(x, readings)
    except FitError:
        return None
    h = coef[3:6]  # (coil j, axis i)
    sigma = np.zeros((9, 9))
    for i in range(3):
        idx = [3 * j + i for j in range(3)]
        sigma[np.ix_(idx, idx)] = _bias_covariance(h[:, i], cov[i][3:6, 3:6])
    return h, sigma


def hysteresis_sensitivity(directions_run: np.ndarray) -> np.ndarray:
    """(N,3,9): the reference error per unit of h_j's component i: s_j / 2 on axis i."""
    out = np.zeros((len(directions_run), 3, 9))
    for j in range(3):
        for i in range(3):
            out[:, i, 3 * j + i] = 0.5 * directions_run[:, j]
    return out


def repeat_drift(settings, repeats: int) -> np.ndarray | None:
    """(9,): per matrix element (row-major), the variance of the matrix between the commissioning's
    repeats beyond what their noise explains (0 where none); None with fewer than two repeats."""
    if repeats < 2 or len(settings) < repeats * MIN_SETTINGS or len(settings) % repeats:
        return None
    currents, readings = _arrays(settings)
    size = len(settings) // repeats
    estimates, noise = [], []
    for r in range(repeats):
        rows = slice(r * size, (r + 1) * size)
        try:
            coef, cov = _fit(np.column_stack([currents[rows], np.ones(size)]), readings[rows])
        except FitError:
            return None
        estimates.append(coef[:3].T.ravel())  # M[i][j] = coef[j, i]
        noise.append(np.array([cov[i][j, j] for i in range(3) for j in range(3)]))
    between = np.var(np.array(estimates), axis=0, ddof=1)
    return np.maximum(between - np.mean(noise, axis=0), 0.0)
