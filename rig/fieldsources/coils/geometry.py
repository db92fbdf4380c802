"""The field of a three-axis coil set off its centre, from its geometry (Biot-Savart, closed forms).

Each axis i has a pair of identical loops centred on the axis i, in planes at +-spacing_i/2, carrying the
same current in the same sense (right-handed about +i, so the field at the centre points along +i):
- square loops of side size_i, sides parallel to the other two axes: each side is a finite straight
  wire, whose field has a closed form (Hanson & Hirshman's expression in the end-point vectors);
- circular loops of diameter size_i: the closed form in the complete elliptic integrals K(m), E(m),
  computed here by the arithmetic-geometric mean (no scipy).

    g = geometry_matrix(shape, size_m, spacing_m, position_m)    # column j: field (T) per ampere of pair j
    m = coil_matrix_at(centre_matrix, shape, size_m, spacing_m, positions_m)   # (N,3,3), nT/A
    CoilGeometry(shape=..., size_m=..., spacing_m=...)    # the station's `geometry:`, the same in mm

The geometry only gives the SHAPE of each pair's field. `coil_matrix_at` scales and turns it to match a
coil matrix measured at the centre (commissioned or declared): pair j's measured column says how far its
constant is off (k_j) and where its axis points; the pair is taken as the drawn pair scaled by k_j and
turned by the smallest rotation R_j from axis j to that direction, B_j(r) = k_j R_j g_j(R_j^T r). Exact
at the centre; off the centre a tilted pair's field pattern is tilted with it (at 70 mm in a 0.4 m set,
0.3 deg of tilt moves the pattern by some 0.4 mm, worth 10-20 nT at 50 uT).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from rig.core.configbase import Strict
from rig.core.errors import LimitError
from rig.core.numbers import bounded
from rig.core.yamlload import blamed

MU0 = 4e-7 * math.pi  # T m / A
TESLA_TO_NT = 1e9
AGM_TOLERANCE = 1e-15
LENGTH_M = bounded(gt=0, hi=100.0)


def _segment_field(start: np.ndarray, end: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Field (T) of 1 A along the straight wire start -> end at points (N,3).

    With Ri = p - start, Rf = p - end (lengths ri, rf): B = mu0/(4 pi) (ri + rf) (Ri x Rf) /
    (ri rf (ri rf + Ri.Rf)). Singular only on the wire itself (outside any coil set's volume)."""
    ri_vec = points - start
    rf_vec = points - end
    ri = np.linalg.norm(ri_vec, axis=1)
    rf = np.linalg.norm(rf_vec, axis=1)
    denom = ri * rf * (ri * rf + np.einsum("ij,ij->i", ri_vec, rf_vec))
    return (MU0 / (4 * math.pi)) * ((ri + rf) / denom)[:, None] * np.cross(ri_vec, rf_vec)


def _square_loop_field(axis: int, offset_m: float, side_m: float, points: np.ndarray) -> np.ndarray:
    """1 A around a square of side `side_m` in the plane x_axis = offset_m, right-handed about +axis."""
    u, v = (axis + 1) % 3, (axis + 2) % 3  # (u, v, axis) is a right-handed triple
    half = side_m / 2
    corners = []
    for cu, cv in ((half, -half), (half, half), (-half, half), (-half, -half)):  # counter-clockwise
        c = np.zeros(3)
        c[axis], c[u], c[v] = offset_m, cu, cv
        corners.append(c)
    return sum(_segment_field(corners[k], corners[(k + 1) % 4], points) for k in range(4))


def elliptic_ke(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Complete elliptic integrals K(m), E(m) (parameter m = k^2, 0 <= m < 1) by the AGM."""
    m = np.asarray(m, float)
    a = np.ones_like(m)
    b = np.sqrt(1.0 - m)
    c = np.sqrt(m)
    total = 0.5 * c**2
    power = 0.5
    while np.max(np.abs(c)) > AGM_TOLERANCE:
        a, b, c = 0.5 * (a + b), np.sqrt(a * b), 0.5 * (a - b)
        power *= 2.0
        total = total + power * c**2
    k = math.pi / (2.0 * a)
    return k, k * (1.0 - total)


def _circular_loop_field(axis: int, offset_m: float, diameter_m: float, points: np.ndarray) -> np.ndarray:
    """1 A around a circle of `diameter_m` in the plane x_axis = offset_m, centred on the axis."""
    a = diameter_m / 2
    z = points[:, axis] - offset_m
    radial = points.copy()
    radial[:, axis] = 0.0
    rho = np.linalg.norm(radial, axis=1)
    alpha2 = (a - rho) ** 2 + z**2
    beta2 = (a + rho) ** 2 + z**2
    k_int, e_int = elliptic_ke(4 * a * rho / beta2)
    beta = np.sqrt(beta2)
    c = MU0 / (2 * math.pi)
    b_axial = c / beta * (k_int + (a**2 - rho**2 - z**2) / alpha2 * e_int)
    with np.errstate(invalid="ignore", divide="ignore"):
        b_rho = np.where(rho > 1e-12 * a,
                         c * z / (rho * beta) * (-k_int + (a**2 + rho**2 + z**2) / alpha2 * e_int), 0.0)
        unit = np.where(rho[:, None] > 0, radial / np.where(rho > 0, rho, 1.0)[:, None], 0.0)
    out = b_rho[:, None] * unit
    out[:, axis] += b_axial
    return out


LOOPS = {"square": _square_loop_field, "circular": _circular_loop_field}


def pair_field(shape: str, axis: int, size_m: float, spacing_m: float, points_m) -> np.ndarray:
    """Field (T, (N,3)) of 1 A in both loops of the axis-`axis` pair, at points (N,3) in metres."""
    points = np.atleast_2d(np.asarray(points_m, float))
    loop = LOOPS[shape]
    return loop(axis, spacing_m / 2, size_m, points) + loop(axis, -spacing_m / 2, size_m, points)


def geometry_matrix(shape: str, size_m, spacing_m, position_m) -> np.ndarray:
    """3x3: column j is the field (T) of 1 A in coil pair j at `position_m`."""
    p = np.asarray(position_m, float).reshape(1, 3)
    return np.column_stack([pair_field(shape, j, size_m[j], spacing_m[j], p)[0] for j in range(3)])


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a to unit vector b (Rodrigues' formula)."""
    v = np.cross(a, b)
    s = float(np.linalg.norm(v))
    if s < 1e-15:
        return np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    angle = math.atan2(s, float(a @ b))
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def coil_matrix_at(centre_matrix_nt_per_a, shape: str, size_m, spacing_m, positions_m) -> np.ndarray:
    """(N,3,3) coil matrices (nT/A) at positions (N,3) in metres, of the pairs whose centre matrix is
    `centre_matrix_nt_per_a` (module docstring)."""
    m = np.asarray(centre_matrix_nt_per_a, float)
    points = np.atleast_2d(np.asarray(positions_m, float))
    out = np.empty((len(points), 3, 3))
    for j in range(3):
        axis = np.eye(3)[j]
        centre = pair_field(shape, j, size_m[j], spacing_m[j], np.zeros((1, 3)))[0]
        column = m[:, j]
        rot = rotation_between(axis, column / np.linalg.norm(column))
        scale = np.linalg.norm(column) / np.linalg.norm(centre)
        out[:, :, j] = scale * (pair_field(shape, j, size_m[j], spacing_m[j], points @ rot) @ rot.T)
    return out


def shape_factor(shape: str, size_m, spacing_m, position_m) -> np.ndarray:
    """G(0)^-1 G(r): how the field of each coil at `position_m` differs from its field at the centre,
    in the coils' own terms (the identity at the centre)."""
    g0 = geometry_matrix(shape, size_m, spacing_m, np.zeros(3))
    return np.linalg.solve(g0, geometry_matrix(shape, size_m, spacing_m, position_m))


def nonuniformity(shape: str, size_m, spacing_m, position_m) -> float:
    """The largest relative deviation of the field at `position_m` from the field at the centre, over
    every field direction the coils can make (spectral norm of G(0)^-1 G(r) - I)."""
    return float(np.linalg.norm(shape_factor(shape, size_m, spacing_m, position_m) - np.eye(3), 2))


def inside(shape: str, size_m, spacing_m, position_m) -> bool:
    """Whether a point lies within the volume the three pairs enclose: between each pair's planes and
    within every loop's outline (a square's sides, a circle's radius)."""
    p = np.abs(np.asarray(position_m, float))
    for axis in range(3):
        across = np.delete(p, axis)
        half = size_m[axis] / 2
        outside = np.hypot(*across) >= half if shape == "circular" else np.max(across) >= half
        if p[axis] >= spacing_m[axis] / 2 or outside:
            return False
    return True


class CoilGeometry(Strict):
    """The drawn coil set: per axis, a pair of square loops of side size_m (or circular ones of diameter
    size_m), in planes spacing_m apart, centred on that axis."""

    shape: Literal["square", "circular"]
    size_m: tuple[LENGTH_M, LENGTH_M, LENGTH_M]
    spacing_m: tuple[LENGTH_M, LENGTH_M, LENGTH_M]

    def matrices_at(self, centre_matrix, positions_mm) -> np.ndarray:
        """(N,3,3) coil matrices at positions (N,3) in mm, matching `centre_matrix` at the centre."""
        points = np.asarray(positions_mm, float).reshape(-1, 3) / 1000.0
        return coil_matrix_at(centre_matrix, self.shape, self.size_m, self.spacing_m, points)

    def nonuniformity_ppm(self, position_mm) -> float:
        point_m = np.asarray(position_mm, float) / 1000.0
        return 1e6 * nonuniformity(self.shape, self.size_m, self.spacing_m, point_m)

    def encloses(self, position_mm) -> bool:
        return inside(self.shape, self.size_m, self.spacing_m, np.asarray(position_mm) / 1000.0)


def nonuniformity_lines(geometry, station, plan) -> list[str]:
    """`rig check`'s line on the coil field's non-uniformity at each DUT (the largest relative difference
    from the centre's field over every direction the coils make); LimitError, blamed on the station's
    position_mm, where it exceeds the plan's accuracy_ppm. The rig corrects for it (each DUT's reference is
    the field where it sits); what the geometry, the position and their tolerances leave uncertain is in
    every calibration's budget."""
    figures = [(i, d, geometry.nonuniformity_ppm(d.position_mm or (0.0, 0.0, 0.0)))
               for i, d in enumerate(station.duts)]
    target = plan.accuracy_ppm
    for i, d, ppm in figures:
        if target is not None and ppm > target:
            what = (f"the coil field at {d.name} differs from the centre's by {ppm:.0f} ppm, more than the "
                    f"plan's accuracy_ppm {target:g}: move it towards the centre")
            raise blamed(LimitError(f"station {station.name}: duts[{i}].position_mm: {what}"),
                         ("duts", i, "position_mm"), what, document="station")
    return ["coil field non-uniformity at the DUTs (corrected; ppm of the field): "
            + ", ".join(f"{d.name} {ppm:.0f}" for _, d, ppm in figures)]
