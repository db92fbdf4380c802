"""The nested-model test every model check makes: does a model with extra terms fit significantly better?

    test = nested_test(base, extra, y)    # base (N,p) shared by the axes; extra (N,q) or (3,N,q); y (N,3)

Each output axis i is fitted by least squares twice, on the base regressors and on the base plus the extra
ones (columns scaled to unit norm before the solve). The drop of the residual sum of squares over the
noise the larger model leaves on that axis, summed over the axes, is chi-square with 3q degrees of
freedom when the extra terms are zero (large N); dividing it by 3q gives a statistic close to
F(3q, 3(N - p - q)), whose tail is the p-value (exact for equal noise on the axes, and it keeps the test
honest on small data, where the noise estimate itself scatters). The larger model's extra coefficients
and per-axis noise come with it, so a check can state the effect's size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.equations import t24_regressors
from calib.stats.distributions import f_sf

# below this curvature share (`curvature_share`) the data have fewer than three distinct temperatures: about
# (2 x jitter / half span)^2 for two steps, 2/9 for three equal steps at the ends and the middle
MIN_CURVATURE_SHARE = 1e-4


@dataclass(frozen=True)
class NestedTest:
    statistic: float  # sum over the axes of the residual drop over the axis' noise (chi-square like)
    dof: int  # 3 q
    dof_residual: int  # 3 (N - p - q)
    p: float
    extra_coef: np.ndarray  # (q, 3): the extra terms' coefficients per output axis, in y per extra unit
    sigma: np.ndarray  # (3,): the larger model's residual noise per axis

    @property
    def noise(self) -> float:
        """The residual noise pooled over the axes (RMS of the three)."""
        return float(np.sqrt(np.mean(self.sigma**2)))


def lstsq_scaled(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(coefficients, residual sum of squares per column of y): least squares with x's columns scaled."""
    scale = np.linalg.norm(x, axis=0)
    scale[scale == 0] = 1.0
    coef = np.linalg.lstsq(x / scale, y, rcond=None)[0] / scale[:, None]
    r = y - x @ coef
    return coef, np.sum(r * r, axis=0)


def nested_test(base: np.ndarray, extra: np.ndarray, y: np.ndarray) -> NestedTest:
    n, p = base.shape
    per_axis = extra.ndim == 3
    q = extra.shape[-1]
    _, rss0 = lstsq_scaled(base, y)
    if per_axis:
        coefs, rss1 = [], np.empty(3)
        for i in range(3):
            c, r = lstsq_scaled(np.column_stack([base, extra[i]]), y[:, i:i + 1])
            coefs.append(c[p:, 0])
            rss1[i] = r[0]
        extra_coef = np.column_stack(coefs)
    else:
        c, rss1 = lstsq_scaled(np.column_stack([base, extra]), y)
        extra_coef = c[p:]
    dof_resid = n - p - q
    sigma2 = np.maximum(rss1 / dof_resid, np.finfo(float).tiny)
    statistic = float(np.sum(np.maximum(rss0 - rss1, 0.0) / sigma2))
    return NestedTest(statistic, 3 * q, 3 * dof_resid, f_sf(statistic / (3 * q), 3 * q, 3 * dof_resid),
                      extra_coef, np.sqrt(sigma2))


def t24_design(h_nt: np.ndarray, temp_c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T24's regressors [1, s, u, s u], s, u): s the temperature scaled to -1..1 over its range, u the
    reading over its median length, so the columns are of similar size."""
    lo, hi = float(np.min(temp_c)), float(np.max(temp_c))
    half = 0.5 * (hi - lo) or 1.0
    s = (np.asarray(temp_c, float) - 0.5 * (lo + hi)) / half
    u = h_nt / (float(np.median(np.linalg.norm(h_nt, axis=1))) or 1.0)
    return t24_regressors(u, s), s, u


def curvature_share(s: np.ndarray) -> float:
    """The residual mean square of s^2 regressed on [1, s] (s = -1..1 over the range): zero for two
    temperatures, 2/9 for three equal steps at the ends and the middle, 4/45 for a uniform ramp."""
    if len(s) < 3:
        return 0.0
    _, rss = lstsq_scaled(np.column_stack([np.ones(len(s)), s]), (s * s)[:, None])
    return float(rss[0] / len(s))
