"""Does T24's linearity in temperature hold? The model check the interior temperatures of a plan are for.

    check = linearity(h_nt, temp_c, ref_nt)   # {"testable", "holds", "quadratic_nt", "chi2", "p", "message"}

T24 is B = (S + tau K) h + b + tau kb: linear in tau. Its next term is quadratic, (tau - tm)^2 (Q h + q),
with tm the middle of the range. Both models are fitted by least squares to the same rows, per axis
(calib/checks/nested.py); the drop in the residual sum of squares, over the noise the larger model leaves, is
chi-square distributed with 4 degrees of freedom per axis when T24 holds (12 for the three axes, for large
N; the p-value takes it as F(12, 3(N - 12)), which stays honest on small data). A p-value below P_WARN
says the curvature is real; `quadratic_nt` says how large it is: the largest change the quadratic term
makes over the range, at the median field. Data at two temperatures only cannot tell a curve from a line:
the check then says it is not testable and asks for interior temperatures. calib/checks/model_checks.py puts
this check beside the others in their common shape, with the practical threshold of its verdict.
"""

from __future__ import annotations

import math

import numpy as np

from calib.checks.nested import MIN_CURVATURE_SHARE, NestedTest, curvature_share, nested_test, t24_design
from calib.errors import DataError
from calib.stats.residuals import temperature_steps

P_WARN = 1e-3
TEMPS_NEEDED = 3  # distinct temperatures for a curve to show
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
    return linearity_with_test(h_nt, temp_c, ref_nt)[0]


def linearity_with_test(h_nt, temp_c, ref_nt) -> tuple[dict, NestedTest | None]:
    """(linearity's result, the nested test behind it, None when not testable)."""
    h = np.asarray(h_nt, float).reshape(-1, 3)
    temp = np.asarray(temp_c, float).ravel()
    ref = np.asarray(ref_nt, float).reshape(-1, 3)
    if not (len(h) == len(temp) == len(ref)):
        raise DataError(f"linearity: {len(h)} readings, {len(temp)} temperatures, {len(ref)} references")
    lo, hi = (float(temp.min()), float(temp.max())) if len(temp) else (0.0, 0.0)
    if len(h) < 8 + N_EXTRA + 10 or hi - lo < 0.5:
        return _not_testable(), None
    base, s, u = t24_design(h, temp)
    if curvature_share(s) < MIN_CURVATURE_SHARE:
        return _not_testable(), None
    extra = (s * s)[:, None] * np.column_stack([np.ones(len(s)), u])
    test = nested_test(base, extra, ref)
    grid = np.linspace(-1, 1, 21)
    worst = 0.0
    for d in (*np.eye(3), *-np.eye(3)):  # the quadratic term's effect along each axis direction, median field
        x = (grid * grid)[:, None] * np.concatenate([[1.0], d])[None, :]
        worst = max(worst, float(np.abs(x @ test.extra_coef).max()))
    holds = test.p >= P_WARN
    steps = int(temperature_steps(temp)[1].size)
    out = {"testable": True, "holds": holds, "quadratic_nt": worst, "chi2": test.statistic, "dof": test.dof,
           "p": test.p, "range_c": [lo, hi], "temperatures": steps, "sigma_nt": test.noise}
    out["message"] = (f"T24's linearity in temperature {'holds' if holds else 'does not hold'}: a quadratic "
                      f"term would change the field by up to {worst:.2f} nT over {lo:.1f} .. {hi:.1f} degC "
                      f"(chi2 {test.statistic:.1f} on {test.dof} dof, p {test.p:.2g})")
    return out, test


def _not_testable() -> dict:
    return {"testable": False, "holds": None,
            "message": f"T24's linearity in temperature not tested: it needs samples at {TEMPS_NEEDED} or "
                       "more temperatures, interior ones included"}
