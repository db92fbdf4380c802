"""Pydantic types for the numbers of a config: finite, not booleans, bounded.

pydantic's plain `float` takes `true` as 1.0 and `.inf`/`.nan`; its `int` takes `true` as 1 and
1e14 as 100000000000000. A config means none of that, so these types refuse booleans, text, inf and
NaN, and carry explicit bounds:

    FiniteFloat                      # any finite number
    PositiveFloat, NonNegativeFloat  # > 0, >= 0 (finite)
    bounded(lo=..., hi=..., gt=...)  # a finite number within bounds
    Count(100_000)                   # an integer 1..100000 (an integral float like 5.0 is taken)
    Vec3, bounded_vec3(1e6)          # three finite numbers (each |x| <= 1e6)

The station and plan models (rig/config/, rig/core/configbase.py, rig/fieldsources/) state these types on
their fields, so validation itself refuses a boolean, inf/NaN or a number out of bounds and names the
key (and the item of a vector). Driver options models (drivers/, which cannot import rig) get the same
finite-number rule from drivers/registry.py's Options base.
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


# The types of the config models' number fields. Bounds: physically generous, small enough that nothing
# derived from them (durations, currents, numbers of points) overflows or explodes.
NT = bounded(gt=0, hi=NT_MAX)  # a field magnitude
NT_VEC = bounded_vec3(NT_MAX)  # a field vector
TEMP_C = bounded(lo=TEMP_C_MIN, hi=TEMP_C_MAX)
RAMP_C_PER_MIN = bounded(gt=0, hi=100.0)
ANGLE_DEG = bounded(lo=-720.0, hi=720.0)
SECONDS = bounded(lo=0, hi=DAY_S)  # a wait of at most a day
TIMEOUT_S = bounded(gt=0, hi=60.0)  # a transport's reply timeout
BAUDRATE = Count(4_000_000)
MODBUS_UNIT = Count(247, lower=0)
