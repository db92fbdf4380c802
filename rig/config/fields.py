"""The `fields:` of a plan: the field set a sweep goes through (field vectors for coils, orientations
for a turntable). Which kinds a station can make is its field source's business (rig/fieldsources/).

A field set's `targets()` are field vectors (nT) or (az, el) pairs, deterministic, in order; `count()`
says how many without making them (bounds are checked before anything is built).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from calib.stats.directions import fibonacci_directions
from rig.core.configbase import Strict
from rig.core.numbers import ANGLE_DEG, NT, NT_MAX, NT_VEC, Count, bounded_vec3
from rig.fieldsources import fieldsets


def _vectors(directions: np.ndarray, magnitudes_nt: list[float]) -> list[tuple[float, ...]]:
    return [tuple(float(x) for x in v) for v in fieldsets.scaled(directions, magnitudes_nt)]


class _Magnitudes(Strict):
    """A field set's `targets()` are field vectors (nT) or (az, el) pairs, deterministic, in order;
    `count()` says how many without making them (bounds are checked before anything is built)."""

    magnitude_nt: NT | None = None
    magnitudes_nt: list[NT] | None = None

    def magnitude_list(self) -> list[float]:
        if self.magnitudes_nt:
            return list(self.magnitudes_nt)
        return [self.magnitude_nt or 50_000.0]


class Cube24Fields(_Magnitudes):
    """The 24 rotations of the cube applied to one reference direction (see rig/fieldsources/fieldsets.py)."""

    kind: Literal["cube24"]

    def targets(self) -> list[tuple[float, ...]]:
        return _vectors(fieldsets.cube24_directions(), self.magnitude_list())

    def count(self) -> int:
        return 24 * len(self.magnitude_list())


class FibonacciFields(_Magnitudes):
    kind: Literal["fibonacci"]
    n: Count(10_000, lower=4)

    def targets(self) -> list[tuple[float, ...]]:
        return _vectors(fibonacci_directions(self.n), self.magnitude_list())

    def count(self) -> int:
        return self.n * len(self.magnitude_list())


class DirectionFields(_Magnitudes):
    kind: Literal["directions"]
    directions: list[bounded_vec3(NT_MAX)] = Field(min_length=1)

    def targets(self) -> list[tuple[float, ...]]:
        """ValueError for a zero direction."""
        return _vectors(fieldsets.normalised(self.directions), self.magnitude_list())

    def count(self) -> int:
        return len(self.directions) * len(self.magnitude_list())

    def listed_index(self, target_index: int) -> int:
        """0-based index in `directions` of target `target_index` (targets are magnitude-major)."""
        return target_index % len(self.directions)


class VectorFields(Strict):
    kind: Literal["vectors"]
    vectors_nt: list[NT_VEC] = Field(min_length=1)

    def targets(self) -> list[tuple[float, ...]]:
        return [tuple(float(x) for x in v) for v in self.vectors_nt]

    def count(self) -> int:
        return len(self.vectors_nt)


class GridOrientations(Strict):
    """Turntable: every azimuth at every elevation (the default is 16 of the cube's 24 rotations, all
    that a two-axis table can reach)."""

    kind: Literal["grid"]
    az_deg: list[ANGLE_DEG] = Field([-90.0, 0.0, 90.0, 180.0], min_length=1)
    el_deg: list[ANGLE_DEG] = Field([-90.0, 0.0, 90.0, 180.0], min_length=1)

    def targets(self) -> list[tuple[float, ...]]:
        return fieldsets.grid_orientations(self.az_deg, self.el_deg)

    def count(self) -> int:
        return len(self.az_deg) * len(self.el_deg)


class ListOrientations(Strict):
    kind: Literal["orientations"]
    angles_deg: list[tuple[ANGLE_DEG, ANGLE_DEG]] = Field(min_length=1, description="[az, el] pairs")

    def targets(self) -> list[tuple[float, ...]]:
        return [tuple(map(float, a)) for a in self.angles_deg]

    def count(self) -> int:
        return len(self.angles_deg)


FieldSet = Annotated[
    Cube24Fields | FibonacciFields | DirectionFields | VectorFields | GridOrientations | ListOrientations,
    Field(discriminator="kind"),
]
