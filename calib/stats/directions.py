"""The field directions a calibration's data took, and how far other directions are from them.

A calibration holds among the directions its data took; away from them its parameters extrapolate, and
a fit without a reference direction (the scalar fit) has nothing there to hold them at all. A turntable
tilted at most 60 deg under a steep site field never shows the DUT the field from below.

    taken = taken_directions(ref_nt)            # (M,3) unit vectors, recorded in the calibration's stats
    spacing_deg(taken)                          # how far apart the taken directions are
    far, angles, apart = beyond_taken(taken, field_nt)   # the fields farther than that from all of them
    nearest_deg(taken, field_nt)                # (N,): each field's angle to the nearest taken direction
    reach_deg(taken)                            # the largest such angle over every direction
"""

from __future__ import annotations

import numpy as np

MAX_DIRECTIONS = 1000  # recorded at most: coarser rounding until they fit
MAX_ROWS = 100_000  # of a longer record, this many rows evenly spread over it
ROUNDINGS = (0.02, 0.05, 0.1, 0.2)  # of the unit vectors' components (about 1, 3, 6 and 11 deg)
SPHERE_DIRECTIONS = 6000  # the sphere's directions a reach is judged at (about 2.6 deg apart)
CHUNK = 500
ROW_CHUNK = 20_000
TWINS_DEG = 10.0  # directions nearer than this count as one for their spacing


def unit_vectors(vectors) -> np.ndarray:
    """(M,3): the non-zero vectors among `vectors`, scaled to unit length."""
    v = np.asarray(vectors, float).reshape(-1, 3)
    size = np.linalg.norm(v, axis=1)
    return v[size > 0] / size[size > 0, None]


def spread_rows(n: int) -> np.ndarray:
    """Indices of at most MAX_ROWS of n rows, evenly spread over them."""
    return np.arange(n) if n <= MAX_ROWS else np.linspace(0, n - 1, MAX_ROWS).astype(int)


def taken_directions(field_nt) -> np.ndarray:
    """(M,3): the distinct directions of the fields (rounded to the finest of ROUNDINGS that leaves at most
    MAX_DIRECTIONS), unit vectors; of a long record, MAX_ROWS rows evenly spread over it (a direction is
    held for many rows)."""
    field = np.asarray(field_nt, float).reshape(-1, 3)
    unit = unit_vectors(field[spread_rows(len(field))])
    for step in ROUNDINGS:
        cells = np.round(unit / step).astype(np.int64)  # each component within +-1/step
        half = int(np.ceil(1.0 / step))
        width = 2 * half + 1
        keys = ((cells[:, 0] + half) * width + cells[:, 1] + half) * width + cells[:, 2] + half
        first = np.unique(keys, return_index=True)[1]
        taken = unit_vectors(cells[first] * step)
        if len(taken) <= MAX_DIRECTIONS:
            break
    return taken


def nearest_deg(taken, field_nt) -> np.ndarray:
    """(N,): the angle of each field to the nearest taken direction (180 where none was taken; a zero
    field is 0: it has no direction to be far in)."""
    v = np.asarray(field_nt, float).reshape(-1, 3)
    size = np.linalg.norm(v, axis=1)
    unit = np.where(size[:, None] > 0, v / np.where(size > 0, size, 1.0)[:, None], 0.0)
    taken = np.asarray(taken, float).reshape(-1, 3)
    if not len(taken):
        return np.where(size > 0, 180.0, 0.0)
    best = np.full(len(unit), -1.0)
    for row in range(0, len(unit), ROW_CHUNK):  # a block of rows x of taken directions at a time
        rows = slice(row, row + ROW_CHUNK)
        for lo in range(0, len(taken), CHUNK):
            best[rows] = np.maximum(best[rows], (unit[rows] @ taken[lo:lo + CHUNK].T).max(axis=1))
    return np.where(size > 0, np.degrees(np.arccos(np.clip(best, -1.0, 1.0))), 0.0)


def spacing_deg(taken) -> float:
    """How far apart the taken directions are: the largest angle from one of them to its nearest other (a
    direction nearer than that to one taken is among them), once those within TWINS_DEG of each other are
    one (a pose taken again at another temperature, a degree or two off). TWINS_DEG with one direction
    only; 180 with none."""
    taken = np.asarray(taken, float).reshape(-1, 3)
    if not len(taken):
        return 180.0
    cos = taken @ taken.T
    twins, kept = np.cos(np.radians(TWINS_DEG)), []
    free = np.ones(len(taken), bool)
    for i in range(len(taken)):  # each direction stands for the ones within TWINS_DEG not yet taken
        if free[i]:
            kept.append(i)
            free &= cos[i] < twins
    if len(kept) < 2:
        return TWINS_DEG
    apart = cos[np.ix_(kept, kept)]
    np.fill_diagonal(apart, -1.0)
    return float(np.degrees(np.arccos(np.clip(apart.max(axis=1).min(), -1.0, 1.0))))


def fibonacci_directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors on a golden-angle spiral from the north pole to the south pole."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    radius = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.column_stack([radius * np.cos(phi), radius * np.sin(phi), z])


def beyond_taken(taken, field_nt) -> tuple[np.ndarray, np.ndarray, float]:
    """(which fields lie beyond the taken directions: farther from every one of them than they are apart,
    each field's angle to the nearest, that spacing)."""
    angles, apart = nearest_deg(taken, field_nt), spacing_deg(taken)
    return angles > apart, angles, apart


def reach_deg(taken) -> float:
    """The largest angle from any direction to the nearest taken one."""
    return float(nearest_deg(taken, fibonacci_directions(SPHERE_DIRECTIONS)).max())
