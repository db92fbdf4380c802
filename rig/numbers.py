"""Pydantic types for the numbers of a config: finite, not booleans, bounded.

pydantic's plain `float` takes `true` as 1.0 and `.inf`/`.nan`; its `int` takes `true` as 1 and
1e14 as 100000000000000. A config means none of that, so these types refuse booleans, text, inf and
NaN, and carry explicit bounds:

    FiniteFloat                      # any finite number
    PositiveFloat, NonNegativeFloat  # > 0, >= 0 (finite)
    bounded(lo=..., hi=..., gt=...)  # a finite number within bounds
    Count(100_000)                   # an integer 1..100000 (an integral float like 5.0 is taken)
    Vec3, bounded_vec3(1e6)          # three finite numbers (each |x| <= 1e6)

`FIELD_TYPES` proposes the type of each number field of the station and plan models; until those
models use the types themselves, rig/yamlload.py applies the table after validation.
"""

from __future__ import annotations

import math
from typing import Annotated, Any

from pydantic import AfterValidator, BeforeValidator, Field

NT_MAX = 1e6  # largest field magnitude a config may state (20x the Earth's field)
A_MAX = 1e3  # coil current, A
TEMP_C_MIN, TEMP_C_MAX = -273.15, 1000.0
DAY_S = 86_400.0
MAX_SAMPLES_PER_POINT = 100_000


def _number(value: Any) -> Any:
    """Refuse booleans and anything else that is not a real number; refuse inf and NaN. Text that
    spells a number is taken: YAML 1.1 reads `1.0e3` (no sign in the exponent) as text."""
    if isinstance(value, str):
        try:
            value = float(value.strip())
        except ValueError:
            raise ValueError(f"expected a number, got {_show(value)}") from None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"expected a number, got {_show(value)}")
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"must be a finite number, got {value}")
    return value


def _integer(value: Any) -> Any:
    value = _number(value)
    if isinstance(value, float):
        if not value.is_integer():
            raise ValueError(f"expected a whole number, got {value:g}")
        if abs(value) > 2**53:
            raise ValueError(f"{value:g} is far too large")
        value = int(value)
    return value


def _show(value: Any) -> str:
    if isinstance(value, bool):
        return str(value).lower()  # as YAML spells it
    text = repr(value)
    return text if len(text) <= 40 else text[:40] + "..."


FiniteFloat = Annotated[float, BeforeValidator(_number)]
PositiveFloat = Annotated[float, BeforeValidator(_number), Field(gt=0)]
NonNegativeFloat = Annotated[float, BeforeValidator(_number), Field(ge=0)]


def bounded(*, lo: float | None = None, hi: float | None = None, gt: float | None = None) -> Any:
    """A finite float with bounds: lo <= x <= hi, x > gt."""
    return Annotated[float, BeforeValidator(_number), Field(ge=lo, le=hi, gt=gt)]


def Count(upper: int, lower: int = 1) -> Any:  # noqa: N802 - reads as a type in annotations
    """A whole number lower..upper; booleans and fractions refused."""
    return Annotated[int, BeforeValidator(_integer), Field(ge=lower, le=upper)]


def _max_abs(limit: float):
    def check(v: tuple[float, ...]) -> tuple[float, ...]:
        if any(abs(x) > limit for x in v):
            raise ValueError(f"each component must be within +-{limit:g}")
        return v

    return AfterValidator(check)


Vec3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]


def bounded_vec3(limit: float) -> Any:
    return Annotated[Vec3, _max_abs(limit)]


# The proposed type of each number field of the config models, by (model class, field). Where a list
# or tuple is given, the type is its items'. Bounds: physically generous, small enough that nothing
# derived from them (durations, currents, numbers of points) overflows or explodes.
NT_VEC = bounded_vec3(NT_MAX)
TEMP_C = bounded(lo=TEMP_C_MIN, hi=TEMP_C_MAX)
ANGLE_DEG = bounded(lo=-720.0, hi=720.0)
FIELD_TYPES: dict[tuple[str, str], Any] = {
    # transports
    ("ModbusTcp", "timeout_s"): bounded(gt=0, hi=60.0),
    ("ModbusRtu", "timeout_s"): bounded(gt=0, hi=60.0),
    ("Serial", "timeout_s"): bounded(gt=0, hi=60.0),
    ("ModbusRtu", "baudrate"): Count(4_000_000),
    ("Serial", "baudrate"): Count(4_000_000),
    ("I2c", "bus"): Count(1_000, lower=0),
    # chamber
    ("ChamberLimits", "min_setpoint_c"): TEMP_C,
    ("ChamberLimits", "max_setpoint_c"): TEMP_C,
    ("ChamberLimits", "safe_setpoint_c"): TEMP_C,
    ("ChamberLimits", "max_ramp_c_per_min"): bounded(gt=0, hi=100.0),
    ("ChamberLimits", "max_deviation_c"): bounded(gt=0, hi=1_000.0),
    # field sources
    ("Coils", "max_current_a"): bounded(gt=0, hi=A_MAX),
    ("Coils", "coil_constants_nt_per_a"): NT_VEC,  # each row
    ("Coils", "ambient_nt"): NT_VEC,
    ("Coils", "ambient_max_nt"): bounded(gt=0, hi=NT_MAX),
    ("Turntable", "az_limits_deg"): ANGLE_DEG,
    ("Turntable", "el_limits_deg"): ANGLE_DEG,
    ("Turntable", "rate_deg_s"): bounded(gt=0, hi=1_000.0),
    ("SiteFromModel", "alt_km"): bounded(lo=-10.0, hi=1_000.0),
    ("SiteFromVector", "vector_nt"): NT_VEC,
    # simulated world
    ("TruthSpec", "S"): bounded_vec3(100.0),
    ("TruthSpec", "K"): bounded_vec3(1.0),
    ("TruthSpec", "b_nt"): NT_VEC,
    ("TruthSpec", "kb_nt_per_c"): NT_VEC,
    ("TruthSpec", "bridge_offset_nt"): NT_VEC,
    ("TruthSpec", "bridge_offset_tc_nt_per_c"): NT_VEC,
    ("SimDut", "noise_nt"): bounded(lo=0, hi=NT_MAX),
    ("SimDut", "thermal_lag_s"): bounded(gt=0, hi=DAY_S),
    ("SimWorld", "seed"): Count(2**63 - 1, lower=0),
    ("SimWorld", "ambient_nt"): NT_VEC,
    ("SimWorld", "site_field_nt"): NT_VEC,
    ("SimWorld", "air_c"): TEMP_C,
    # plan
    ("Stability", "band_c"): bounded(gt=0, hi=100.0),
    ("Stability", "rate_c_per_min"): bounded(gt=0, hi=100.0),
    ("Stability", "dwell_s"): bounded(lo=0, hi=DAY_S),
    ("Stability", "max_wait_s"): bounded(gt=0, hi=7 * DAY_S),
    ("TempStep", "setpoint_c"): TEMP_C,
    ("TempStep", "ramp_c_per_min"): bounded(gt=0, hi=100.0),
    ("TempRange", "start_c"): TEMP_C,
    ("TempRange", "stop_c"): TEMP_C,
    ("TempRange", "step_c"): bounded(lo=-1_000.0, hi=1_000.0),
    ("Temperatures", "ramp_c_per_min"): bounded(gt=0, hi=100.0),
    ("Cube24Fields", "magnitude_nt"): bounded(gt=0, hi=NT_MAX),
    ("Cube24Fields", "magnitudes_nt"): bounded(gt=0, hi=NT_MAX),
    ("FibonacciFields", "magnitude_nt"): bounded(gt=0, hi=NT_MAX),
    ("FibonacciFields", "magnitudes_nt"): bounded(gt=0, hi=NT_MAX),
    ("DirectionFields", "magnitude_nt"): bounded(gt=0, hi=NT_MAX),
    ("DirectionFields", "magnitudes_nt"): bounded(gt=0, hi=NT_MAX),
    ("DirectionFields", "directions"): bounded_vec3(NT_MAX),
    ("VectorFields", "vectors_nt"): NT_VEC,
    ("GridOrientations", "az_deg"): ANGLE_DEG,
    ("GridOrientations", "el_deg"): ANGLE_DEG,
    ("ListOrientations", "angles_deg"): ANGLE_DEG,  # each of az, el
    ("Plan", "samples_per_point"): Count(MAX_SAMPLES_PER_POINT),
    ("Plan", "settle_s"): bounded(lo=0, hi=DAY_S),
}


def is_vector(tp: Any) -> bool:
    """Whether a FIELD_TYPES entry is a 3-vector type (applied to a whole list) or a scalar type."""
    from typing import get_args, get_origin

    while get_origin(tp) is Annotated:
        tp = get_args(tp)[0]
    return get_origin(tp) is tuple
