"""Three-axis coils: a field vector is made by currents, B = C I + ambient (rig/reference.py).

`ambient_nt` is the field with the coils off, in the lab frame; "measure" means the engine measures it at
the start of the campaign (with a DUT or a reference magnetometer), and until then `rig check` allows
for any ambient up to `ambient_max_nt`.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Discriminator, Field, Tag, model_validator

from drivers.coils import CoilOptions
from rig import fieldsets
from rig.errors import ConfigError
from rig.fieldsources.base import FieldSourceConfig, point_limit_error
from rig.names import SafeName
from rig.numbers import A_MAX, NT, NT_VEC, bounded
from rig.reference import TYPICAL_FIELD_NT, CoilReference, currents_for_field
from rig.yamlload import KeyPathError

VECTOR_FIELD_KINDS = frozenset({"cube24", "fibonacci", "directions", "vectors"})

# "measure" or a field vector: chosen by the value, so a bad vector is named by its item alone
AmbientNt = Annotated[
    Annotated[NT_VEC, Tag("vector")] | Annotated[Literal["measure"], Tag("measure")],
    Discriminator(lambda v: "measure" if isinstance(v, str) else "vector"),
]


class Coils(FieldSourceConfig, CoilOptions):
    field_kinds: ClassVar[frozenset[str]] = VECTOR_FIELD_KINDS
    point_letter: ClassVar[str] = "F"
    described: ClassVar[str] = "coils"

    kind: Literal["coils"]
    name: SafeName = "coils"
    max_current_a: bounded(gt=0, hi=A_MAX)
    coil_constants_nt_per_a: tuple[NT_VEC, NT_VEC, NT_VEC]
    ambient_nt: AmbientNt
    ambient_max_nt: NT = Field(
        70_000.0, description="bound on |ambient| used to check currents while ambient is 'measure'"
    )

    @model_validator(mode="after")
    def _invertible(self):
        if np.linalg.cond(self.constants) > 1e6:
            raise KeyPathError(("coil_constants_nt_per_a",), "matrix is singular (coil axes not independent)")
        return self

    @property
    def constants(self) -> np.ndarray:
        return np.asarray(self.coil_constants_nt_per_a, float)

    # --- plan ---------------------------------------------------------------------------------------
    def record(self, target) -> dict:
        return {"field_nt": list(target)}

    def nominal_field_nt(self, target) -> np.ndarray:
        return np.asarray(target, float)

    def check_targets(self, plan_name, points, warnings) -> list[str]:
        """LimitError when a point needs more than max_current_a on an axis."""
        inv = np.linalg.inv(self.constants)
        if isinstance(self.ambient_nt, str):
            ambient = np.zeros(3)
            margin = np.linalg.norm(inv, axis=1) * self.ambient_max_nt  # worst case over |ambient| <= max
            assumption = (f"any ambient up to {self.ambient_max_nt:g} nT (field_source.ambient_max_nt; "
                          "ambient_nt is 'measure')")
            warnings.append(f"ambient field not yet measured: currents checked for {assumption}")
        else:
            ambient, margin = np.asarray(self.ambient_nt, float), np.zeros(3)
            assumption = "the station's ambient_nt"
        largest = 0.0
        for p in points:
            worst = np.abs(currents_for_field(p.command, self.constants, ambient)) + margin
            axis = int(np.argmax(worst))
            if worst[axis] > self.max_current_a:
                raise point_limit_error(
                    plan_name, p, f"field {_fmt_vec(p.command)} nT needs {worst[axis]:.3f} A "
                    f"in coil {'xyz'[axis]} with {assumption}, above field_source.max_current_a "
                    f"{self.max_current_a:g} A"
                )
            largest = max(largest, float(worst[axis]))
        first_step = [p.command for p in points if p.temp_index == points[0].temp_index]
        span = fieldsets.span_ratio(np.array(first_step))
        if span < 0.2:
            warnings.append(f"field directions barely span 3-D (ratio {span:.2f}): the scale and cross-axis "
                            "terms will be poorly determined")
        return [f"largest coil current {largest:.3f} A"]

    # --- run ----------------------------------------------------------------------------------------
    def reference(self, measured_nt=None) -> CoilReference:
        """`measured_nt`: the ambient field measured at the start (needed when ambient_nt is 'measure')."""
        ambient = measured_nt if measured_nt is not None else self.ambient_nt
        if isinstance(ambient, str):
            raise ConfigError("field_source.ambient_nt is 'measure': measure it first")
        return CoilReference(self.constants, ambient)

    # --- simulation ---------------------------------------------------------------------------------
    def world_field(self, sim) -> dict:
        stated = None if self.ambient_nt == "measure" else self.ambient_nt
        ambient = next(v for v in (sim.ambient_nt, stated, TYPICAL_FIELD_NT) if v is not None)
        return {"field_source": "coils", "coil_constants_nt_per_a": self.constants,
                "ambient_nt": np.asarray(ambient, float)}


def _fmt_vec(v) -> str:
    return "(" + ", ".join(f"{x:.0f}" for x in v) + ")"
