"""Each coil loop off its drawing, measured: the 30 loop quantities (rig/fieldsources/coils/loops.py) fitted
to the coil matrices a reference magnetometer measured at several places (`rig commission --position`).

At the centre the loops do not show (the pairs are scaled and turned to the centre's matrix); at a place
r_k off the centre the matrix M(r_k) = f(M0, q, r_k) depends on them. With the loops' tolerances as what
is known before (each quantity q_i within +-t_i, rectangular: standard deviation t_i / sqrt 3), the fit is
the Gauss-Newton solution of the measured matrices and that prior together, in units of the prior's
standard deviations (centred at the drawing and scaled):

    minimise  |W (y - f(z))|^2 + |z|^2,   q = s z,   W^T W = C^-1

with C the measured matrices' covariance: their commissioning's, plus the centre matrix's (shared by every
place, M0 enters every f) and the reference's place, off by up to its `position_tolerance_mm` the same way
at every place (one sensor in one holder). Its covariance (J^T C^-1 J + I)^-1 is what the budget's
"coil loops" line then states; a quantity whose standard deviation the places leave above half its prior
one is not identified by them (some never are: both loops' turns together only scale the pair, which the
centre matrix already fixes), and `unidentified` names them.

    fit = fit_loops(centre, centre_cov, geometry, places, reference_tolerance_mm)
    fit.deviations (3, 2, PER_LOOP); fit.covariance (30, 30); fit.unidentified ["x+ turns", ...]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.fieldsources.coils.loops import PER_LOOP, loop_sensitivity, matrix_with_loops

QUANTITIES = ("shift x mm", "shift y mm", "shift z mm", "tilt deg", "turns ppm")
N_LOOP = 3 * 2 * PER_LOOP
IDENTIFIED = 0.5  # a quantity is identified when the places take its standard deviation below this share
ITERATIONS = 6
POSITION_STEP_MM = 0.5


def quantity_names() -> list[str]:
    """The 30 loop quantities in loops.py's order: axis, loop (+ side, - side), quantity."""
    return [f"{'xyz'[j]}{'+-'[k]} {q}" for j in range(3) for k in range(2) for q in QUANTITIES]


def prior_sd(geometry) -> np.ndarray:
    """(30,): each loop quantity's standard deviation from the station's tolerances (rectangular)."""
    half = np.array([geometry.tolerance_mm] * 3 + [geometry.tilt_tolerance_deg, geometry.turns_tolerance_ppm])
    return np.tile(half, 6) / np.sqrt(3.0)


@dataclass(frozen=True)
class Place:
    position_mm: np.ndarray  # where the reference was put (stated)
    matrix_nt_per_a: np.ndarray  # (3,3) as measured there
    covariance: np.ndarray  # (9,9) of the matrix, row-major


@dataclass(frozen=True)
class LoopFit:
    deviations: np.ndarray  # (3, 2, PER_LOOP)
    covariance: np.ndarray  # (30, 30)
    reference_offset_mm: np.ndarray  # (3,): the reference's place off its stated one, fitted alongside
    remaining: np.ndarray  # (30,): posterior / prior standard deviation of each quantity
    chi2: float  # the measured matrices' weighted residual
    dof: int

    @property
    def unidentified(self) -> list[str]:
        names = quantity_names()
        return [names[i] for i in np.flatnonzero(self.remaining > IDENTIFIED)]

    @property
    def std_errors(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))


def _model(centre, geometry, positions_mm, q: np.ndarray, offset_mm: np.ndarray) -> np.ndarray:
    """(9K,): the matrices at every place for loop quantities q (30,) and the reference's offset."""
    deviations = q.reshape(3, 2, PER_LOOP)
    return np.concatenate([
        matrix_with_loops(centre, geometry.shape, geometry.size_m, geometry.spacing_m,
                          (np.asarray(p, float) + offset_mm) / 1000.0, deviations).ravel()
        for p in positions_mm])


def _jacobian(centre, geometry, positions_mm) -> np.ndarray:
    """(9K, 33): d(matrices)/d(30 loop quantities, 3 offset mm) about the drawing (the map is linear to
    well within the fit's noise over the tolerances: loops.py's test)."""
    rows = []
    for p in positions_mm:
        by_loop = loop_sensitivity(centre, geometry, p).reshape(N_LOOP, 9).T
        moved = np.asarray(p, float) + np.concatenate([np.eye(3), -np.eye(3)]) * POSITION_STEP_MM
        m = geometry.matrices_at(centre, moved).reshape(6, 9)
        by_offset = ((m[:3] - m[3:]) / (2 * POSITION_STEP_MM)).T
        rows.append(np.hstack([by_loop, by_offset]))
    return np.vstack(rows)


def fit_loops(centre, centre_cov, geometry, places: list[Place],
              reference_tolerance_mm: float) -> LoopFit:
    """The loop quantities the matrices measured at `places` show, with their covariance (module doc)."""
    centre = np.asarray(centre, float)
    positions = [pl.position_mm for pl in places]
    y = np.concatenate([np.asarray(pl.matrix_nt_per_a, float).ravel() for pl in places])
    k = len(places)
    cov = np.zeros((9 * k, 9 * k))
    for i, pl in enumerate(places):
        cov[9 * i:9 * i + 9, 9 * i:9 * i + 9] = np.asarray(pl.covariance, float)
    shared = np.tile(np.eye(9), (k, 1))  # M0's error moves every place's matrix alike (to first order)
    cov += shared @ np.asarray(centre_cov, float) @ shared.T
    scale = np.concatenate([prior_sd(geometry), np.full(3, max(reference_tolerance_mm, 1e-6) / np.sqrt(3))])
    whiten = np.linalg.inv(np.linalg.cholesky(cov + 1e-12 * np.trace(cov) / len(cov) * np.eye(len(cov))))
    jw = whiten @ _jacobian(centre, geometry, positions) * scale  # scaled: z = p / scale
    normal = jw.T @ jw + np.eye(len(scale))
    z = np.zeros(len(scale))
    for _ in range(ITERATIONS):
        p = z * scale
        r = whiten @ (y - _model(centre, geometry, positions, p[:N_LOOP], p[N_LOOP:]))
        step = np.linalg.solve(normal, jw.T @ r - z)
        z = z + step
        if np.max(np.abs(step)) < 1e-6:
            break
    p = z * scale
    r = whiten @ (y - _model(centre, geometry, positions, p[:N_LOOP], p[N_LOOP:]))
    posterior = np.linalg.inv(normal)
    cov_p = posterior * np.outer(scale, scale)
    remaining = np.sqrt(np.diag(posterior))[:N_LOOP]
    return LoopFit(p[:N_LOOP].reshape(3, 2, PER_LOOP), cov_p[:N_LOOP, :N_LOOP], p[N_LOOP:], remaining,
                   float(r @ r), max(len(y) - int(np.sum(remaining < IDENTIFIED)), 1))
