"""What the Watlow F4T and legacy F4 chamber drivers (drivers/watlow.py) share: both register maps, the
optional alarm register, the reading, the limits and the common driver over Modbus (TCP or RTU).

Construct (the station YAML maps onto these keywords; `transport` is a drivers.transports.modbus
ModbusTransport built from the station's link settings):

    WatlowF4T(transport, *, name, clock, min_setpoint_c, max_setpoint_c, max_ramp_c_per_min,
              safe_setpoint_c, word_order="little", alarm=None, max_deviation_c=5.0)
    WatlowF4(transport, *, name, clock, min_setpoint_c, max_setpoint_c, max_ramp_c_per_min,
             safe_setpoint_c, alarm=None, max_deviation_c=5.0)

Both: connect(), close(), set(setpoint_c), set_ramp_rate(c_per_min), read() -> ChamberReading,
safe_state() (setpoint -> safe_setpoint_c), describe().

Only documented registers are touched (hardware-notes 3.1 and 3.2): a real controller answers any other
address with exception 2, and `rig devices check` would fail on every real chamber. No source documents
an alarm register for either map, so by default read() watches what can be read for sure:
- F4T: chamber temperature 27586, set point 2782, closed-loop set point 2810 (no input-error register is
  documented for data map 1, so `input_error` is always False there);
- F4: temperature 100 with its input error 101, set point 300; 606 (precision) and 901 (units) at connect;
and the rig's own limits: the air's rate of change against max_ramp_c_per_min, and, once the air has
reached its set point, a departure of more than max_deviation_c from it.

`alarm`: a lab whose controller has an alarm register names it (ChamberAlarm, or a dict of its fields);
only then is it read.

Problems are *reported*, not raised: read() returns them in ChamberReading.problems (`fault` is True when
there is any) and the engine decides to hold. A chamber in alarm may still need a safe setpoint written,
which a raising read() would get in the way of.

Register maps: docs/modbus-maps.md.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from numbers import Real
from typing import Literal

from pydantic import (
    ConfigDict,
    Field,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic.dataclasses import dataclass as validated_dataclass

from drivers import registry
from drivers.base import Device
from drivers.clock import Clock
from drivers.errors import LimitError, OptionError
from drivers.transports.modbus import ModbusTransport

# --- F4T, Data Map 1 (float32, low word first by default; hardware-notes 3.2) ---------------------
F4T_SETPOINT = 2782  # RW float32, temperature set point
F4T_RAMP_ACTION = 2794  # RW uint16: off 62, startup 88, set point 85, both 13
F4T_RAMP_SCALE = 2796  # RW uint16: degrees per minute 57, per hour 39
F4T_RAMP_RATE = 2798  # RW float32
F4T_CLOSED_LOOP_SETPOINT = 2810  # R float32, instantaneous set point during a ramp
F4T_CHAMBER_TEMP = 27586  # R float32, actual chamber temperature
RAMP_OFF, RAMP_ON_SETPOINT, RAMP_BOTH = 62, 85, 13
RAMP_SCALE_PER_MINUTE, RAMP_SCALE_PER_HOUR = 57, 39

# --- legacy F4 (int16, scaled by the display precision; hardware-notes 3.1) -----------------------
F4_TEMP = 100  # R int16, input 1 (chamber temperature)
F4_INPUT_ERROR = 101  # R 0/1
F4_SETPOINT = 300  # RW int16, set point 1
F4_PRECISION = 606  # RW 0..3 decimals: the int16 values carry that many implied decimals
F4_UNITS = 901  # RW: 1 degC, 0 degF
F4_UNITS_C = 1

ABSOLUTE_ZERO_C, MAX_SETPOINT_C = -273.15, 1000.0  # bounds on any limit a station may state

# --- the rig's own watch (not the controller's) ---------------------------------------------------
DEFAULT_MAX_DEVIATION_C = 5.0  # ours: air this far from a set point it had reached = lost control
RATE_WINDOW_S = 60.0  # the air's rate is measured over at least this long (a single read is too noisy)
RATE_TOLERANCE = 1.2  # measured rate may exceed max_ramp_c_per_min by 20 % (controller overshoot)


@validated_dataclass(frozen=True, config=ConfigDict(extra="forbid"))
class ChamberAlarm:
    """A station-given alarm register (hardware-notes document none for the F4T or F4 maps).

    register: holding-register address on the lab's controller, read with FC03 (one register).
    kind: "nonzero": any value other than 0 is an alarm, described by `meaning`;
          "bits": only the bits listed in `bits` (bit number 0..15 -> meaning) count, others are ignored.
    A pydantic dataclass, so a station model can hold it as a field (`alarm: ChamberAlarm | None`).
    """

    register: int = Field(ge=0, le=65535, strict=True)  # strict: `true` is no register number
    kind: Literal["nonzero", "bits"] = "nonzero"
    meaning: str = "alarm active"
    bits: dict[int, str] = Field(default_factory=dict, strict=True)

    @model_validator(mode="after")
    def _bits_match_kind(self):
        if self.kind == "bits" and not self.bits:
            raise ValueError("kind 'bits' needs `bits` (bit number -> meaning)")
        if self.kind == "nonzero" and self.bits:
            raise ValueError("`bits` is only for kind 'bits'")
        if bad := [b for b in self.bits if not 0 <= b <= 15]:
            raise ValueError(f"bit numbers must be 0..15, got {bad}")
        return self

    def active(self, word: int) -> list[str]:
        """What the register value says is wrong (empty: no alarm)."""
        if self.kind == "nonzero":
            return [self.meaning] if word else []
        return [f"bit {b} {text}" for b, text in sorted(self.bits.items()) if word >> b & 1]


def alarm_option(name: str, alarm: ChamberAlarm | Mapping | None) -> ChamberAlarm | None:
    """A ChamberAlarm from the station's mapping; bad fields raise OptionError naming the key."""
    if alarm is None or isinstance(alarm, ChamberAlarm):
        return alarm
    try:
        return TypeAdapter(ChamberAlarm).validate_python(dict(alarm))
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in ("alarm", *first["loc"]))
        raise OptionError(f"{name}: {where}: {first['msg']}") from None


@dataclass(frozen=True)
class ChamberReading:
    t: float
    air_c: float
    setpoint_c: float
    input_error: bool
    alarm: bool
    closed_loop_c: float | None = None  # F4T: the instantaneous set point during a ramp
    rate_c_per_min: float | None = None  # the air's rate over the last window (None until known)
    problems: tuple[str, ...] = ()  # each one line: "alarm: ...", "temperature input error ...", ...

    @property
    def fault(self) -> bool:
        return bool(self.problems) or self.alarm or self.input_error

    @property
    def problem(self) -> str:
        """All problems in one line ("" when there is none)."""
        return "; ".join(self.problems)


class ChamberLimits(registry.Options):
    """A chamber's options in the station file (`limits:`): what the driver refuses to command."""

    min_setpoint_c: float = Field(ge=ABSOLUTE_ZERO_C, le=MAX_SETPOINT_C)
    max_setpoint_c: float = Field(ge=ABSOLUTE_ZERO_C, le=MAX_SETPOINT_C)
    max_ramp_c_per_min: float = Field(gt=0, le=100.0)
    safe_setpoint_c: float = Field(25.0, ge=ABSOLUTE_ZERO_C, le=MAX_SETPOINT_C)
    max_deviation_c: float | None = Field(DEFAULT_MAX_DEVIATION_C, gt=0, le=1_000.0,
                                          description="None: not watched")

    @field_validator("max_setpoint_c")
    @classmethod
    def _above_min(cls, value: float, info: ValidationInfo) -> float:
        low = info.data.get("min_setpoint_c")
        if low is not None and value <= low:
            raise ValueError("must be above min_setpoint_c")
        return value

    @field_validator("safe_setpoint_c")
    @classmethod
    def _inside(cls, value: float, info: ValidationInfo) -> float:
        low, high = info.data.get("min_setpoint_c"), info.data.get("max_setpoint_c")
        if low is not None and high is not None and not low <= value <= high:
            raise ValueError("must lie between min_setpoint_c and max_setpoint_c")
        return value


class WatlowChamber(Device):
    """Limits, the rig's own watch, the optional alarm register, safe state and description."""

    kind = "chamber"
    model = "Watlow"
    ramps_setpoint = False  # True: set_ramp_rate() makes the controller ramp towards the next setpoint

    def __init__(
        self,
        transport: ModbusTransport,
        *,
        name: str,
        clock: Clock | None = None,
        min_setpoint_c: float,
        max_setpoint_c: float,
        max_ramp_c_per_min: float,
        safe_setpoint_c: float,
        alarm: ChamberAlarm | Mapping | None = None,
        max_deviation_c: float | None = DEFAULT_MAX_DEVIATION_C,
    ):
        super().__init__(name, clock)
        if not min_setpoint_c <= safe_setpoint_c <= max_setpoint_c:
            raise OptionError(
                f"{name}: safe_setpoint_c {safe_setpoint_c} is outside "
                f"[min_setpoint_c {min_setpoint_c}, max_setpoint_c {max_setpoint_c}]"
            )
        if max_deviation_c is not None and not max_deviation_c > 0:
            raise OptionError(f"{name}: max_deviation_c {max_deviation_c} must be positive (or None: off)")
        self.transport = transport
        self.min_setpoint_c = min_setpoint_c
        self.max_setpoint_c = max_setpoint_c
        self.max_ramp_c_per_min = max_ramp_c_per_min
        self.safe_setpoint_c = safe_setpoint_c
        self.alarm = alarm_option(name, alarm)
        self.max_deviation_c = max_deviation_c
        self._forget_history()

    def connect(self) -> None:
        self.transport.connect()
        self._forget_history()

    def close(self) -> None:
        self.transport.close()

    def set(self, setpoint_c: float) -> None:
        """Command a new setpoint; the limits are checked before anything is written."""
        self._check_setpoint(setpoint_c)
        self._write_setpoint(float(setpoint_c), f"write setpoint {setpoint_c:.1f} degC")
        self._reached_setpoint_c = None

    def safe_state(self) -> None:
        self._write_setpoint(self.safe_setpoint_c, f"write safe setpoint {self.safe_setpoint_c:.1f} degC")
        self._reached_setpoint_c = None

    def describe(self) -> dict:
        return {
            **super().describe(),
            "model": self.model,
            "min_setpoint_c": self.min_setpoint_c,
            "max_setpoint_c": self.max_setpoint_c,
            "max_ramp_c_per_min": self.max_ramp_c_per_min,
            "safe_setpoint_c": self.safe_setpoint_c,
            "max_deviation_c": self.max_deviation_c,
            "alarm": dataclasses.asdict(self.alarm) if self.alarm else None,
            **self.transport.describe(),
        }

    def _check_setpoint(self, setpoint_c: float) -> None:
        if isinstance(setpoint_c, bool) or not isinstance(setpoint_c, Real) or not math.isfinite(
                setpoint_c):
            raise LimitError(f"{self.name}: setpoint {setpoint_c} degC is not a number")
        where = f"{self.name}: setpoint {setpoint_c:.1f} degC"
        # written as "refuse unless provably inside": a NaN limit refuses every setpoint
        if not setpoint_c <= self.max_setpoint_c:
            raise LimitError(f"{where} is above max_setpoint_c {self.max_setpoint_c} degC")
        if not setpoint_c >= self.min_setpoint_c:
            raise LimitError(f"{where} is below min_setpoint_c {self.min_setpoint_c} degC")

    def _check_ramp(self, c_per_min: float) -> None:
        if isinstance(c_per_min, bool) or not isinstance(c_per_min, Real) or not (
                math.isfinite(c_per_min) and c_per_min > 0):
            raise LimitError(f"{self.name}: ramp rate {c_per_min} degC/min must be a positive number")
        if not c_per_min <= self.max_ramp_c_per_min:
            raise LimitError(
                f"{self.name}: ramp rate {c_per_min:g} degC/min is above max_ramp_c_per_min "
                f"{self.max_ramp_c_per_min:g} degC/min"
            )

    # --- the watch ----------------------------------------------------------------------------------
    def _forget_history(self) -> None:
        self._rate_ref: tuple[float, float] | None = None  # (t, air_c) at the start of the rate window
        self._rate_c_per_min: float | None = None
        self._reached_setpoint_c: float | None = None  # the set point the air has reached, if any

    def _watch(self, t: float, air_c: float, setpoint_c: float, input_error: bool, **extra) -> ChamberReading:
        """The reading with every problem the controller reports or the rig's limits show."""
        problems = []
        alarm_text = self._read_alarm()
        if alarm_text:
            problems.append(f"alarm: {alarm_text}")
        if input_error:
            problems.append(f"temperature input error (register {F4_INPUT_ERROR} reads 1)")
        rate = self._rate(t, air_c)
        if rate is not None and abs(rate) > self.max_ramp_c_per_min * RATE_TOLERANCE:
            problems.append(
                f"air changes at {rate:+.2f} degC/min, faster than max_ramp_c_per_min "
                f"{self.max_ramp_c_per_min:g}"
            )
        if deviation := self._deviation(air_c, setpoint_c):
            problems.append(deviation)
        return ChamberReading(
            t, air_c, setpoint_c, input_error, bool(alarm_text), rate_c_per_min=rate,
            problems=tuple(problems), **extra,
        )

    def _rate(self, t: float, air_c: float) -> float | None:
        if self._rate_ref is None:
            self._rate_ref = (t, air_c)
        t0, air0 = self._rate_ref
        if t - t0 >= RATE_WINDOW_S:
            self._rate_c_per_min = (air_c - air0) / (t - t0) * 60.0
            self._rate_ref = (t, air_c)
        return self._rate_c_per_min

    def _deviation(self, air_c: float, setpoint_c: float) -> str | None:
        """Air that had reached its set point and left it again by more than max_deviation_c. Until the
        air first reaches a (new) set point it is on its way there, which is no fault."""
        if self.max_deviation_c is None:
            return None
        if self._reached_setpoint_c is not None and abs(self._reached_setpoint_c - setpoint_c) > 0.05:
            self._reached_setpoint_c = None  # the set point was changed (front panel, another program)
        off_c = air_c - setpoint_c
        if self._reached_setpoint_c is None:
            if abs(off_c) <= self.max_deviation_c:
                self._reached_setpoint_c = setpoint_c
            return None
        if abs(off_c) <= self.max_deviation_c:
            return None
        return (
            f"air {air_c:.1f} degC left its set point {setpoint_c:.1f} degC by {off_c:+.1f} degC "
            f"(max_deviation_c {self.max_deviation_c:g})"
        )

    def _read_alarm(self) -> str:
        """'' when no alarm register is configured or it shows no alarm."""
        if self.alarm is None:
            return ""
        word = self.transport.read_holding(self.alarm.register, 1, operation="read alarm register")[0]
        active = self.alarm.active(word)
        return f"register {self.alarm.register} = 0x{word:04X} ({', '.join(active)})" if active else ""

    def _write_setpoint(self, setpoint_c: float, operation: str) -> None:
        raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class ChamberSettings:
    """What a chamber driver (and its simulator) is built with: the station's `limits:` and its
    optional `alarm:` register."""

    limits: ChamberLimits
    alarm: ChamberAlarm | None = None
