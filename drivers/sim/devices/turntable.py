"""Simulated 2-axis turntable (our map, drivers/turntable.py), a real pymodbus server.

    TurntableSim(world, unit=1, *, az_limits_deg=(-360.0, 360.0), el_limits_deg=(-90.0, 90.0),
                 homed=True, framing="tcp")

The move command sends the target registers to world.set_turntable_target; stop calls
world.stop_turntable; home drives to (0, 0) and sets the homed bit on arrival. Positions and status are
computed from the world lazily on each read. Targets outside the soft limits get exception 3.
Fault hooks: the server's, plus world.table_fault = True (drive fault: status fault bit, fault code 1,
moves ignored until the clear-fault command).
"""

from __future__ import annotations

from pymodbus.constants import ExcCodes
from pymodbus.simulator import SimDevice

from drivers import turntable as regs
from drivers.registry import SimModbus, SimRequest
from drivers.sim.devices.modbus_server import SimulatedModbusDevice, register_block, value_after_write
from drivers.sim.world import World
from drivers.transports.modbus import encode_string

FIRMWARE = (2, 0)
MODEL = "MAGRIG-TT2 sim"


class TurntableSim(SimulatedModbusDevice):
    def __init__(
        self,
        world: World,
        unit: int = 1,
        *,
        az_limits_deg: tuple[float, float] = (-360.0, 360.0),
        el_limits_deg: tuple[float, float] = (-90.0, 90.0),
        homed: bool = True,
        framing: str = "tcp",
    ):
        super().__init__(unit, framing)
        self.world = world
        self.soft_limits_deg = (*az_limits_deg, *el_limits_deg)
        self.homed = homed
        self._homing = False

    def sim_device(self) -> SimDevice:
        position = regs.angles_to_words(self.world.turntable_angles_deg())
        simdata = [
            register_block(regs.MODEL, encode_string(MODEL, regs.MODEL_REGISTERS), readonly=True),
            register_block(regs.FIRMWARE, FIRMWARE, readonly=True),
            register_block(regs.POSITION_MDEG, position, readonly=True),
            register_block(regs.TARGET_MDEG, position),
            register_block(regs.COMMAND, [0]),
            register_block(regs.STATUS, [0], readonly=True),
            register_block(regs.SOFT_LIMITS_MDEG, regs.angles_to_words(self.soft_limits_deg), readonly=True),
            register_block(regs.FAULT_CODE, [0], readonly=True),
        ]
        return SimDevice(id=self.unit, simdata=simdata, action=self._action)

    def status_word(self, target_deg) -> int:
        moving = self.world.turntable_moving()
        if self._homing and not moving:
            self._homing, self.homed = False, True
        at = self.world.turntable_angles_deg()
        word = regs.STATUS_MOVING if moving else 0
        if not moving and all(
            abs(a - t) < 0.5 / regs.MDEG_PER_DEG for a, t in zip(at, target_deg, strict=True)
        ):
            word |= regs.STATUS_IN_POSITION
        if self.world.table_fault:
            word |= regs.STATUS_FAULT
        if self.homed:
            word |= regs.STATUS_HOMED
        return word

    async def _action(self, function_code, start, address, count, registers, set_values):
        def put(reg: int, words: list[int]) -> None:
            registers[reg - start : reg - start + len(words)] = words

        def target_deg(value=lambda reg: registers[reg - start]):
            return regs.words_to_angles([value(regs.TARGET_MDEG + i) for i in range(4)])

        if set_values is None:
            put(regs.POSITION_MDEG, regs.angles_to_words(self.world.turntable_angles_deg()))
            put(regs.STATUS, [self.status_word(target_deg())])
            put(regs.FAULT_CODE, [regs.FAULT_DRIVE if self.world.table_fault else regs.FAULT_NONE])
            return None
        value = value_after_write(registers, start, address, set_values)
        written = set(range(address, address + len(set_values)))
        if written & set(range(regs.TARGET_MDEG, regs.TARGET_MDEG + 4)):
            az, el = target_deg(value)
            az_min, az_max, el_min, el_max = self.soft_limits_deg
            if not (az_min <= az <= az_max and el_min <= el <= el_max):
                return ExcCodes.ILLEGAL_VALUE
        if regs.COMMAND in written:
            result = self._command(value(regs.COMMAND), target_deg(value), put)
            set_values[regs.COMMAND - address] = 0  # a command register reads back 0
            return result
        return None

    def _command(self, command: int, target_deg, put) -> ExcCodes | None:
        if command == regs.COMMAND_CLEAR_FAULT:
            self.world.table_fault = False
        elif command == regs.COMMAND_STOP:
            self.world.stop_turntable()
            put(regs.TARGET_MDEG, regs.angles_to_words(self.world.turntable_angles_deg()))
        elif self.world.table_fault:
            return None  # a faulted drive ignores motion commands; the status shows why
        elif command == regs.COMMAND_MOVE:
            self.world.set_turntable_target(*target_deg)
        elif command == regs.COMMAND_HOME:
            self._homing = True
            self.world.set_turntable_target(0.0, 0.0)
            put(regs.TARGET_MDEG, [0, 0, 0, 0])
        else:
            return ExcCodes.ILLEGAL_VALUE
        return None


def simulate(req: SimRequest) -> SimModbus:
    return SimModbus(TurntableSim(req.world, req.unit, az_limits_deg=req.options.az_limits_deg,
                                  el_limits_deg=req.options.el_limits_deg))
