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
    differences about the drawn loops (order: axis, loop, quantity)."""
    point = np.asarray(position_mm, float) / 1000.0
    out = np.empty((3, 2, PER_LOOP, 3, 3))
    for index in np.ndindex(3, 2, PER_LOOP):
        step = np.zeros((3, 2, PER_LOOP))
        step[index] = STEPS[index[2]]
        up = matrix_with_loops(centre_matrix_nt_per_a, geometry.shape, geometry.size_m, geometry.spacing_m,
                               point, step)
        down = matrix_with_loops(centre_matrix_nt_per_a, geometry.shape, geometry.size_m, geometry.spacing_m,
                                 point, -step)
        out[index] = (up - down) / (2 * STEPS[index[2]])
    return out.reshape(-1, 3, 3)
