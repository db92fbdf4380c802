"""The simulated world a station states (`sim:`), used by the devices whose transport is `{kind: sim}`.

Only what the station file says is kept here; a key left out (None) takes the simulator's default
(drivers/sim/truths.py), applied when rig/simstation.py builds the world.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from rig.configbase import Mat3, PositiveFloat, Strict, Vec3


class TruthSpec(Strict):
    """Explicit calibration errors of a simulated DUT (absolute-tau T24 convention, see MODELS.md)."""

    S: Mat3
    K: Mat3 = ((0, 0, 0), (0, 0, 0), (0, 0, 0))
    b_nt: Vec3 = (0, 0, 0)
    kb_nt_per_c: Vec3 = (0, 0, 0)
    bridge_offset_nt: Vec3 = (0, 0, 0)
    bridge_offset_tc_nt_per_c: Vec3 = (0, 0, 0)


class SimDut(Strict):
    truth: Literal["random"] | TruthSpec = "random"
    noise_nt: float | None = Field(None, ge=0, description="default: the simulator's")
    thermal_lag_s: PositiveFloat | None = Field(None, description="default: the simulator's")
    sensor_lag_s: float = Field(0.0, ge=0, description="its temperature sensors lag the element by this "
                                "time constant (s); 0: they read the element's temperature")


class SimWorld(Strict):
    seed: int = 0
    ambient_nt: Vec3 | None = Field(None, description="default: the coils' ambient_nt, when given")
    site_field_nt: Vec3 | None = Field(None, description="default: the turntable's site field")
    air_c: float | None = Field(None, description="chamber air at the start; default: the simulator's")
    duts: dict[str, SimDut] = {}
