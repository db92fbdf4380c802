"""The misfit: a fit's residual beyond what the DUT's own noise explains, as a line of its budget
(rig/budget/modelerror.py says where it stands among the others).

    noise, dof = within_point_noise(resid, points)      # the scatter within points
    source = misfit_source(resid, w, dof, points, notes, ref)

The noise is the scatter within points (the samples of one point see the same field and temperature);
the excess, when significant (MISFIT_SIGNIFICANCE standard errors of the variance ratio), is a field
error at every grid point that no parameter carries. Where part of the residual is an affine function of
the field (a model without some linear term: P12 has no rotation) and the data's directions are
unbalanced (a turntable's), that part is larger at the directions the data did not visit: the misfit
takes its size over every direction. With one sample a point the noise cannot be told from the misfit: a
note says so.
"""

from __future__ import annotations

import numpy as np

from calib.uncertainty.propagation import InputSource

MISFIT_SIGNIFICANCE = 3.0
AFFINE_SIGNIFICANCE = 3.0  # standard errors beyond the affine part the noise alone would give


def within_point_noise(residuals: np.ndarray, points) -> tuple[np.ndarray, int]:
    """(per axis RMS scatter of the residuals within points, its degrees of freedom)."""
    labels, index = np.unique(np.asarray(points, object).astype(str), return_inverse=True)
    counts = np.bincount(index, minlength=len(labels))
    means = np.stack([np.bincount(index, residuals[:, i], len(labels)) for i in range(residuals.shape[1])],
                     axis=1) / np.maximum(counts, 1)[:, None]
    dof = int(np.sum(np.maximum(counts - 1, 0)))
    if dof == 0:
        return np.full(residuals.shape[1], np.nan), 0
    return np.sqrt(np.sum((residuals - means[index]) ** 2, axis=0) / dof), dof


def directional_part(resid, ref, w, points=None) -> tuple[np.ndarray, np.ndarray] | None:
    """The residual's part that is an affine function of the field (per axis: c . B / |B|rms + c0), as
    a model without some linear term leaves it (P12 has no rotation), when it is beyond what the noise
    gives by chance (AFFINE_SIGNIFICANCE standard errors; counted in points, whose samples share their
    errors): (its mean square over the data, its mean square over every direction at the data's RMS
    magnitude, |c|^2 / 3 + c0^2). Over unbalanced directions (a turntable's) the second is the larger: the
    model's error at the directions the data did not visit. None: not significant, or no field."""
    used = w > 0
    if ref is None or resid.shape[1] != 3 or used.sum() < 8:
        return None
    ref_used = np.asarray(ref, float)[used]
    size = float(np.sqrt(np.mean(np.sum(ref_used**2, axis=1))))
    if size == 0:
        return None
    x = np.column_stack([ref_used / size, np.ones(len(ref_used))]) * np.sqrt(w[used])[:, None]
    r = resid[used] * np.sqrt(w[used])[:, None]
    coef = np.linalg.lstsq(x, r, rcond=None)[0]  # (4,3)
    n = len(np.unique(np.asarray(points, object)[used].astype(str))) if points is not None else len(r)
    total = np.sum(r**2, axis=0) / np.sum(w[used])
    in_data = np.sum((x @ coef) ** 2, axis=0) / np.sum(w[used])
    chance = (4 + AFFINE_SIGNIFICANCE * np.sqrt(8.0)) * total / max(n, 1)
    if not np.any(in_data > chance):
        return None
    everywhere_ms = np.sum(coef[:3] ** 2, axis=0) / 3 + coef[3] ** 2
    significant = in_data > chance
    return np.where(significant, in_data, 0.0), np.where(significant, everywhere_ms, 0.0)


def misfit_source(resid, w, dof, points, notes, ref=None) -> InputSource | None:
    used = w > 0
    rms2 = np.sum(w[used, None] * resid[used] ** 2, axis=0) / max(dof, 1)
    if points is None:
        notes.append("misfit: the samples carry no point labels; the DUT's noise cannot be told from it")
        return None
    noise, noise_dof = within_point_noise(resid[used], np.asarray(points, object)[used])
    if noise_dof == 0:
        notes.append("misfit: one sample a point, the DUT's noise cannot be told from the misfit: not in the "
                     "budget (take two or more samples a point)")
        return None
    limit = 1.0 + MISFIT_SIGNIFICANCE * np.sqrt(2.0 / max(dof, 1) + 2.0 / noise_dof)
    excess2 = np.where(rms2 > limit * noise**2, rms2 - noise**2, 0.0)
    excess2 = np.broadcast_to(excess2, (3,)) if excess2.size == 1 else excess2
    rms = np.sqrt(np.broadcast_to(rms2, (3,)))
    noise3 = np.broadcast_to(noise, (3,))
    origin = (f"residual rms ({_fmt(rms)}) nT against the noise within points ({_fmt(noise3)}) nT: excess "
              f"({_fmt(np.sqrt(excess2))}) nT")
    directional = directional_part(resid, ref, w, points)
    if directional is not None and np.any(directional[1] > directional[0]):
        in_data, anywhere = directional
        excess2 = excess2 + np.maximum(anywhere - in_data, 0.0)
        origin += (f"; of the residual, an affine function of the field's direction "
                   f"({_fmt(np.sqrt(in_data))}) nT grows to ({_fmt(np.sqrt(anywhere))}) nT over every "
                   f"direction (the data's are not balanced): excess taken ({_fmt(np.sqrt(excess2))}) nT")
    excess = np.sqrt(excess2)
    return InputSource("misfit", np.diag(excess**2), field_nt=everywhere, origin=origin)


def everywhere(grid_h, grid_temp) -> np.ndarray:
    """(G,3,3): a field error of its own on each axis at every grid point."""
    return np.broadcast_to(np.eye(3), (len(grid_h), 3, 3))


def _fmt(values) -> str:
    return ", ".join(f"{v:.1f}" for v in values)
