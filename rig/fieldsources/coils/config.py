"""Three-axis coils: a field vector is made by currents, B = C I + ambient (rig/fieldsources/fieldmaths.py).

`ambient_nt` is the field with the coils off, in the lab frame; "measure" means a reference magnetometer
(the station's `reference_magnetometers`, never a DUT) measures it with the coils at 0 A at the start of
the campaign and again at each temperature step (rig/reference/sitefield.py). Until then `rig check` allows
for any ambient up to `ambient_max_nt`; `rig run` checks the plan's currents again with the measured ambient.

The coil matrix C at the centre is the declared `coil_constants_nt_per_a`, or the one `rig commission`
measured (`commissioning: FILE`, rig/config/commissioning_file.py), which replaces it. With a `geometry`,
the field at each DUT's `position_mm` is the coil field there (rig/fieldsources/coils/geometry.py), scaled and
turned to match C at the centre; without one the field is taken as uniform.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Discriminator, Field, Tag, model_validator

import rig.fieldsources.fieldsets as fieldsets
from drivers.coils import CoilOptions
from rig.core.configbase import Strict
from rig.core.errors import ConfigError
from rig.core.names import SafeName
from rig.core.numbers import A_MAX, NT, NT_VEC, bounded
from rig.core.yamlload import KeyPathError
from rig.fieldsources.base import (
    DRIFT_MAX_NT,
    FieldSourceConfig,
    only_reference,
    point_limit_error,
)
from rig.fieldsources.coils import commissioning
from rig.fieldsources.coils.geometry import CoilGeometry, nonuniformity_lines
from rig.fieldsources.coils.loops import matrix_with_loops
from rig.fieldsources.fieldmaths import CoilReference, currents_for_field

VECTOR_FIELD_KINDS = frozenset({"cube24", "fibonacci", "directions", "vectors"})

# "measure" or a field vector: chosen by the value, so a bad vector is named by its item alone
AmbientNt = Annotated[
    Annotated[NT_VEC, Tag("vector")] | Annotated[Literal["measure"], Tag("measure")],
    Discriminator(lambda v: "measure" if isinstance(v, str) else "vector"),
]


MAX_CONDITION = 1e6  # a coil matrix worse conditioned than this cannot be inverted for currents
DECLARED_UNCERTAINTY_PPM = 10_000.0  # real sets differ from their design by 0.5-2 % and tenths of a degree


class DeclaredGeometry(CoilGeometry):
    tolerance_mm: bounded(lo=0, hi=1000.0) = Field(
        1.0, description="how well the loops' sizes, spacings and places are known (+-, mm): the budget's "
        "'coil geometry' and, for each loop's place, 'coil loops'")
    tilt_tolerance_deg: bounded(lo=0, hi=10.0) = Field(
        0.1, description="how far each loop may lean off its drawing (+-, deg): the budget's 'coil loops'")
    turns_tolerance_ppm: bounded(lo=0, hi=1e5) = Field(
        1000.0, description="how far each loop's turns may be off (+-, ppm): the budget's 'coil loops'")


class CurrentAccuracy(Strict):
    """The coil current source's accuracy from its datasheet (+-, per axis or one value for all): what the
    read-back currents the rig uses may be off by, the setpoint's error included (the commissioning
    fitted the matrix against commanded currents)."""

    gain_ppm: bounded(lo=0, hi=1e5) | tuple[bounded(lo=0, hi=1e5), bounded(lo=0, hi=1e5),
                                            bounded(lo=0, hi=1e5)]
    offset_ma: bounded(lo=0, hi=1e4) | tuple[bounded(lo=0, hi=1e4), bounded(lo=0, hi=1e4),
                                             bounded(lo=0, hi=1e4)]


class Coils(FieldSourceConfig, CoilOptions):
    field_kinds: ClassVar[frozenset[str]] = VECTOR_FIELD_KINDS
    point_letter: ClassVar[str] = "F"
    described: ClassVar[str] = "coils"
    frame_text: ClassVar[str] = ("the station's field frame: the coil axes x, y, z (the rows of its coil "
                                 "constants), the DUT as it was mounted in the coils")
    declared_words: ClassVar[str] = "the coils' declared constants"
    commissioned_words: ClassVar[str] = "the coil matrix as `rig commission` measured it"
    measured_name: ClassVar[str] = "ambient field"

    kind: Literal["coils"]
    name: SafeName = "coils"
    max_current_a: bounded(gt=0, hi=A_MAX)
    coil_constants_nt_per_a: tuple[NT_VEC, NT_VEC, NT_VEC] | None = Field(
        None, description="the design matrix (rows = lab axes); replaced by `commissioning` when given")
    constants_uncertainty_ppm: bounded(lo=0, hi=1e6) = Field(
        DECLARED_UNCERTAINTY_PPM, description="standard uncertainty of each declared matrix element, "
        "relative to its column (used while the coils are not commissioned)")
    geometry: DeclaredGeometry | None = Field(
        None, description="the coil set's shape and size: the field at each DUT's position")
    ambient_nt: AmbientNt
    ambient_max_nt: NT = Field(
        70_000.0, description="bound on |ambient| used to check currents while ambient is 'measure'"
    )
    reference_magnetometer: SafeName | None = Field(
        None, description="which reference magnetometer measures the ambient; default: the only one")
    ambient_drift_max_nt: NT = Field(
        DRIFT_MAX_NT, description="a measured ambient that moves more than this between steps holds the run")
    current_accuracy: CurrentAccuracy | None = Field(
        None, description="the current source's accuracy from its datasheet (budget: 'current source'); "
        "measured at commissioning from its read-back instead, where the commissioning file has it")
    constants_drift_ppm_per_year: bounded(lo=0, hi=1e5) | None = Field(
        None, description="how fast the coil constants may drift since commissioning (+-, ppm per year): "
        "the budget's 'coil drift since commissioning', times the commissioning's age")
    ambient_gradient_nt_per_m: bounded(lo=0, hi=1e6) | None = Field(
        None, description="the largest lab-field gradient dB_i/dx_j over the DUT positions (+-, nT/m): the "
        "budget's 'ambient gradient' between the reference magnetometer and each DUT, where the "
        "commissioning's places (rig commission --position) or other reference magnetometers do not "
        "measure it")

    @model_validator(mode="after")
    def _invertible(self):
        if self.coil_constants_nt_per_a is None:
            if self.commissioning is None:
                raise KeyPathError(("coil_constants_nt_per_a",), "give the coil matrix, or `commissioning:` "
                                   "naming the file `rig commission` wrote")
        elif np.linalg.cond(self.declared_constants) > MAX_CONDITION:
            raise KeyPathError(("coil_constants_nt_per_a",), "matrix is singular (coil axes not independent)")
        return self

    @property
    def declared_constants(self) -> np.ndarray | None:
        c = self.coil_constants_nt_per_a
        return None if c is None else np.asarray(c, float)

    @property
    def constants(self) -> np.ndarray:
        """The coil matrix at the centre the rig uses: the commissioned one, else the declared one."""
        if self._commissioned is not None:
            return self._commissioned.matrix_nt_per_a
        if self.coil_constants_nt_per_a is None:
            raise ConfigError(f"field_source.commissioning {self.commissioning!r} has not been loaded")
        return self.declared_constants

    def matrices_at(self, positions_mm: dict[str, tuple | None]) -> dict[str, np.ndarray]:
        """{device name: the coil matrix where it sits} (the centre's without a geometry or position)."""
        centre = self.constants
        stated = {name: p for name, p in positions_mm.items() if p is not None and any(p)}
        out = {name: centre for name in positions_mm}
        if self.geometry is not None and stated:
            loops = self.fitted_loops
            if loops is None:
                matrices = self.geometry.matrices_at(centre, list(stated.values()))
            else:  # each loop as the commissioning's places measured it
                g = self.geometry
                matrices = [matrix_with_loops(centre, g.shape, g.size_m, g.spacing_m,
                                              np.asarray(p, float) / 1000.0, loops) for p in stated.values()]
            out.update(zip(stated, matrices, strict=True))
        return out

    @property
    def measured_gradient(self):
        """The lab field's gradient the commissioning's places measured (a GradientRecord; None: not)."""
        com = self._commissioned
        return None if com is None else com.record.coils.gradient

    def gradient_offsets_nt(self, positions_mm: dict[str, tuple | None],
                            ambient_at_mm: tuple | None) -> dict[str, np.ndarray]:
        """{device name: G (r - r_ambient)}: what the measured gradient adds to the ambient, measured at
        `ambient_at_mm` (None: the centre), where each device sits; {} without a measured gradient."""
        gradient = self.measured_gradient
        if gradient is None:
            return {}
        g = np.asarray(gradient.nt_per_m, float)
        origin = np.zeros(3) if ambient_at_mm is None else np.asarray(ambient_at_mm, float)
        return {name: g @ ((np.zeros(3) if p is None else np.asarray(p, float)) - origin) / 1000.0
                for name, p in positions_mm.items()}

    @property
    def fitted_loops(self) -> np.ndarray | None:
        """(3, 2, 5): each loop off its drawing as the commissioning's places measured it (None: not)."""
        com = self._commissioned
        loops = None if com is None or self.geometry is None else com.record.coils.loops
        return None if loops is None else np.asarray(loops.deviations, float)

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
        largest = self._check_currents(plan_name, points, ambient, margin, assumption)
        first_step = [p.command for p in points if p.temp_index == points[0].temp_index]
        span = fieldsets.span_ratio(np.array(first_step))
        if span < 0.2:
            warnings.append(f"field directions barely span 3-D (ratio {span:.2f}): the scale and cross-axis "
                            "terms will be poorly determined")
        return [f"largest coil current {largest:.3f} A"]

    def _check_currents(self, plan_name, points, ambient, margin, assumption) -> float:
        """The largest current any point needs; LimitError at the first point above max_current_a."""
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
        return largest

    # --- run ----------------------------------------------------------------------------------------
    def reference(self, measured_nt=None, positions_mm=None, ambient_at_mm=None) -> CoilReference:
        """`measured_nt`: the ambient field measured at the start (needed when ambient_nt is 'measure');
        `positions_mm`: {DUT name: position} for the field where each DUT sits; `ambient_at_mm`: where the
        ambient was measured (None: the centre), from which a measured gradient carries it to each DUT."""
        ambient = measured_nt if measured_nt is not None else self.ambient_nt
        if isinstance(ambient, str):
            raise ConfigError("field_source.ambient_nt is 'measure': measure it first")
        positions = positions_mm or {}
        return CoilReference(self.constants, ambient, self.matrices_at(positions),
                             self.gradient_offsets_nt(positions, ambient_at_mm))

    # --- a measured ambient -------------------------------------------------------------------------
    def needs_measurement(self) -> bool:
        return self.ambient_nt == "measure"

    def measuring_magnetometer(self, reference_names) -> str | None:
        if not self.needs_measurement():
            return None
        return self.reference_magnetometer or only_reference(reference_names)

    def measurement_setting(self) -> tuple[float, ...]:
        return (0.0, 0.0, 0.0)  # every coil at 0 A: what is left is the ambient

    def own_field_nt(self, readback, readback_se, position_mm):
        """The field of the read-back currents at 0 A (a supply's offset, its noise averaged): the run's
        references are the field of the read-back currents plus the ambient, so the ambient is measured
        without it, as the commissioning's ambient is."""
        matrix = self.matrices_at({"here": position_mm})["here"]
        se = np.sqrt(np.square(matrix) @ np.square(np.asarray(readback_se, float)))
        return matrix @ np.asarray(readback, float), se

    def drift_max_nt(self) -> float:
        return self.ambient_drift_max_nt

    def check_measured(self, plan_name, points, measured_nt) -> None:
        self._check_currents(plan_name, points, np.asarray(measured_nt, float), np.zeros(3),
                             f"the measured ambient {_fmt_vec(measured_nt)} nT")

    # --- the reference chain ------------------------------------------------------------------------
    commissioning_section: ClassVar[str] = "coils"
    commissioning_covariance_size: ClassVar[int] = 12  # the matrix row by row, then the ambient

    def commissioning_design(self, current_a, repeats):
        return commissioning.design(self, current_a, repeats)

    def commissioning_reference_problem(self, position_mm) -> str | None:
        if self.geometry is None and np.any(np.asarray(position_mm or (0.0, 0.0, 0.0), float) != 0):
            return "is not at the centre and field_source has no geometry to carry its readings there"
        return None

    def commissioning_place_problem(self, position_mm) -> str | None:
        if self.geometry is None:
            return "field_source has no geometry: the loops cannot be fitted to places off the centre"
        if not self.geometry.encloses(position_mm):
            return "is outside the coil set (field_source.geometry)"
        return None

    def commissioning_with_place(self, section: dict, readings, position_mm, created_utc: str,
                                 settings: list[dict], reference_tolerance_mm: float) -> dict:
        place = commissioning.fit_place(self, readings, position_mm, created_utc, settings)
        merged = {**section, "places": [*section.get("places", []), place]}
        return commissioning.with_loops(self, merged, reference_tolerance_mm)

    def setting_readback(self, reading) -> tuple[float, ...] | None:
        return tuple(float(v) for v in reading.currents_a)

    def fit_commissioning(self, readings, reference_position_mm) -> dict:
        return commissioning.fit(self, readings, reference_position_mm)

    measures_gradient: ClassVar[bool] = True

    def commissioning_with_others(self, section: dict, others: list[dict], reference_position_mm) -> dict:
        return commissioning.with_other_references(self, section, others, reference_position_mm)

    @classmethod
    def commissioning_section_problem(cls, section):
        if np.linalg.cond(np.asarray(section.matrix_nt_per_a, float)) > MAX_CONDITION:
            return ("matrix_nt_per_a",), "the matrix is singular (coil axes not independent)"
        return None

    def commissioning_lines(self, section) -> list[str]:
        return commissioning.summary_lines(section)

    def chain_record(self, positions_mm: dict) -> dict:
        return {"centre_matrix_nt_per_a": np.asarray(self.constants, float).tolist(),
                "matrices_nt_per_a": {name: np.asarray(m, float).tolist()
                                      for name, m in self.matrices_at(positions_mm).items()}}

    def reference_check_lines(self, station, plan, warnings: list[str]) -> list[str]:
        """The coil field's non-uniformity over the DUT positions: LimitError (blamed on the station's
        position_mm) above plan.accuracy_ppm. (An uncommissioned matrix's declared uncertainty is the
        `uncertainty_caveat` line, printed first.)"""
        lines: list[str] = []
        if self.geometry is None:
            if any(d.position_mm is not None for d in station.duts):
                warnings.append("DUT positions are stated but field_source has no geometry: the coil field "
                                "is taken as uniform")
            return lines
        return lines + nonuniformity_lines(self.geometry, station, plan)

    def uncertainty_caveat(self) -> str | None:
        if self.commissioned is not None:
            return None
        ppm = self.constants_uncertainty_ppm
        return (f"the coils are not commissioned: each coil constant is taken as uncertain by its declared "
                f"{ppm:g} ppm ({ppm / 1e4:g} %), which will dominate every calibration's uncertainty; "
                "`rig commission` measures the coils (configs/stations/sim-commissioned.yaml shows how)")

    def budget_chain(self, run, dut: str, ds):
        from rig.fieldsources.coils.budget import CoilChain

        return CoilChain(run, dut, ds)

    def ambient_in_references(self, run, ds):
        used = run.recorded_ambient(ds)
        return None if used is None else (used, None)

    # --- station and simulation ---------------------------------------------------------------------
    def station_problems(self, dut_names, reference_names=()):
        if self.reference_magnetometer is not None and self.reference_magnetometer not in reference_names:
            known = ", ".join(reference_names) or "none defined"
            return [(("reference_magnetometer",), f"no reference magnetometer named "
                     f"{self.reference_magnetometer!r} (reference_magnetometers: {known})")]
        if self.needs_measurement() and self.measuring_magnetometer(reference_names) is None:
            if not reference_names:
                return [(("ambient_nt",), "'measure' needs a reference magnetometer at the DUT position: add "
                         "one under reference_magnetometers (a DUT cannot double as the reference), or state "
                         "the ambient as [x, y, z] nT")]
            return [(("reference_magnetometer",), "the station has several reference magnetometers: name "
                     f"the one that measures the ambient (one of {', '.join(reference_names)})")]
        return []

    def declared_world(self) -> dict:
        """What the station declares of the coils, as the simulated world's keywords (the matrix: the
        declared one, else the commissioned one)."""
        matrix = self.constants if self.coil_constants_nt_per_a is None else self.coil_constants_nt_per_a
        geometry = self.geometry
        return {"field_source": "coils", "coil_constants_nt_per_a": np.asarray(matrix, float),
                "coil_geometry": None if geometry is None else
                (geometry.shape, tuple(geometry.size_m), tuple(geometry.spacing_m)),
                "ambient_nt": None if self.ambient_nt == "measure" else np.asarray(self.ambient_nt, float)}


def _fmt_vec(v) -> str:
    return "(" + ", ".join(f"{x:.0f}" for x in v) + ")"
