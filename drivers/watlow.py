"""Watlow F4T (Data Map 1, float32) and legacy F4 (int16) thermal-chamber controllers over Modbus (TCP or
RTU), registered as chamber types `watlow_f4t` and `watlow_f4`. Their register maps and what they share
are in drivers/chamber.py; docs/modbus-maps.md lists the maps.

    WatlowF4T(transport, *, name, clock, min_setpoint_c, max_setpoint_c, max_ramp_c_per_min,
              safe_setpoint_c, word_order="little", alarm=None, max_deviation_c=5.0)
    WatlowF4(transport, *, name, clock, min_setpoint_c, max_setpoint_c, max_ramp_c_per_min,
             safe_setpoint_c, alarm=None, max_deviation_c=5.0)
"""

from __future__ import annotations

from drivers import registry
from drivers.base import Device
from drivers.chamber import (
    F4_PRECISION,
    F4_SETPOINT,
    F4_TEMP,
    F4_UNITS,
    F4_UNITS_C,
    F4T_CHAMBER_TEMP,
    F4T_CLOSED_LOOP_SETPOINT,
    F4T_RAMP_ACTION,
    F4T_RAMP_RATE,
    F4T_RAMP_SCALE,
    F4T_SETPOINT,
    RAMP_ON_SETPOINT,
    RAMP_SCALE_PER_MINUTE,
    ChamberLimits,
    ChamberReading,
    ChamberSettings,
    WatlowChamber,
)
from drivers.clock import Clock
from drivers.errors import LimitError, OptionError
from drivers.transports.modbus import ModbusTransport, WordOrder, decode_int16


class WatlowF4T(WatlowChamber):
    """Watlow F4T, Data Map 1: float32 registers, low word first unless the controller is set otherwise."""

    model = "Watlow F4T (data map 1)"
    ramps_setpoint = True

    def __init__(self, transport: ModbusTransport, *, word_order: WordOrder = "little", **options):
        super().__init__(transport, **options)
        self.word_order = word_order

    def set_ramp_rate(self, c_per_min: float) -> None:
        """Ramp the setpoint at c_per_min (manual ramp on set point changes)."""
        self._check_ramp(c_per_min)
        op = f"write ramp rate {c_per_min:g} degC/min"
        self.transport.write_register(F4T_RAMP_SCALE, RAMP_SCALE_PER_MINUTE, operation=op)
        self.transport.write_float32(F4T_RAMP_RATE, c_per_min, word_order=self.word_order, operation=op)
        self.transport.write_register(F4T_RAMP_ACTION, RAMP_ON_SETPOINT, operation=op)

    def read(self) -> ChamberReading:
        t = self.clock.now()
        air_c = self._read_float(F4T_CHAMBER_TEMP, "read chamber temperature")
        setpoint_c = self._read_float(F4T_SETPOINT, "read setpoint")
        closed_loop_c = self._read_float(F4T_CLOSED_LOOP_SETPOINT, "read closed-loop setpoint")
        # hardware-notes 3.2 document no input-error register for data map 1: none is read.
        return self._watch(t, air_c, setpoint_c, False, closed_loop_c=closed_loop_c)

    def describe(self) -> dict:
        return {**super().describe(), "word_order": self.word_order}

    def _read_float(self, register: int, operation: str) -> float:
        return self.transport.read_float32(register, word_order=self.word_order, operation=operation)

    def _write_setpoint(self, setpoint_c: float, operation: str) -> None:
        self.transport.write_float32(
            F4T_SETPOINT, setpoint_c, word_order=self.word_order, operation=operation
        )


class WatlowF4(WatlowChamber):
    """Legacy Watlow F4: int16 registers whose implied decimals come from the precision register 606."""

    model = "Watlow F4 (legacy map)"

    def __init__(self, transport: ModbusTransport, **options):
        super().__init__(transport, **options)
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
        return self._watch(t, self._to_c(temp_word), self._to_c(sp_word), error_word != 0)

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


def _builder(cls):
    def build(link: ModbusTransport, settings: ChamberSettings, *, name: str, clock: Clock, **_) -> Device:
        return cls(link, name=name, clock=clock, alarm=settings.alarm, **settings.limits.model_dump())

    return build


registry.register(registry.DeviceSpec(
    role="chamber", type="watlow_f4t", options=ChamberLimits, transports=registry.MODBUS_KINDS,
    build=_builder(WatlowF4T), simulator="drivers.sim.devices.chamber:simulate"))
registry.register(registry.DeviceSpec(
    role="chamber", type="watlow_f4", options=ChamberLimits, transports=registry.MODBUS_KINDS,
    build=_builder(WatlowF4), simulator="drivers.sim.devices.chamber:simulate"))
