"""Does T24's linearity in temperature hold? The model check the interior temperatures of a plan are for.

    check = linearity(h_nt, temp_c, ref_nt)   # {"testable", "holds", "quadratic_nt", "chi2", "p", "message"}

T24 is B = (S + tau K) h + b + tau kb: linear in tau. Its next term is quadratic, (tau - tm)^2 (Q h + q),
with tm the middle of the range. Both models are fitted by least squares to the same rows, per axis; the
drop in the residual sum of squares, over the noise the larger model leaves, is chi-square distributed
with 4 degrees of freedom per axis when T24 holds (12 for the three axes, for large N). A p-value below
P_WARN says the curvature is real; `quadratic_nt` says how large it is: the largest change the quadratic
term makes over the range, at the median field. Data at two temperatures only cannot tell a curve from a
line: the check then says it is not testable and asks for interior temperatures.
"""

from __future__ import annotations

import math

import numpy as np

from calib.errors import DataError

P_WARN = 1e-3
TEMPS_NEEDED = 3  # distinct temperatures (0.5 degC apart) for a curve to show
N_EXTRA = 4  # per axis: (tau - tm)^2 [1, h1, h2, h3]


def chi2_sf_even(x: float, dof: int) -> float:
    """P(chi2 > x) for an even number of degrees of freedom (closed form)."""
    half = 0.5 * x
    term, total = 1.0, 1.0
    for k in range(1, dof // 2):
        term *= half / k
        total += term
    return min(1.0, math.exp(-half) * total)


def linearity(h_nt, temp_c, ref_nt) -> dict:
    h = np.asarray(h_nt, float).reshape(-1, 3)
    temp = np.asarray(temp_c, float).ravel()
    ref = np.asarray(ref_nt, float).reshape(-1, 3)
    if not (len(h) == len(temp) == len(ref)):
        raise DataError(f"linearity: {len(h)} readings, {len(temp)} temperatures, {len(ref)} references")
    lo, hi = (float(temp.min()), float(temp.max())) if len(temp) else (0.0, 0.0)
    distinct = np.unique(np.round(temp / 0.5)).size if len(temp) else 0
    if distinct < TEMPS_NEEDED or len(h) < 8 + N_EXTRA + 10:
        return {"testable": False, "holds": None,
                "message": f"T24's linearity in temperature not tested: it needs samples at {TEMPS_NEEDED}"
                " or more temperatures, interior ones included"}
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    s = (temp - mid) / half  # -1 .. 1
    h_scale = float(np.median(np.linalg.norm(h, axis=1))) or 1.0
    u = h / h_scale
    base = np.column_stack([np.ones(len(s)), s, u, s[:, None] * u])
    extra = (s * s)[:, None] * np.column_stack([np.ones(len(s)), u])
    full = np.column_stack([base, extra])
    rss0 = _rss(base, ref)
    beta, rss1 = _fit(full, ref)
    dof_resid = len(s) - full.shape[1]
    sigma2 = np.maximum(rss1 / dof_resid, 1e-300)
    chi2 = float(np.sum((rss0 - rss1) / sigma2))
    dof = 3 * N_EXTRA
    p = chi2_sf_even(chi2, dof)
    grid = np.linspace(-1, 1, 21)
    unit = np.eye(3)
    worst = 0.0
    for d in (*unit, *-unit):  # the quadratic term's effect along each axis direction, at the median field
        x = (grid * grid)[:, None] * np.concatenate([[1.0], d])[None, :]
        worst = max(worst, float(np.abs(x @ beta[base.shape[1]:]).max()))
    holds = p >= P_WARN
    out = {"testable": True, "holds": holds, "quadratic_nt": worst, "chi2": chi2, "dof": dof, "p": p,
           "range_c": [lo, hi], "temperatures": int(distinct)}
    out["message"] = (f"T24's linearity in temperature {'holds' if holds else 'does not hold'}: a quadratic "
                      f"term would change the field by up to {worst:.2f} nT over {lo:.1f} .. {hi:.1f} degC "
                      f"(chi2 {chi2:.1f} on {dof} dof, p {p:.2g})")
    return out


def _fit(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares per output column, columns scaled: (coefficients, residual sum of squares per column)."""
    scale = np.sqrt(np.mean(x * x, axis=0))
    scale[scale == 0] = 1.0
    coef, *_ = np.linalg.lstsq(x / scale, y, rcond=None)
    coef = coef / scale[:, None]
    r = y - x @ coef
    return coef, np.sum(r * r, axis=0)


def _rss(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return _fit(x, y)[1]
