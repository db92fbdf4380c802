"""Attitude-independent (scalar) calibration: |A (h - c)| = |B| when only the field magnitude is known.

A is upper-triangular (the calibrated field is in a sensor-aligned frame: the true frame up to one
rotation). Optional linear temperature terms: A(t) = A + t KA, c(t) = c + t kc, t = T - temp_ref_c.

Initial guess: the algebraic ellipsoid fit (linear least squares on the quadric h'Wh - 2u'h + e = |B|^2
with W = A'A), done on centred and scaled readings. Refinement: Levenberg-Marquardt on the field-domain
residuals |A(h - c)| - |B|, with analytic Jacobian and column scaling. No scipy. Optionally samples are
weighted by inverse direction density (orientation balancing, for hand-held recordings that dwell on some
orientations); whether to balance and whether to fit temperature terms is chosen by validation
(calib/models/scalar_choice.py).
"""

from __future__ import annotations

import numpy as np

from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.errors import DataError, FitError
from calib.stats.residuals import default_temp_ref_c, known_norm

MIN_TEMP_SPAN_C = 0.5
UPPER = np.triu_indices(3)  # the 6 free entries of an upper-triangular matrix
MAX_ITER = 200
RCOND_SINGULAR = 1e-13
MIN_DENSITY_SHARE = 0.1  # density floor, as a share of uniform coverage: caps balance weights at 10x
UNEVEN_COVERAGE_SHARE = 0.8  # balancing is a candidate when its weights leave fewer effective samples
# ...and only from this many samples on: a 20 degree cone then expects >= 20 of them under uniform
# coverage, so sampling noise alone does not make the coverage look uneven
MIN_SAMPLES_TO_BALANCE = 700
BALANCE_CHUNK = 128  # samples per pass of the direction-density count
# The starting ellipsoid takes |B| as constant (its mean) when it spreads by less than this share: fitted to a
# nearly constant |B|, the quadric's scale would follow the reference's jitter, not the readings (a zero
# quadric and a constant fit it best). Levenberg-Marquardt then fits each sample's own |B|.
NORM_SPREAD_CONSTANT = 0.01


def field_norm(ds: Dataset, field_norm_nt: float | None) -> tuple[np.ndarray, str]:
    if field_norm_nt is not None:
        if not field_norm_nt > 0:
            raise DataError(f"field norm must be positive, got {field_norm_nt} nT")
        return np.full(len(ds), float(field_norm_nt)), f"given constant {field_norm_nt:g} nT"
    norm = known_norm(ds)
    if norm is not None:
        return norm, "per-sample reference"
    # unknown constant magnitude: output scaled to the raw readings' mean radius about their centre
    radius = float(np.sqrt(np.mean(np.sum((ds.h_nt - ds.h_nt.mean(axis=0)) ** 2, axis=1))))
    return np.full(len(ds), radius), f"unknown; scaled to the raw mean radius {radius:.6g} nT"


def _constant_norm(fn_nt: np.ndarray) -> dict:
    return {"field_norm_nt": float(fn_nt[0])} if np.ptp(fn_nt) == 0 else {}


def _algebraic(hn: np.ndarray, fn: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ellipsoid through scaled readings hn with known scaled norms fn: returns (A upper, c), the start of
    the least-squares fit. Norms that spread are fitted as such (the quadric = |B|^2), and the quadric
    through the points, scaled to their mean |B|^2, too: the one whose norms are nearer the known ones
    starts the fit (readings near a sphere whose norms spread a little, by a percent or two: the first's
    constant trades with its scale, and its matrix comes out indefinite or far off)."""
    if np.ptp(fn) <= NORM_SPREAD_CONSTANT * np.max(fn):
        return _quadric(hn, fn, w, through_points=True)
    starts = []
    for through_points in (False, True):
        try:
            a, c = _quadric(hn, fn, w, through_points)
        except FitError:
            continue
        misfit = np.average((np.linalg.norm((hn - c) @ a.T, axis=1) - fn) ** 2, weights=w)
        starts.append((misfit, through_points, a, c))
    if not starts:
        raise FitError(_coverage_message())
    return min(starts, key=lambda s: s[:2])[2:]  # the start nearer the norms


def _quadric(hn: np.ndarray, fn: np.ndarray, w: np.ndarray, through_points: bool
             ) -> tuple[np.ndarray, np.ndarray]:
    x, y, z = hn.T
    quad = np.column_stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, -2 * x, -2 * y, -2 * z])
    sw = np.sqrt(w)[:, None]
    d = np.column_stack([quad, np.ones(len(hn))]) * sw
    if through_points:
        # homogeneous: the quadric through the points, its scale fixed afterwards by the known norm
        v = np.linalg.svd(d, full_matrices=False)[2][-1]
    else:
        v = np.linalg.lstsq(d, (fn**2)[:, None] * sw, rcond=None)[0][:, 0]
    wm = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    if np.trace(wm) < 0:
        wm, v = -wm, -v
    try:
        c = np.linalg.solve(wm, v[6:9])
    except np.linalg.LinAlgError:
        raise FitError(_coverage_message()) from None
    if through_points:
        denom = c @ wm @ c - v[9]
        if denom <= 0:
            raise FitError(_coverage_message())
        wm = wm * (np.average(fn**2, weights=w) / denom)
    try:
        a = np.linalg.cholesky(wm).T  # W = A'A, A upper-triangular with positive diagonal
    except np.linalg.LinAlgError:
        raise FitError(_coverage_message()) from None
    return a, c


def _coverage_message() -> str:
    return (
        "scalar: the readings do not outline an ellipsoid (matrix A and offset c are not identifiable); "
        "rotate the sensor through more orientations"
    )


def _unpack(theta: np.ndarray, temp: bool):
    a = np.zeros((3, 3))
    a[UPPER] = theta[:6]
    c = theta[6:9]
    if not temp:
        return a, c, None, None
    ka = np.zeros((3, 3))
    ka[UPPER] = theta[9:15]
    return a, c, ka, theta[15:18]


def _times(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """x @ m for x (N,3), m (3,3), column by column: numpy's matmul with an inner size of 3 is several
    times slower on long arrays (the same products and sums, in the same order)."""
    out = np.empty((len(x), 3))
    for j in range(3):
        out[:, j] = x[:, 0] * m[0, j] + x[:, 1] * m[1, j] + x[:, 2] * m[2, j]
    return out


def _residuals_jacobian(theta, hn, fn, t, temp: bool):
    """(residuals |y| - |B| (N,), their Jacobian (N,9|18): d/d A's upper entries, c [, KA, kc])."""
    a, c, ka, kc = _unpack(theta, temp)
    v = hn - c if not temp else hn - c - t[:, None] * kc
    y = _times(v, a.T) if not temp else _times(v, a.T) + t[:, None] * _times(v, ka.T)
    norm = np.sqrt(y[:, 0] * y[:, 0] + y[:, 1] * y[:, 1] + y[:, 2] * y[:, 2])
    u = y / norm[:, None]
    r = norm - fn
    jac = np.empty((len(hn), 18 if temp else 9))
    for k, (i, j) in enumerate(zip(*UPPER, strict=True)):
        np.multiply(u[:, i], v[:, j], out=jac[:, k])
    if not temp:
        jac[:, 6:9] = -_times(u, a)
        return r, jac
    am_u = _times(u, a) + t[:, None] * _times(u, ka)
    jac[:, 6:9] = -am_u
    jac[:, 9:15] = t[:, None] * jac[:, :6]
    jac[:, 15:18] = -t[:, None] * am_u
    return r, jac


def _levenberg_marquardt(theta, hn, fn, t, w, temp: bool):
    r, jac = _residuals_jacobian(theta, hn, fn, t, temp)
    cost = np.sum(w * r**2)
    mu = 1e-3
    for _ in range(MAX_ITER):
        jtj = jac.T @ (jac * w[:, None])
        grad = jac.T @ (w * r)
        scale = np.sqrt(np.maximum(np.diag(jtj), np.finfo(float).tiny))
        jtj_s = jtj / np.outer(scale, scale)
        improved = False
        while mu < 1e10:
            step = -np.linalg.solve(jtj_s + mu * np.eye(len(theta)), grad / scale) / scale
            r_new, jac_new = _residuals_jacobian(theta + step, hn, fn, t, temp)
            cost_new = np.sum(w * r_new**2)
            if cost_new <= cost:
                improved = True
                break
            mu *= 10
        if not improved:
            break
        theta = theta + step
        small = cost - cost_new <= 1e-14 * cost
        r, jac, cost = r_new, jac_new, cost_new
        mu = max(mu / 10, 1e-12)
        if small:
            break
    return theta, r, jac


def orientation_balance_weights(
    field_nt: np.ndarray, angle_deg: float = 20.0, max_reference: int = 4000
) -> np.ndarray:
    """Weights ~ 1 / (share of samples within angle_deg of each sample's direction), mean 1.

    Hand-held recordings dwell on some orientations; balancing keeps those from dominating the fit, so
    the calibration holds better on orientations it saw less. Density is counted against at most
    `max_reference` evenly spaced samples, so the cost stays linear in N. A count below a tenth of what
    uniform coverage would give is raised to that tenth: a few samples alone in their cone (often ones
    caught mid-motion) get at most 10x the weight they would have on a uniformly covered sphere.
    """
    u = field_nt / np.linalg.norm(field_nt, axis=1, keepdims=True)
    ref = u[:: max(1, len(u) // max_reference)]
    ref = ref[np.argsort(ref[:, 2])]
    cos_limit = np.cos(np.radians(angle_deg))
    # two directions within angle_deg differ by at most their chord in z: a block of samples sorted by z
    # is compared with the band of references its z range allows, not with all of them
    chord = 2 * np.sin(np.radians(angle_deg) / 2)
    order = np.argsort(u[:, 2])
    counts = np.empty(len(u), np.int64)
    for lo in range(0, len(u), BALANCE_CHUNK):
        rows = order[lo : lo + BALANCE_CHUNK]
        z = u[rows, 2]
        first, last = np.searchsorted(ref[:, 2], [z[0] - chord, z[-1] + chord], side="left")
        band = ref[first : last + 1]
        counts[rows] = np.count_nonzero(u[rows] @ band.T > cos_limit, axis=1)
    uniform_count = len(ref) * (1 - cos_limit) / 2  # cone area / sphere area
    w = 1.0 / np.maximum(counts, max(1.0, MIN_DENSITY_SHARE * uniform_count))
    return w * (len(w) / w.sum())


def effective_share(weights: np.ndarray) -> float:
    """Kish effective sample size over N: 1 for equal weights, lower the more uneven they are."""
    return float(weights.sum() ** 2 / (len(weights) * np.sum(weights**2)))


def fit_weighted(
    ds: Dataset,
    weights: np.ndarray | None,
    *,
    temp_ref_c: float | None = None,
    field_norm_nt: float | None = None,
    temperature_terms: bool = False,
    balance: np.ndarray | None = None,
):
    """(Calibration, |B| residuals (N,)) of a weighted scalar fit of one variant.

    field_norm_nt: one known |B| for every sample; else ref_norm_nt, else |ref_nt|, else unknown (the
    output is then scaled to the raw readings' mean radius). temperature_terms: fit KA and kc.
    balance: orientation balance weights (`orientation_balance_weights`) multiplied into `weights`.
    calib.fit decides the options a caller leaves open (calib.models.scalar_choice).
    """
    if balance is not None:
        weights = balance if weights is None else np.asarray(weights, float) * balance
    cal, residuals = _fit(ds, weights, temp_ref_c=temp_ref_c, field_norm_nt=field_norm_nt,
                          temperature_terms=temperature_terms)
    cal.stats["balance_orientations"] = balance is not None
    return cal, residuals


def _fit(
    ds: Dataset,
    weights: np.ndarray | None,
    *,
    temp_ref_c: float | None,
    field_norm_nt: float | None,
    temperature_terms: bool,
):
    n = len(ds)
    w = np.ones(n) if weights is None else np.asarray(weights, float)
    fn_nt, norm_source = field_norm(ds, field_norm_nt)
    span = 0.0 if ds.temp_c is None else float(np.ptp(ds.temp_c[w > 0]))
    temp = temperature_terms
    if temp and span < MIN_TEMP_SPAN_C:
        raise FitError(
            f"scalar: temperature span {span:.2f} degC: "
            "the temperature terms KA and kc are not identifiable; "
            "add a temperature step or fit without temperature terms"
        )
    n_params = 18 if temp else 9
    if np.count_nonzero(w) <= n_params:
        raise FitError(f"scalar: {np.count_nonzero(w)} samples, more than {n_params} needed")
    if temp:
        ref_c = default_temp_ref_c(ds.temp_c) if temp_ref_c is None else temp_ref_c
        t = ds.temp_c - ref_c
    else:
        ref_c, t = None, np.zeros(n)
    # centre and scale so the quadric's columns are of similar size
    centre = np.average(ds.h_nt, axis=0, weights=w)
    size = float(np.sqrt(np.average(np.sum((ds.h_nt - centre) ** 2, axis=1), weights=w)))
    hn, fn = (ds.h_nt - centre) / size, fn_nt / size
    a0, c0 = _algebraic(hn, fn, w)
    theta = np.concatenate([a0[UPPER], c0] + ([np.zeros(9)] if temp else []))
    theta, r, jac = _levenberg_marquardt(theta, hn, fn, t, w, temp)
    jtj = jac.T @ (jac * w[:, None])
    scale = np.sqrt(np.diag(jtj))
    eig, vec = np.linalg.eigh(jtj / np.outer(scale, scale))
    if eig[0] < RCOND_SINGULAR * eig[-1]:
        if temp and np.sum(vec[9:, 0] ** 2) > 0.5:
            raise FitError(
                "scalar: the temperature terms KA and kc are not identifiable from these samples; "
                "add orientations at each temperature step or fit without temperature terms"
            )
        raise FitError(_coverage_message())
    cov = (vec / eig) @ vec.T / np.outer(scale, scale)
    sigma2 = float(np.sum(w * r**2) / (np.count_nonzero(w) - n_params))
    se = np.sqrt(np.diag(cov) * sigma2)
    a, c, ka, kc = _unpack(theta, temp)
    se_a, se_c, se_ka, se_kc = _unpack(se, temp)
    params = {"A": a, "c_nt": centre + size * c}
    std_errors = {"A": se_a, "c_nt": size * se_c}
    if temp:
        params.update({"KA_per_c": ka, "kc_nt_per_c": size * kc})
        std_errors.update({"KA_per_c": se_ka, "kc_nt_per_c": size * se_kc})
    cal = Calibration(
        model="scalar",
        params=params,
        std_errors=std_errors,
        temp_ref_c=ref_c,
        stats={
            "field_norm": norm_source,
            **_constant_norm(fn_nt),
            "balance_orientations": False,
            "sigma_nt": float(np.sqrt(sigma2) * size),
            "temperature_terms": temp,
        },
        source={"kind": "dataset"},
    )
    return cal, r * size
