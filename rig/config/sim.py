"""The simulated world a station states (`sim:`), used by the devices whose transport is `{kind: sim}`.

Only what the station file says is kept here; a key left out (None) takes the simulator's default
(rig/devices/simulated/world.py), applied when the simulated bench builds the world.
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import Discriminator, Field, Tag

from rig.core.configbase import Strict
from rig.core.numbers import (
    ANGLE_DEG,
    DAY_S,
    NT_MAX,
    NT_VEC,
    RAMP_C_PER_MIN,
    TEMP_C,
    Count,
    bounded,
    bounded_vec3,
)
from rig.fieldsources.coils.geometry import CoilGeometry

Row = bounded_vec3(100.0)  # a row of S (scale: 1 is nominal)
KRow = bounded_vec3(1.0)  # a row of K (per degC)
K2Row = bounded_vec3(0.01)  # a row of K2 (per degC^2)
PPM_VEC = bounded_vec3(1e5)  # parts per million, up to 10 %
NonNegative = bounded(lo=0, hi=NT_MAX)
ZERO3 = (0.0, 0.0, 0.0)


class HysteresisSpec(Strict):
    """The offset's thermal hysteresis: +offset_nt after heating, -offset_nt after cooling, through a play
    of width band_c (drivers/sim/world/dutmodel.py)."""

    offset_nt: NT_VEC
    band_c: bounded(gt=0, hi=200.0)


class TruthSpec(Strict):
    """Explicit calibration errors of a simulated DUT (absolute-tau T24 convention, see MODELS.md)."""

    S: tuple[Row, Row, Row]
    K: tuple[KRow, KRow, KRow] = ((0, 0, 0), (0, 0, 0), (0, 0, 0))
    b_nt: NT_VEC = (0, 0, 0)
    kb_nt_per_c: NT_VEC = (0, 0, 0)
    bridge_offset_nt: NT_VEC = (0, 0, 0)
    bridge_offset_tc_nt_per_c: NT_VEC = (0, 0, 0)
    # beyond T24 (drivers/sim/world/dutmodel.py): B = (S + tau K + tau^2 K2) h + b + tau kb + tau^2 kb2 + ...
    K2_per_c2: tuple[K2Row, K2Row, K2Row] = (ZERO3, ZERO3, ZERO3)
    kb2_nt_per_c2: bounded_vec3(1e4) = ZERO3
    hysteresis: HysteresisSpec | None = None
    cubic_ppm_at_50ut: PPM_VEC = Field(ZERO3, description="each axis off linear by this at |B| = 50 uT, "
                                       "growing as |B|^2")


def _truth_kind(value) -> str:
    """A mapping is an explicit truth: its errors are then about its keys, never "not 'random'"."""
    return "random" if isinstance(value, str) else "explicit"


Truth = Annotated[Union[Annotated[Literal["random"], Tag("random")],  # noqa: UP007 - tags need Union
                        Annotated[TruthSpec, Tag("explicit")]], Discriminator(_truth_kind)]


class SimDut(Strict):
    truth: Truth = "random"
    noise_nt: bounded(lo=0, hi=NT_MAX) | None = Field(None, description="default: the simulator's")
    thermal_lag_s: bounded(gt=0, hi=DAY_S) | None = Field(None, description="default: the simulator's")
    sensor_lag_s: bounded(lo=0, hi=DAY_S) = Field(0.0, description="its temperature sensors lag the element "
                                                   "by this time constant (s); 0: they read the element")
    position_error_mm: bounded_vec3(100.0) = Field(
        (0.0, 0.0, 0.0), description="where it really sits, relative to its stated position_mm")
    random_walk_nt_per_sqrt_h: NonNegative = Field(0.0, description="random walk of its offset, per axis")
    flicker_nt: NonNegative = Field(0.0, description="1/f noise on its offset, RMS per axis")
    air_offset_c: bounded(lo=-50.0, hi=50.0) = Field(
        0.0, description="its place is this much warmer than the air the chamber's controller sees")


class CurrentSourceSpec(Strict):
    """The coil current source's errors per axis (drivers/sim/world/currentsource.py)."""

    gain_error_ppm: PPM_VEC = ZERO3
    offset_ma: bounded_vec3(1e4) = ZERO3
    noise_ma: tuple[NonNegative, NonNegative, NonNegative] = ZERO3
    readback_error_ppm: PPM_VEC = ZERO3


MM_VEC = bounded_vec3(100.0)
TILT_DEG = bounded(lo=-10.0, hi=10.0)


class LoopSpec(Strict):
    """The two loops of one axis's pair, each on its own: [+ side, - side]
    (drivers/sim/world/coilfield.py)."""

    turns_error_ppm: tuple[bounded(lo=-1e5, hi=1e5), bounded(lo=-1e5, hi=1e5)] = (0.0, 0.0)
    offset_mm: tuple[MM_VEC, MM_VEC] = (ZERO3, ZERO3)
    tilt_deg: tuple[TILT_DEG, TILT_DEG] = Field((0.0, 0.0), description="each loop's normal tilted about "
                                                "the next lab axis (x loops about y, y about z, z about x)")


class CoilLoopsSpec(Strict):
    x: LoopSpec = LoopSpec()
    y: LoopSpec = LoopSpec()
    z: LoopSpec = LoopSpec()


class AmbientStepsSpec(Strict):
    """Poisson-timed steps of the ambient, each of random direction and RMS size size_nt."""

    mean_interval_h: bounded(gt=0, hi=1e5)
    size_nt: NonNegative


class ChamberSpec(Strict):
    """The simulated chamber as it really is (drivers/sim/world/chamberair.py)."""

    max_rate_c_per_min: RAMP_C_PER_MIN | None = Field(None, description="default: the simulator's")
    overshoot_c: bounded(lo=0, hi=20.0) = Field(0.0, description="after a change at the full rate")
    heater_field_nt: NT_VEC = Field(ZERO3, description="at the coil centre while the heater is on")
    compressor_field_nt: NT_VEC = Field(ZERO3, description="at the coil centre while the compressor runs")


class TableAxesSpec(Strict):
    """How the simulated turntable differs from its drawing (drivers/sim/world/__init__.py TableAxes)."""

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
    current_source: CurrentSourceSpec | None = Field(None, description="the coil current source's errors")
    coil_loops: CoilLoopsSpec | None = Field(None, description="each coil loop off its drawing (needs a "
                                             "coil geometry)")
    ambient_gradient_nt_per_m: tuple[NT_VEC, NT_VEC, NT_VEC] | None = Field(
        None, description="dB_i/dx_j: the ambient at a sensor's true position r is ambient + G r")
    ambient_steps: AmbientStepsSpec | None = None
    chamber: ChamberSpec | None = None
    duts: dict[str, SimDut] = {}
