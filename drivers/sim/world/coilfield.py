"""The simulated coil set's true field at any point: numerical Biot-Savart over its loops.

An implementation of its own, apart from the rig's closed forms (rig/fieldsources/coils/geometry.py), so
that a mistake in either shows as a disagreement: each loop is integrated numerically (Gauss-Legendre
nodes along every side of a square, the trapezoidal rule around a circle, both converging far faster
than the accuracy needed here).

A real coil pair differs from its drawing: its constant is off by a scale factor and its axis is tilted.
The simulated pair j is the drawn pair scaled by k_j and turned by the smallest rotation R_j that takes
axis j to the direction of the true matrix's column j: B_j(r) = k_j R_j b_j(R_j^T r), so that at the
centre it gives exactly `coil_constants_nt_per_a[:, j]` per ampere.

Each loop of a pair may also differ from its drawing on its own (LoopErrors: turns, centre offset, tilt
of its normal); the pair is then integrated loop by loop, and the pair-level truth still holds on top:
the deviated pair is scaled and turned (the smallest rotation taking its own centre field to column j)
so that the centre matrix stays exactly `coil_constants_nt_per_a`, which is what a commissioning at the
centre measures. The loop errors shape the field away from the centre (hardware-notes §9.2: a turns
imbalance gives a gradient along the axis, a shifted or tilted loop a transverse field).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MU0 = 4e-7 * math.pi
GAUSS_NODES = 64  # per side of a square loop
CIRCLE_NODES = 4096


@dataclass(frozen=True)
class CoilGeometry:
    shape: str  # "square" (size = side) or "circular" (size = diameter)
    size_m: tuple[float, float, float]
    spacing_m: tuple[float, float, float]


def _loop_path(shape: str, axis: int, offset_m: float, size_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature points on one loop and their weighted line elements dl (right-handed about +axis)."""
    u, v = (axis + 1) % 3, (axis + 2) % 3
    if shape == "circular":
        theta = np.arange(CIRCLE_NODES) * (2 * math.pi / CIRCLE_NODES)
        radius = size_m / 2
        pts = np.zeros((CIRCLE_NODES, 3))
        dl = np.zeros((CIRCLE_NODES, 3))
        pts[:, axis] = offset_m
        pts[:, u], pts[:, v] = radius * np.cos(theta), radius * np.sin(theta)
        step = 2 * math.pi / CIRCLE_NODES
        dl[:, u], dl[:, v] = -radius * np.sin(theta) * step, radius * np.cos(theta) * step
        return pts, dl
    nodes, weights = np.polynomial.legendre.leggauss(GAUSS_NODES)
    half = size_m / 2
    corners = [(half, -half), (half, half), (-half, half), (-half, -half)]
    all_pts, all_dl = [], []
    for k in range(4):
        a, b = np.zeros(3), np.zeros(3)
        a[axis] = b[axis] = offset_m
        (a[u], a[v]), (b[u], b[v]) = corners[k], corners[(k + 1) % 4]
        s = 0.5 * (nodes + 1.0)
        all_pts.append(a + np.outer(s, b - a))
        all_dl.append(np.outer(0.5 * weights, b - a))
    return np.vstack(all_pts), np.vstack(all_dl)


@dataclass(frozen=True)
class LoopErrors:
    """How the two loops of one axis's pair differ from the drawing: loop 0 is the one on the + side of
    the centre, loop 1 the one on the - side. A tilt turns the loop about its own centre, about the next
    lab axis in cyclic order (x loops about y, y loops about z, z loops about x), right-handed."""

    turns_error_ppm: tuple[float, float] = (0.0, 0.0)
    offset_m: tuple[tuple[float, float, float], tuple[float, float, float]] = ((0.0, 0.0, 0.0),) * 2
    tilt_deg: tuple[float, float] = (0.0, 0.0)

    def is_zero(self) -> bool:
        return not (any(self.turns_error_ppm) or np.any(self.offset_m) or any(self.tilt_deg))


def _axis_rotation(axis: int, angle_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    u, v = (axis + 1) % 3, (axis + 2) % 3
    rot = np.eye(3)
    rot[v, v], rot[v, u], rot[u, v], rot[u, u] = c, s, -s, c
    return rot


def _loop_field(pts: np.ndarray, dl: np.ndarray, point_m: np.ndarray) -> np.ndarray:
    r = point_m - pts
    d3 = np.linalg.norm(r, axis=1) ** 3
    return MU0 / (4 * math.pi) * np.sum(np.cross(dl, r) / d3[:, None], axis=0)


def drawn_pair_field(geometry: CoilGeometry, axis: int, point_m: np.ndarray,
                     errors: LoopErrors | None = None) -> np.ndarray:
    """Field (T) of 1 A in the pair of `axis` at one point: the drawn pair, or its loops as `errors` say."""
    total = np.zeros(3)
    for k, offset in enumerate((geometry.spacing_m[axis] / 2, -geometry.spacing_m[axis] / 2)):
        pts, dl = _loop_path(geometry.shape, axis, offset, geometry.size_m[axis])
        if errors is None:
            total += _loop_field(pts, dl, point_m)
            continue
        centre = np.zeros(3)
        centre[axis] = offset
        tilt = _axis_rotation((axis + 1) % 3, errors.tilt_deg[k])
        pts = centre + (pts - centre) @ tilt.T + np.asarray(errors.offset_m[k], float)
        turns = 1.0 + errors.turns_error_ppm[k] * 1e-6
        total += turns * _loop_field(pts, dl @ tilt.T, point_m)
    return total


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a to unit vector b (Rodrigues)."""
    v = np.cross(a, b)
    c = float(a @ b)
    s = float(np.linalg.norm(v))
    if s < 1e-15:
        return np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    angle = math.atan2(s, c)
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def coil_matrix_at(constants_nt_per_a: np.ndarray, geometry: CoilGeometry | None,
                   position_m, loops: dict[int, LoopErrors] | None = None) -> np.ndarray:
    """The true coil matrix (nT/A) at `position_m`: every pair its field (drawn, or loop by loop as
    `loops` says by axis), scaled and turned to match the true centre matrix (module docstring). Without a
    geometry the field is uniform."""
    m = np.asarray(constants_nt_per_a, float)
    if geometry is None:
        return m.copy()
    p = np.asarray(position_m, float)
    out = np.empty((3, 3))
    for j in range(3):
        errors = None if loops is None or loops.get(j) is None or loops[j].is_zero() else loops[j]
        centre = drawn_pair_field(geometry, j, np.zeros(3), errors)
        if errors is None:
            along = np.zeros(3)
            along[j] = 1.0  # the drawn pair's centre field, exactly
        else:
            along = centre / np.linalg.norm(centre)
        rot = _rotation_between(along, m[:, j] / np.linalg.norm(m[:, j]))
        scale = np.linalg.norm(m[:, j]) / np.linalg.norm(centre)
        out[:, j] = scale * (rot @ drawn_pair_field(geometry, j, rot.T @ p, errors))
    return out
