"""Each loop of a coil pair off its drawing, as the budget's "coil loops" line sees it (hardware-notes 9.2).

A pair's two loops are built to a tolerance: each may sit off its place (a shift of its centre, mm), lean
(a tilt of its normal about the next lab axis: x loops about y, y about z, z about x), and carry a few
turns more or fewer (ppm). At the centre none of this shows: commissioning measures the centre matrix, and
the pair is taken as its deviated self scaled and turned to match that matrix's column (as
rig/fieldsources/coils/geometry.py does for the ideal pair). Off the centre it shapes the field: a turns
imbalance gives a gradient along the axis, a shifted or tilted loop a transverse field, worth some
1e-4 of the field at 70 mm in a 0.4 m set.

    deviations = np.zeros((3, 2, 5))     # [axis, loop (+ side, - side), (dx, dy, dz mm, tilt deg, turns ppm)]
    m = matrix_with_loops(centre_matrix, "square", size_m, spacing_m, position_m, deviations)   # nT/A
"""

from __future__ import annotations

import math

import numpy as np

from rig.fieldsources.coils.geometry import LOOPS, rotation_between

PER_LOOP = 5  # offset x, y, z (mm), tilt (deg), turns (ppm)
STEPS = np.array([0.1, 0.1, 0.1, 0.01, 100.0])  # central-difference steps per quantity, in their units


def _tilt(axis: int, angle_deg: float) -> np.ndarray:
    """The rotation by angle_deg about lab axis `axis` (right-handed)."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    u, v = (axis + 1) % 3, (axis + 2) % 3
    rot = np.eye(3)
    rot[u, u], rot[u, v], rot[v, u], rot[v, v] = c, -s, s, c
    return rot


def deviated_pair_field(shape: str, axis: int, size_m: float, spacing_m: float, points_m: np.ndarray,
                        deviations: np.ndarray) -> np.ndarray:
    """Field (T, (N,3)) of 1 A in the pair of `axis` whose loops deviate as `deviations` (2, PER_LOOP)."""
    points = np.atleast_2d(np.asarray(points_m, float))
    loop = LOOPS[shape]
    total = np.zeros_like(points)
    for k, offset in enumerate((spacing_m / 2, -spacing_m / 2)):
        shift_m = deviations[k, :3] / 1000.0
        tilt = _tilt((axis + 1) % 3, deviations[k, 3])
        centre = np.zeros(3)
        centre[axis] = offset
        local = (points - shift_m - centre) @ tilt + centre  # tilt^T (p - shift - centre) + centre
        total += (1.0 + deviations[k, 4] * 1e-6) * (loop(axis, offset, size_m, local) @ tilt.T)
    return total


def matrix_with_loops(centre_matrix_nt_per_a, shape: str, size_m, spacing_m, position_m,
                      deviations: np.ndarray) -> np.ndarray:
    """The coil matrix (nT/A) at `position_m` of pairs whose loops deviate as `deviations` (3, 2,
    PER_LOOP), each pair scaled and turned so that the centre matrix stays `centre_matrix_nt_per_a`."""
    m = np.asarray(centre_matrix_nt_per_a, float)
    p = np.asarray(position_m, float).reshape(1, 3)
    out = np.empty((3, 3))
    for j in range(3):
        centre = deviated_pair_field(shape, j, size_m[j], spacing_m[j], np.zeros((1, 3)), deviations[j])[0]
        rot = rotation_between(centre / np.linalg.norm(centre), m[:, j] / np.linalg.norm(m[:, j]))
        scale = np.linalg.norm(m[:, j]) / np.linalg.norm(centre)
        field = deviated_pair_field(shape, j, size_m[j], spacing_m[j], p @ rot, deviations[j])[0]
        out[:, j] = scale * (rot @ field)
    return out


def loop_sensitivity(centre_matrix_nt_per_a, geometry, position_mm) -> np.ndarray:
    """(3 * 2 * PER_LOOP, 3, 3): d(matrix at the position)/d(each loop quantity, in its unit), by central
    differences about the drawn loops (order: axis, loop, quantity). Every deviated pair of an axis is
    evaluated in one call per loop (the points carried into each deviated loop's own frame)."""
    m = np.asarray(centre_matrix_nt_per_a, float)
    point = np.asarray(position_mm, float) / 1000.0
    loop = LOOPS[geometry.shape]
    out = np.zeros((3, 2, PER_LOOP, 3, 3))
    for j in range(3):
        steps = np.zeros((2 * 2 * PER_LOOP, 2, PER_LOOP))  # +step, -step of every quantity of both loops
        for n, (k, q) in enumerate(np.ndindex(2, PER_LOOP)):
            steps[2 * n, k, q], steps[2 * n + 1, k, q] = STEPS[q], -STEPS[q]
        column = _pair_columns(loop, j, geometry.size_m[j], geometry.spacing_m[j], steps, m[:, j], point)
        diff = (column[0::2] - column[1::2]) / (2 * np.tile(STEPS, 2))[:, None]  # (2 * PER_LOOP, 3)
        out[j, :, :, :, j] = diff.reshape(2, PER_LOOP, 3)
    return out.reshape(-1, 3, 3)


def _pair_columns(loop, axis: int, size_m: float, spacing_m: float, deviations: np.ndarray,
                  column: np.ndarray, point_m: np.ndarray) -> np.ndarray:
    """(D,3): column `axis` of the matrix at `point_m` for D deviated pairs (D, 2, PER_LOOP), each scaled and
    turned to match `column` at the centre (as matrix_with_loops)."""
    d = len(deviations)
    tilts = np.array([[_tilt((axis + 1) % 3, deviations[i, k, 3]) for k in range(2)] for i in range(d)])

    def field(points: np.ndarray) -> np.ndarray:  # points (D,3): the deviated pairs' fields (D,3), T/A
        total = np.zeros((d, 3))
        for k, offset in enumerate((spacing_m / 2, -spacing_m / 2)):
            centre = np.zeros(3)
            centre[axis] = offset
            shifted = points - deviations[:, k, :3] / 1000.0 - centre
            local = np.einsum("dj,dji->di", shifted, tilts[:, k]) + centre
            b = loop(axis, offset, size_m, local)
            total += (1.0 + deviations[:, k, 4] * 1e-6)[:, None] * np.einsum("dij,dj->di", tilts[:, k], b)
        return total

    at_centre = field(np.zeros((d, 3)))
    target = column / np.linalg.norm(column)
    rots = np.array([rotation_between(c / np.linalg.norm(c), target) for c in at_centre])
    scale = np.linalg.norm(column) / np.linalg.norm(at_centre, axis=1)
    moved = field(np.einsum("dji,j->di", rots, point_m))  # R^T r for every deviated pair
    return scale[:, None] * np.einsum("dij,dj->di", rots, moved)
