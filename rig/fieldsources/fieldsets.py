"""Sets of field directions (coils) and table orientations (turntable) that a plan sweeps.

- cube24: the 24 rotations of the cube (`cube_rotations()`), applied to the reference direction
  (3, 2, 1)/sqrt(14). That direction lies on no symmetry axis, so its 24 images are distinct: half of
  the 48 signed permutations of (3, 2, 1), three in every octant. At any one temperature they span every
  axis, which the T24 model needs at more than one temperature.
- fibonacci: N nearly uniform directions on the sphere (golden-angle spiral), deterministic.
- explicit directions (normalised here) or explicit vectors in nT.
- turntable: a grid of az x el, or an explicit list of (az, el) pairs.

Everything is deterministic: the same plan always gives the same list in the same order.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

CUBE24_REFERENCE = np.array([3.0, 2.0, 1.0]) / math.sqrt(14.0)


def cube_rotations() -> list[np.ndarray]:
    """The 24 proper rotations of the cube: signed permutation matrices with determinant +1, in a fixed
    order (permutations in lexicographic order, then sign patterns)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            for row, col in enumerate(perm):
                m[row, col] = signs[row]
            if np.linalg.det(m) > 0:
                out.append(m)
    return out


def cube24_directions(reference: np.ndarray = CUBE24_REFERENCE) -> np.ndarray:
    """(24, 3) unit vectors: every cube rotation applied to `reference`."""
    ref = np.asarray(reference, float) / np.linalg.norm(reference)
    return np.array([r @ ref for r in cube_rotations()])


def normalised(directions) -> np.ndarray:
    d = np.asarray(directions, float).reshape(-1, 3)
    norms = np.linalg.norm(d, axis=1)
    if np.any(norms == 0):
        raise ValueError("a direction is the zero vector")
    return d / norms[:, None]


def scaled(directions: np.ndarray, magnitudes_nt: list[float]) -> np.ndarray:
    """Each magnitude in turn, all directions at that magnitude."""
    return np.vstack([directions * m for m in magnitudes_nt])


def grid_orientations(az_deg: list[float], el_deg: list[float]) -> list[tuple[float, float]]:
    """Every azimuth at each elevation, elevation-major (one tilt, then a full turn)."""
    return [(float(a), float(e)) for e in el_deg for a in az_deg]


def span_ratio(vectors_nt: np.ndarray) -> float:
    """Smallest over largest singular value of the matrix of unit directions: 0 when all field vectors
    lie in one plane, 1 for directions spread evenly over the sphere."""
    d = normalised(vectors_nt)
    s = np.linalg.svd(d, compute_uv=False)
    return float(s[-1] / s[0]) if s[0] > 0 else 0.0
