"""The field directions a calibration's data took, and how far other directions are from them.

A calibration holds among the directions its data took; away from them its parameters extrapolate, and
a fit without a reference direction (the scalar fit) has nothing there to hold them at all. A turntable
tilted at most 60 deg under a steep site field never shows the DUT the field from below.

    taken = taken_directions(ref_nt)            # (M,3) unit vectors, recorded in the calibration's stats
    spacing_deg(taken)                          # how far apart the taken directions are
    nearest_deg(taken, field_nt)                # (N,): each field's angle to the nearest taken direction
    reach_deg(taken)                            # the largest such angle over every direction
"""

from __future__ import annotations

import numpy as np

MAX_DIRECTIONS = 1000  # recorded at most: coarser rounding until they fit
ROUNDINGS = (0.02, 0.05, 0.1, 0.2)  # of the unit vectors' components (about 1, 3, 6 and 11 deg)
SPHERE_DIRECTIONS = 6000  # the sphere's directions a reach is judged at (about 2.6 deg apart)
CHUNK = 500
TWINS_DEG = 10.0  # directions nearer than this count as one for their spacing


def _unit(vectors) -> np.ndarray:
    v = np.asarray(vectors, float).reshape(-1, 3)
    size = np.linalg.norm(v, axis=1)
    return v[size > 0] / size[size > 0, None]


def taken_directions(field_nt) -> np.ndarray:
    """(M,3): the distinct directions of the fields (rounded to the finest of ROUNDINGS that leaves at most
    MAX_DIRECTIONS), unit vectors."""
    unit = _unit(field_nt)
    for step in ROUNDINGS:
        taken = _unit(np.unique(np.round(unit / step) * step, axis=0))
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
    for lo in range(0, len(taken), CHUNK):
        best = np.maximum(best, (unit @ taken[lo:lo + CHUNK].T).max(axis=1))
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


def reach_deg(taken) -> float:
    """The largest angle from any direction to the nearest taken one."""
    k = np.arange(SPHERE_DIRECTIONS) + 0.5
    z = 1 - 2 * k / SPHERE_DIRECTIONS
    phi = np.pi * (3 - np.sqrt(5)) * k
    sphere = np.column_stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z])
    return float(nearest_deg(taken, sphere).max())
