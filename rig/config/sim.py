"""The simulated world a station states (`sim:`), used by the devices whose transport is `{kind: sim}`.

Only what the station file says is kept here; a key left out (None) takes the simulator's default
(drivers/sim/truths.py), applied when rig/devices/bench.py builds the world.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from rig.core.configbase import Strict
from rig.core.numbers import ANGLE_DEG, DAY_S, NT_MAX, NT_VEC, TEMP_C, Count, bounded, bounded_vec3
from rig.fieldsources.coils.geometry import CoilGeometry

Row = bounded_vec3(100.0)  # a row of S (scale: 1 is nominal)
KRow = bounded_vec3(1.0)  # a row of K (per degC)


class TruthSpec(Strict):
    """Explicit calibration errors of a simulated DUT (absolute-tau T24 convention, see MODELS.md)."""

    S: tuple[Row, Row, Row]
    K: tuple[KRow, KRow, KRow] = ((0, 0, 0), (0, 0, 0), (0, 0, 0))
    b_nt: NT_VEC = (0, 0, 0)
    kb_nt_per_c: NT_VEC = (0, 0, 0)
    bridge_offset_nt: NT_VEC = (0, 0, 0)
    bridge_offset_tc_nt_per_c: NT_VEC = (0, 0, 0)


class SimDut(Strict):
    truth: Literal["random"] | TruthSpec = "random"
    noise_nt: bounded(lo=0, hi=NT_MAX) | None = Field(None, description="default: the simulator's")
    thermal_lag_s: bounded(gt=0, hi=DAY_S) | None = Field(None, description="default: the simulator's")
    sensor_lag_s: bounded(lo=0, hi=DAY_S) = Field(0.0, description="its temperature sensors lag the element "
                                                   "by this time constant (s); 0: they read the element")
    position_error_mm: bounded_vec3(100.0) = Field(
        (0.0, 0.0, 0.0), description="where it really sits, relative to its stated position_mm")


class TableAxesSpec(Strict):
    """How the simulated turntable differs from its drawing (drivers/sim/world.py TableAxes)."""

    az_tilt_deg: tuple[ANGLE_DEG, ANGLE_DEG] = (0.0, 0.0)
    el_tilt_deg: ANGLE_DEG = 0.0
    zero_offsets_deg: tuple[ANGLE_DEG, ANGLE_DEG] = (0.0, 0.0)


class SimWorld(Strict):
    seed: Count(2**63 - 1, lower=0) = 0
    ambient_nt: NT_VEC | None = Field(None, description="default: the coils' ambient_nt, when given")
    site_field_nt: NT_VEC | None = Field(None, description="default: the turntable's site field")
    ambient_drift_nt_per_h: NT_VEC | None = Field(
        None, description="slow drift of the ambient (coils) or the site field (turntable); default none")
    air_c: TEMP_C | None = Field(None, description="chamber air at the start; default: the simulator's")
    coil_constants_nt_per_a: tuple[NT_VEC, NT_VEC, NT_VEC] | None = Field(
        None, description="the simulated coils' true matrix at the centre; default: the field source's")
    coil_nonlinearity_per_a: bounded_vec3(1.0) = Field(
        (0.0, 0.0, 0.0), description="each coil's field off linear by this share per ampere (a fault)")
    coil_geometry: CoilGeometry | None = Field(
        None, description="the simulated coils' true geometry; default: the field source's (none: uniform)")
    turntable_axes: TableAxesSpec | None = Field(
        None, description="the simulated turntable's true axes; default: the ideal table")
    duts: dict[str, SimDut] = {}
