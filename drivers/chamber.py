"""Watlow F4T and legacy F4 thermal-chamber controllers over Modbus (TCP or RTU).

Construct (the station YAML maps onto these keywords; `transport` is a drivers.transports.modbus
ModbusTransport built from the station's link settings):

    WatlowF4T(transport, *, name, clock, min_setpoint_c, max_setpoint_c, max_ramp_c_per_min,
              safe_setpoint_c, word_order="little",
              alarm_register=ALARM_REGISTER, input_error_register=F4T_INPUT_ERROR_REGISTER)
    WatlowF4(transport, *, name, clock, min_setpoint_c, max_setpoint_c, max_ramp_c_per_min,
             safe_setpoint_c, alarm_register=ALARM_REGISTER)

Both: connect(), close(), set(setpoint_c), set_ramp_rate(c_per_min), read() -> ChamberReading,
safe_state() (setpoint -> safe_setpoint_c), describe().

Alarms are *reported*, not raised: read() returns `alarm` and `input_error` flags and the engine decides
to hold (ChamberReading.fault is True when either is set). A chamber in alarm may still need a safe
setpoint written, which a raising read() would get in the way of.

The controllers are assumed to be set to degrees C (TestEquity ships them so); the legacy F4's units
register (901) is read at connect and a controller in degrees F is converted.
Register maps: docs/modbus-maps.md. Addresses marked "ours" there are not from Watlow's documents.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pydantic import Field, ValidationInfo, field_validator

from drivers import registry
from drivers.base import Device
from drivers.clock import Clock
from drivers.errors import LimitError, OptionError
from drivers.transports.modbus import ModbusTransport, WordOrder, decode_int16

# --- F4T, Data Map 1 (float32, low word first by default) -----------------------------------------
F4T_SETPOINT = 2782  # RW float32, temperature set point
F4T_RAMP_ACTION = 2794  # RW uint16: off 62, startup 88, set point 85, both 13
F4T_RAMP_SCALE = 2796  # RW uint16: degrees per minute 57, per hour 39
F4T_RAMP_RATE = 2798  # RW float32
F4T_CLOSED_LOOP_SETPOINT = 2810  # R float32, instantaneous set point during a ramp
F4T_CHAMBER_TEMP = 27586  # R float32, actual chamber temperature
RAMP_OFF, RAMP_ON_SETPOINT = 62, 85
RAMP_SCALE_PER_MINUTE, RAMP_SCALE_PER_HOUR = 57, 39
F4T_INPUT_ERROR_REGISTER = 60001  # ours: R uint16, 0 ok / 1 temperature input error

# --- legacy F4 (int16, scaled by the display precision) -------------------------------------------
F4_TEMP = 100  # R int16, input 1 (chamber temperature)
F4_INPUT_ERROR = 101  # R 0/1
F4_SETPOINT = 300  # RW int16, set point 1
F4_PRECISION = 606  # RW 0..3 decimals: the int16 values carry that many implied decimals
F4_UNITS = 901  # RW: 1 degC, 0 degF
F4_UNITS_C = 1

# --- both maps ------------------------------------------------------------------------------------
ALARM_REGISTER = 60000  # ours: R uint16 alarm summary, 0 none / 1 an alarm is active


@dataclass(frozen=True)
class ChamberReading:
    t: float
    air_c: float
    setpoint_c: float
    input_error: bool
    alarm: bool

    @property
    def fault(self) -> bool:
        return self.alarm or self.input_error


class ChamberLimits(registry.Options):
    """A chamber's options in the station file (`limits:`): what the driver refuses to command."""

    min_setpoint_c: float
    max_setpoint_c: float
    max_ramp_c_per_min: float = Field(gt=0)
    safe_setpoint_c: float = 25.0

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


class _WatlowChamber(Device):
    """Limits, safe state and description shared by both register maps."""

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
        alarm_register: int | None = ALARM_REGISTER,
    ):
        super().__init__(name, clock)
        if not min_setpoint_c <= safe_setpoint_c <= max_setpoint_c:
            raise OptionError(
                f"{name}: safe_setpoint_c {safe_setpoint_c} is outside "
                f"[min_setpoint_c {min_setpoint_c}, max_setpoint_c {max_setpoint_c}]"
            )
        self.transport = transport
        self.min_setpoint_c = min_setpoint_c
        self.max_setpoint_c = max_setpoint_c
        self.max_ramp_c_per_min = max_ramp_c_per_min
        self.safe_setpoint_c = safe_setpoint_c
        self.alarm_register = alarm_register

    def connect(self) -> None:
        self.transport.connect()

    def close(self) -> None:
        self.transport.close()

    def set(self, setpoint_c: float) -> None:
        """Command a new setpoint; the limits are checked before anything is written."""
        self._check_setpoint(setpoint_c)
        self._write_setpoint(float(setpoint_c), f"write setpoint {setpoint_c:.1f} degC")

    def safe_state(self) -> None:
        self._write_setpoint(self.safe_setpoint_c, f"write safe setpoint {self.safe_setpoint_c:.1f} degC")

    def describe(self) -> dict:
        return {
            **super().describe(),
            "model": self.model,
            "min_setpoint_c": self.min_setpoint_c,
            "max_setpoint_c": self.max_setpoint_c,
            "max_ramp_c_per_min": self.max_ramp_c_per_min,
            "safe_setpoint_c": self.safe_setpoint_c,
            **self.transport.describe(),
        }

    def _check_setpoint(self, setpoint_c: float) -> None:
        if not math.isfinite(setpoint_c):
            raise LimitError(f"{self.name}: setpoint {setpoint_c} degC is not a number")
        where = f"{self.name}: setpoint {setpoint_c:.1f} degC"
        if setpoint_c > self.max_setpoint_c:
            raise LimitError(f"{where} is above max_setpoint_c {self.max_setpoint_c} degC")
        if setpoint_c < self.min_setpoint_c:
            raise LimitError(f"{where} is below min_setpoint_c {self.min_setpoint_c} degC")

    def _check_ramp(self, c_per_min: float) -> None:
        if not (math.isfinite(c_per_min) and c_per_min > 0):
            raise LimitError(f"{self.name}: ramp rate {c_per_min} degC/min must be a positive number")
        if c_per_min > self.max_ramp_c_per_min:
            raise LimitError(
                f"{self.name}: ramp rate {c_per_min:g} degC/min is above max_ramp_c_per_min "
                f"{self.max_ramp_c_per_min:g} degC/min"
            )

    def _read_alarm(self) -> bool:
        if self.alarm_register is None:
            return False
        return self.transport.read_holding(self.alarm_register, 1, operation="read alarm state")[0] != 0

    def _write_setpoint(self, setpoint_c: float, operation: str) -> None:
        raise NotImplementedError


class WatlowF4T(_WatlowChamber):
    """Watlow F4T, Data Map 1: float32 registers, low word first unless the controller is set otherwise."""

    model = "Watlow F4T (data map 1)"
    ramps_setpoint = True

    def __init__(
        self,
        transport: ModbusTransport,
        *,
        word_order: WordOrder = "little",
        input_error_register: int | None = F4T_INPUT_ERROR_REGISTER,
        **limits,
    ):
        super().__init__(transport, **limits)
        self.word_order = word_order
        self.input_error_register = input_error_register

    def set_ramp_rate(self, c_per_min: float) -> None:
        """Ramp the setpoint at c_per_min (manual ramp on set point changes)."""
        self._check_ramp(c_per_min)
        op = f"write ramp rate {c_per_min:g} degC/min"
        self.transport.write_register(F4T_RAMP_SCALE, RAMP_SCALE_PER_MINUTE, operation=op)
        self.transport.write_float32(F4T_RAMP_RATE, c_per_min, word_order=self.word_order, operation=op)
        self.transport.write_register(F4T_RAMP_ACTION, RAMP_ON_SETPOINT, operation=op)

    def read(self) -> ChamberReading:
        t = self.clock.now()
        air_c = self.transport.read_float32(
            F4T_CHAMBER_TEMP, word_order=self.word_order, operation="read chamber temperature"
        )
        setpoint_c = self.transport.read_float32(
            F4T_SETPOINT, word_order=self.word_order, operation="read setpoint"
        )
        input_error = self.input_error_register is not None and (
            self.transport.read_holding(self.input_error_register, 1, operation="read input error")[0] != 0
        )
        return ChamberReading(t, air_c, setpoint_c, input_error, self._read_alarm())

    def describe(self) -> dict:
        return {**super().describe(), "word_order": self.word_order}

    def _write_setpoint(self, setpoint_c: float, operation: str) -> None:
        self.transport.write_float32(
            F4T_SETPOINT, setpoint_c, word_order=self.word_order, operation=operation
        )


class WatlowF4(_WatlowChamber):
    """Legacy Watlow F4: int16 registers whose implied decimals come from the precision register 606."""

    model = "Watlow F4 (legacy map)"

    def __init__(self, transport: ModbusTransport, **limits):
        super().__init__(transport, **limits)
        self.decimals: int | None = None
        self.units_c = True

    def connect(self) -> None:
        super().connect()
        self._load_scaling()

    def set_ramp_rate(self, c_per_min: float) -> None:
        self._check_ramp(c_per_min)
        raise OptionError(
            f"{self.name}: the legacy F4 register map has no ramp-rate register; "
            "leave the ramp rate unset for this chamber or use the F4T map"
        )

    def read(self) -> ChamberReading:
        self._load_scaling()
        t = self.clock.now()
        temp_word, error_word = self.transport.read_holding(F4_TEMP, 2, operation="read chamber temperature")
        sp_word = self.transport.read_holding(F4_SETPOINT, 1, operation="read setpoint")[0]
        return ChamberReading(
            t, self._to_c(temp_word), self._to_c(sp_word), error_word != 0, self._read_alarm()
        )

    def describe(self) -> dict:
        return {**super().describe(), "decimals": self.decimals, "units": "C" if self.units_c else "F"}

    def _load_scaling(self) -> None:
        if self.decimals is not None:
            return
        decimals = self.transport.read_holding(F4_PRECISION, 1, operation="read display precision")[0]
        if decimals > 3:
            raise OptionError(
                f"{self.name}: precision register {F4_PRECISION} reads {decimals}, expected 0..3"
            )
        units = self.transport.read_holding(F4_UNITS, 1, operation="read temperature units")[0]
        self.decimals, self.units_c = decimals, units == F4_UNITS_C

    def _to_c(self, word: int) -> float:
        value = decode_int16(word) / 10**self.decimals
        return value if self.units_c else (value - 32.0) * 5.0 / 9.0

    def _write_setpoint(self, setpoint_c: float, operation: str) -> None:
        self._load_scaling()
        value = setpoint_c if self.units_c else setpoint_c * 9.0 / 5.0 + 32.0
        scaled = round(value * 10**self.decimals)
        if not -32768 <= scaled <= 32767:
            raise LimitError(
                f"{self.name}: setpoint {setpoint_c:.1f} degC does not fit the F4's int16 register "
                f"at {self.decimals} decimals"
            )
        self.transport.write_int16(F4_SETPOINT, scaled, operation=operation)


# --- registration -----------------------------------------------------------------------------------
def _builder(cls):
    def build(link: ModbusTransport, limits: ChamberLimits, *, name: str, clock: Clock, **_) -> Device:
        return cls(link, name=name, clock=clock, **limits.model_dump())

    return build


registry.register(registry.DeviceSpec(
    role="chamber", type="watlow_f4t", options=ChamberLimits, transports=registry.MODBUS_KINDS,
    build=_builder(WatlowF4T), simulator="drivers.sim.chamber:simulate"))
registry.register(registry.DeviceSpec(
    role="chamber", type="watlow_f4", options=ChamberLimits, transports=registry.MODBUS_KINDS,
    build=_builder(WatlowF4), simulator="drivers.sim.chamber:simulate"))
