"""The lab field's gradient over the coil set, from the ambient the reference magnetometer measured at the
centre and at each further place (`rig commission --position`, rig/commission/places.py), and the station's
other reference magnetometers at theirs (rig/commission/otherrefs.py).

Every ambient is a(r) = a0 + G r. In the coil set the lab field has no sources (no currents, no magnetised
material), so G is symmetric and traceless: five numbers g = (Gxx, Gyy, Gxy, Gxz, Gyz), Gzz = -Gxx - Gyy.
The station's stated bound (`field_source.ambient_gradient_nt_per_m`: +-bound on each component,
rectangular) is the prior, so that what the places leave unseen keeps it: two places on the x axis show
G's x column (Gxx, Gxy, Gxz) and nothing of Gyy or Gyz. The places' ambients, each with its own fit's
covariance, update it (least squares with the prior as a Gaussian of the same variance). The lab field
moves in the minutes between places: a scatter beyond the ambients' own errors (chi2 above its degrees of
freedom) widens their covariance by the ratio (Birge) before the fit is taken.

    fit = fit_gradient([((0, 0, 0), ambient, cov3), ((70, 0, 0), ambient, cov3), ...], bound_nt_per_m=300)
    fit.nt_per_m (3, 3), fit.covariance (5, 5: of g), fit.unidentified, fit.chi2, fit.dof

The field a measured gradient adds at an offset r (m) from where the ambient was measured is
by_position(r) @ g; a change of g moves it by the same map (the budget's "ambient gradient" line).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.fieldsources.ambientlines import by_position

NAMES = ("Gxx", "Gyy", "Gxy", "Gxz", "Gyz")
IDENTIFIED = 0.5  # a component is measured when the places take its standard deviation below this share
# of its prior's (as for the loops, rig/fieldsources/coils/loopfit.py)

# G's nine elements, row by row, from g
TO_ELEMENTS = np.array([
    [1, 0, 0, 0, 0], [0, 0, 1, 0, 0], [0, 0, 0, 1, 0],
    [0, 0, 1, 0, 0], [0, 1, 0, 0, 0], [0, 0, 0, 0, 1],
    [0, 0, 0, 1, 0], [0, 0, 0, 0, 1], [-1, -1, 0, 0, 0],
], float)


@dataclass
class GradientFit:
    nt_per_m: np.ndarray  # (3, 3)
    covariance: np.ndarray  # (5, 5): of g (NAMES)
    unidentified: list[str]  # components the places leave at their prior
    chi2: float  # of the ambients against the fitted field, after no widening
    dof: int
    places: int  # ambients fitted, the centre's included


def fit_gradient(ambients, bound_nt_per_m: float | None, differences=()) -> GradientFit | None:
    """`ambients`: [(position_mm, ambient_nt (3,), its covariance (3, 3))], the centre's among them;
    `differences`: [(offset_mm, difference_nt (3,), its covariance)], another reference's ambient less the
    first's, read together (G offset alone: the readings' common part, the first's ambient among it, is
    not counted twice). None where they cannot show a gradient: fewer than two places, or, with no stated
    bound to keep for what they leave unseen, places that do not show all five components."""
    if len(ambients) + len(differences) < 2:
        return None
    prior_u = None if bound_nt_per_m is None else bound_nt_per_m / np.sqrt(3.0)
    scale = np.full(5, 1.0 if prior_u is None else prior_u)  # g in units of its prior: a balanced system
    rows, values, weights = [], [], []
    for seen, observed in ((np.eye(3), ambients), (np.zeros((3, 3)), differences)):
        for position_mm, value, cov in observed:
            rows.append(np.hstack([seen, by_position(np.asarray(position_mm, float) / 1000.0) * scale]))
            values.append(np.asarray(value, float))
            weights.append(np.linalg.inv(np.asarray(cov, float)))

    def solve(widen: float):
        normal = sum(a.T @ w @ a for a, w in zip(rows, weights, strict=True)) / widen
        rhs = sum(a.T @ w @ v for a, w, v in zip(rows, weights, values, strict=True)) / widen
        if prior_u is not None:
            normal[3:, 3:] += np.eye(5)
        if np.linalg.cond(normal) > 1e12:
            return None
        cov = np.linalg.inv(normal)
        x = cov @ rhs
        misfits = [(v - a @ x, w) for a, w, v in zip(rows, weights, values, strict=True)]
        chi2 = float(sum(r @ w @ r for r, w in misfits))
        return x, cov, chi2

    first = solve(1.0)
    if first is None:
        return None
    x, cov, chi2 = first
    g_sd = np.sqrt(np.diag(cov)[3:])  # in units of the prior's
    unidentified = [] if prior_u is None else [
        name for name, sd in zip(NAMES, g_sd, strict=True) if sd >= IDENTIFIED]
    dof = 3 * len(rows) - int(np.linalg.matrix_rank(np.vstack(rows), tol=1e-9))  # what they can show
    if dof > 0 and chi2 > dof:
        x, cov, _ = solve(chi2 / dof)
    g, g_cov = x[3:] * scale, cov[3:, 3:] * np.outer(scale, scale)
    return GradientFit((TO_ELEMENTS @ g).reshape(3, 3), g_cov, unidentified, chi2, dof, len(rows))


def element_std_errors(covariance) -> np.ndarray:
    """(3, 3): the standard error of each of G's elements, from the covariance of g."""
    return np.sqrt(np.diag(TO_ELEMENTS @ np.asarray(covariance, float) @ TO_ELEMENTS.T)).reshape(3, 3)
