"""Simulated Watlow chamber controller: a real pymodbus server whose registers drive and show the World.

    ChamberSim(world, register_map="f4t" | "f4", unit=1, *, word_order="little", decimals=1,
               units_c=True, range_c=(-73.0, 175.0), framing="tcp", alarm=None)

Only registers documented in hardware-notes 3.1 (F4) and 3.2 (F4T) exist; any other address gets
exception 2 (illegal data address), as from a real controller. `alarm` (a drivers.chamber.ChamberAlarm)
adds the register a lab's station names for its alarm; without it there is none, as in the documents.

A setpoint write moves world.set_chamber_setpoint (out-of-range values get exception 3, as a real
controller refuses them); F4T ramp writes set world.set_chamber_ramp (ramp off = the chamber's natural
rate, the world's ramp at construction). Reads refresh the temperature, setpoint and alarm registers
from the world lazily, so a SimClock may jump. Fault hooks: the server's (silence, fail_next, unplug,
replug, `faults`), world.chamber_alarm or an alarm window of `faults` -> the configured alarm register
(the first of its bits, or 1), and
`input_error = True` -> the F4's input error register 101 (the F4T documents none).
"""

from __future__ import annotations

import math

from pymodbus.constants import ExcCodes
from pymodbus.simulator import SimData, SimDevice

from drivers import chamber as regs
from drivers.chamber import ChamberAlarm
from drivers.registry import SimModbus, SimRequest
from drivers.sim.devices.modbus_server import SimulatedModbusDevice, register_block, value_after_write
from drivers.sim.world import World
from drivers.transports.modbus import decode_float32, decode_int16, encode_float32, encode_int16

RAMP_REGISTERS = {regs.F4T_RAMP_ACTION, regs.F4T_RAMP_SCALE, regs.F4T_RAMP_RATE, regs.F4T_RAMP_RATE + 1}


class ChamberSim(SimulatedModbusDevice):
    def __init__(
        self,
        world: World,
        register_map: str = "f4t",
        unit: int = 1,
        *,
        word_order: str = "little",
        decimals: int = 1,
        units_c: bool = True,
        range_c: tuple[float, float] = (-73.0, 175.0),
        framing: str = "tcp",
        alarm: ChamberAlarm | None = None,
    ):
        if register_map not in ("f4t", "f4"):
            raise ValueError(f"register_map must be 'f4t' or 'f4', not {register_map!r}")
        super().__init__(unit, framing)
        self.world = world
        self.register_map = register_map
        self.word_order = word_order
        self.initial_decimals = decimals
        self.units_c = units_c
        self.range_c = range_c
        self.natural_ramp_c_per_min = world.ramp_c_per_min
        self.input_error = False
        self.alarm = alarm

    def sim_device(self) -> SimDevice:
        if self.register_map == "f4t":
            return SimDevice(id=self.unit, simdata=self._f4t_registers(), action=self._f4t_action)
        return SimDevice(id=self.unit, simdata=self._f4_registers(), action=self._f4_action)

    # --- shared -----------------------------------------------------------------------------------
    def _setpoint_ok(self, setpoint_c: float) -> bool:
        return math.isfinite(setpoint_c) and self.range_c[0] <= setpoint_c <= self.range_c[1]

    def _alarm_word(self) -> int:
        if not (self.world.chamber_alarm or (self.faults is not None and self.faults.alarm())):
            return 0
        return 1 << min(self.alarm.bits) if self.alarm.kind == "bits" else 1

    def _alarm_blocks(self) -> list[SimData]:
        return [register_block(self.alarm.register, [0], readonly=True)] if self.alarm else []

    def _refresh_alarm(self, registers: list[int], start: int, address: int, count: int) -> None:
        if self.alarm and address <= self.alarm.register < address + count:
            registers[self.alarm.register - start] = self._alarm_word()

    # --- F4T data map 1 ---------------------------------------------------------------------------
    def _f4(self, value: float) -> list[int]:
        return encode_float32(value, self.word_order)

    def _f4t_registers(self) -> list[SimData]:
        air_c = self.world.chamber_air_c()
        return [
            register_block(regs.F4T_SETPOINT, self._f4(self.world.setpoint_c)),
            register_block(regs.F4T_RAMP_ACTION, [regs.RAMP_OFF]),
            register_block(regs.F4T_RAMP_SCALE, [regs.RAMP_SCALE_PER_MINUTE]),
            register_block(regs.F4T_RAMP_RATE, self._f4(self.natural_ramp_c_per_min)),
            register_block(regs.F4T_CLOSED_LOOP_SETPOINT, self._f4(self.world.setpoint_c), readonly=True),
            register_block(regs.F4T_CHAMBER_TEMP, self._f4(air_c), readonly=True),
            *self._alarm_blocks(),
        ]

    async def _f4t_action(self, function_code, start, address, count, registers, set_values):
        def put(reg: int, words: list[int]) -> None:
            registers[reg - start : reg - start + len(words)] = words

        if set_values is None:  # a read: bring the live registers up to the world's present
            put(regs.F4T_CHAMBER_TEMP, self._f4(self.world.chamber_air_c()))
            put(regs.F4T_CLOSED_LOOP_SETPOINT, self._f4(self.world.setpoint_c))
            self._refresh_alarm(registers, start, address, count)
            return None
        value = value_after_write(registers, start, address, set_values)
        written = set(range(address, address + len(set_values)))
        if written & {regs.F4T_SETPOINT, regs.F4T_SETPOINT + 1}:
            setpoint_c = decode_float32(
                [value(regs.F4T_SETPOINT), value(regs.F4T_SETPOINT + 1)], self.word_order
            )
            if not self._setpoint_ok(setpoint_c):
                return ExcCodes.ILLEGAL_VALUE
            self.world.set_chamber_setpoint(setpoint_c)
        if written & RAMP_REGISTERS:
            return self._apply_ramp(value)
        return None

    def _apply_ramp(self, value) -> ExcCodes | None:
        action, scale = value(regs.F4T_RAMP_ACTION), value(regs.F4T_RAMP_SCALE)
        rate = decode_float32([value(regs.F4T_RAMP_RATE), value(regs.F4T_RAMP_RATE + 1)], self.word_order)
        if scale not in (regs.RAMP_SCALE_PER_MINUTE, regs.RAMP_SCALE_PER_HOUR):
            return ExcCodes.ILLEGAL_VALUE
        if not (math.isfinite(rate) and rate > 0):
            return ExcCodes.ILLEGAL_VALUE
        rate_per_min = rate if scale == regs.RAMP_SCALE_PER_MINUTE else rate / 60.0
        ramping = action in (regs.RAMP_ON_SETPOINT, regs.RAMP_BOTH)
        # the chamber cannot ramp faster than its heater and compressor allow
        self.world.set_chamber_ramp(
            min(rate_per_min, self.natural_ramp_c_per_min) if ramping else self.natural_ramp_c_per_min
        )
        return None

    # --- legacy F4 --------------------------------------------------------------------------------
    def _to_word(self, temp_c: float, decimals: int) -> int:
        value = temp_c if self.units_c else temp_c * 9.0 / 5.0 + 32.0
        return encode_int16(max(-32768, min(32767, round(value * 10**decimals))))

    def _f4_registers(self) -> list[SimData]:
        d = self.initial_decimals
        return [
            register_block(regs.F4_TEMP, [self._to_word(self.world.chamber_air_c(), d), 0], readonly=True),
            register_block(regs.F4_SETPOINT, [self._to_word(self.world.setpoint_c, d)]),
            register_block(regs.F4_PRECISION, [d]),
            register_block(regs.F4_UNITS, [regs.F4_UNITS_C if self.units_c else 0], readonly=True),
            *self._alarm_blocks(),
        ]

    async def _f4_action(self, function_code, start, address, count, registers, set_values):
        decimals = registers[regs.F4_PRECISION - start]
        if set_values is None:
            registers[regs.F4_TEMP - start] = self._to_word(self.world.chamber_air_c(), decimals)
            registers[regs.F4_INPUT_ERROR - start] = int(self.input_error)
            registers[regs.F4_SETPOINT - start] = self._to_word(self.world.setpoint_c, decimals)
            self._refresh_alarm(registers, start, address, count)
            return None
        value = value_after_write(registers, start, address, set_values)
        written = range(address, address + len(set_values))
        if regs.F4_PRECISION in written and value(regs.F4_PRECISION) > 3:
            return ExcCodes.ILLEGAL_VALUE
        if regs.F4_SETPOINT in written:
            setpoint = decode_int16(value(regs.F4_SETPOINT)) / 10 ** value(regs.F4_PRECISION)
            setpoint_c = setpoint if self.units_c else (setpoint - 32.0) * 5.0 / 9.0
            if not self._setpoint_ok(setpoint_c):
                return ExcCodes.ILLEGAL_VALUE
            self.world.set_chamber_setpoint(setpoint_c)
        return None


def simulate(req: SimRequest) -> SimModbus:
    """The station's simulated chamber: the register map follows the chamber type; an alarm register
    is served only where the station names one (req.options is a drivers.chamber.ChamberSettings)."""
    register_map = "f4t" if req.type == "watlow_f4t" else "f4"
    return SimModbus(ChamberSim(req.world, register_map, req.unit, alarm=req.options.alarm))
