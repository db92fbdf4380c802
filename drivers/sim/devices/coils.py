"""Simulated 3-axis coil current controller (our map, drivers/coils.py), a real pymodbus server.

    CoilSim(world, unit=1, *, compliance_limit_a=2.0, rated_current_a=3.0, settle_tau_s=0.05,
            framing="tcp")

Physics: each channel drives min(|setpoint|, compliance limit) with the setpoint's sign while its output
is on and it has no over-temperature fault; the world gets those currents at once
(world.set_coil_currents), and the regulation approaches them with a first-order lag of settle_tau_s on
the world's clock. The read-back registers show the regulated current as the world's current source
reports it (world.coil_readback_a: exact, unless the station gives `sim.current_source` errors); the
settled bit judges the regulation itself. A setpoint beyond the compliance limit sets the compliance
bit (the field is then not what was asked). Setpoints beyond the rating get exception 3.
Fault hooks: the server's, plus trip_over_temperature(axis) (latched until the clear-faults command).
"""

from __future__ import annotations

import math

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.simulator import SimDevice

from drivers import coils as regs
from drivers.registry import SimModbus, SimRequest
from drivers.sim.devices.modbus_server import SimulatedModbusDevice, register_block, value_after_write
from drivers.sim.world import World
from drivers.transports.modbus import encode_string

FIRMWARE = (1, 2)
MODEL = "MAGRIG-HC3 sim"
SETTLED_TOL_A = 1e-4


class CoilSim(SimulatedModbusDevice):
    def __init__(
        self,
        world: World,
        unit: int = 1,
        *,
        compliance_limit_a: float = 2.0,
        rated_current_a: float = 3.0,
        settle_tau_s: float = 0.05,
        framing: str = "tcp",
    ):
        super().__init__(unit, framing)
        self.world = world
        self.compliance_limit_a = compliance_limit_a
        self.rated_current_a = rated_current_a
        self.settle_tau_s = settle_tau_s
        self.setpoints_a = np.zeros(3)
        self.enabled = np.zeros(3, bool)
        self.over_temperature = np.zeros(3, bool)
        # readback lag: it moves from _from_a toward the output since _t0
        self._from_a = np.zeros(3)
        self._t0 = world.clock.now()

    def sim_device(self) -> SimDevice:
        limit_words = regs.currents_to_words([self.compliance_limit_a] * 3)
        simdata = [
            register_block(regs.MODEL, encode_string(MODEL, regs.MODEL_REGISTERS), readonly=True),
            register_block(regs.FIRMWARE, [*FIRMWARE, round(self.rated_current_a * 1000)], readonly=True),
            register_block(regs.SETPOINT_UA, [0] * 6),
            register_block(regs.READBACK_UA, [0] * 6, readonly=True),
            register_block(regs.OUTPUT_ENABLE, [0] * 3),
            register_block(regs.STATUS, [0] * 3, readonly=True),
            register_block(regs.COMPLIANCE_LIMIT_UA, limit_words, readonly=True),
            register_block(regs.COMMAND, [0]),
        ]
        return SimDevice(id=self.unit, simdata=simdata, action=self._action)

    # --- physics ----------------------------------------------------------------------------------
    def output_a(self) -> np.ndarray:
        """What each channel actually drives now."""
        on = self.enabled & ~self.over_temperature
        clamped = np.clip(self.setpoints_a, -self.compliance_limit_a, self.compliance_limit_a)
        return np.where(on, clamped, 0.0)

    def regulated_a(self) -> np.ndarray:
        """Where the regulation loop is now, on its way to output_a()."""
        dt = max(0.0, self.world.clock.now() - self._t0)
        target = self.output_a()
        return target + (self._from_a - target) * math.exp(-dt / self.settle_tau_s)

    def readback_a(self) -> np.ndarray:
        return self.world.coil_readback_a(self.regulated_a())

    def _before_change(self) -> None:
        """Restart the regulation's lag from where it is now."""
        self._from_a = self.regulated_a()
        self._t0 = self.world.clock.now()

    def _after_change(self) -> None:
        on = self.enabled & ~self.over_temperature
        self.world.set_coil_currents(self.output_a(), enabled=bool(np.any(on)), outputs_on=on)

    def trip_over_temperature(self, axis: int) -> None:
        """Fault hook: the channel's driver overheats; its output goes off until faults are cleared."""
        self._before_change()
        self.over_temperature[axis] = True
        self.enabled[axis] = False
        self._after_change()

    def status_words(self) -> list[int]:
        readback, out = self.regulated_a(), self.output_a()
        words = []
        for i in range(3):
            word = regs.STATUS_OUTPUT_ON if self.enabled[i] and not self.over_temperature[i] else 0
            if abs(readback[i] - out[i]) <= SETTLED_TOL_A:
                word |= regs.STATUS_SETTLED
            if self.over_temperature[i]:
                word |= regs.STATUS_OVER_TEMPERATURE
            if self.enabled[i] and abs(self.setpoints_a[i]) > self.compliance_limit_a:
                word |= regs.STATUS_COMPLIANCE
            words.append(word)
        return words

    # --- protocol ---------------------------------------------------------------------------------
    async def _action(self, function_code, start, address, count, registers, set_values):
        def put(reg: int, words: list[int]) -> None:
            registers[reg - start : reg - start + len(words)] = words

        if set_values is None:
            put(regs.READBACK_UA, regs.currents_to_words(self.readback_a()))
            put(regs.STATUS, self.status_words())
            put(regs.OUTPUT_ENABLE, [int(e) for e in self.enabled])
            return None
        value = value_after_write(registers, start, address, set_values)
        written = set(range(address, address + len(set_values)))
        if written & set(range(regs.SETPOINT_UA, regs.SETPOINT_UA + 6)):
            setpoints = np.array(regs.words_to_currents([value(regs.SETPOINT_UA + i) for i in range(6)]))
            if np.any(np.abs(setpoints) > self.rated_current_a):
                return ExcCodes.ILLEGAL_VALUE
            self._before_change()
            self.setpoints_a[:] = setpoints
            self._after_change()
        if written & set(range(regs.OUTPUT_ENABLE, regs.OUTPUT_ENABLE + 3)):
            enable = [value(regs.OUTPUT_ENABLE + i) for i in range(3)]
            if any(e not in (0, 1) for e in enable):
                return ExcCodes.ILLEGAL_VALUE
            self._before_change()
            self.enabled[:] = np.array(enable, bool) & ~self.over_temperature
            self._after_change()
        if regs.COMMAND in written:
            if value(regs.COMMAND) != regs.COMMAND_CLEAR_FAULTS:
                return ExcCodes.ILLEGAL_VALUE
            self._before_change()
            self.over_temperature[:] = False
            self._after_change()
            set_values[regs.COMMAND - address] = 0  # a command register reads back 0
        return None


def simulate(req: SimRequest) -> SimModbus:
    """A controller rated above the station's max_current_a, so the driver's own limit is what bites."""
    limit = req.options.max_current_a
    return SimModbus(CoilSim(req.world, req.unit, compliance_limit_a=max(2.0, limit),
                             rated_current_a=max(3.0, limit)))
