"""2-axis (azimuth, elevation) non-magnetic turntable over Modbus (our register map, docs/modbus-maps.md).

Construct (the station YAML maps onto these keywords; `transport` is a ModbusTransport):

    Turntable(transport, *, name, clock, az_limits_deg=(min, max), el_limits_deg=(min, max),
              poll_s=0.05, tol_deg=0.01)

set((az_deg, el_deg)) checks the station limits, refuses to move an unhomed or faulted table
(DeviceFault), writes both targets, then the move command. wait_settled(timeout_s) polls until the
table reports in-position at the commanded angles (DeviceFault on a drive fault, DeviceTimeout after
timeout_s on the injected clock). home() starts homing (wait_settled waits for it), stop() stops both
axes where they are, safe_state() = stop().
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real

import numpy as np
from pydantic import Field, field_validator

from drivers import registry
from drivers.base import Device, wait_until
from drivers.clock import Clock
from drivers.errors import DeviceFault, DeviceTimeout, LimitError, ProtocolError
from drivers.transports.modbus import ModbusTransport, decode_int32, encode_int32

MODEL_PREFIX = "MAGRIG-TT2"

# --- register map (holding registers; int32 values are two registers, high word first) ------------
MODEL = 0  # R string, 8 registers
MODEL_REGISTERS = 8
FIRMWARE = 8  # R uint16 major, minor at 9
POSITION_MDEG = 100  # R int32 x2: azimuth, elevation, millidegrees
TARGET_MDEG = 104  # RW int32 x2: azimuth, elevation target, millidegrees
COMMAND = 108  # W uint16, reads 0
STATUS = 109  # R uint16, bits below
SOFT_LIMITS_MDEG = 110  # R int32 x4: az min, az max, el min, el max
FAULT_CODE = 118  # R uint16: FAULT_* below

COMMAND_MOVE, COMMAND_STOP, COMMAND_HOME, COMMAND_CLEAR_FAULT = 1, 2, 3, 4
STATUS_IN_POSITION = 1 << 0
STATUS_MOVING = 1 << 1
STATUS_FAULT = 1 << 2
STATUS_HOMED = 1 << 3
FAULT_NONE, FAULT_DRIVE = 0, 1

MDEG_PER_DEG = 1000


def rotation_deg(az_deg: float, el_deg: float) -> np.ndarray:
    """Table frame -> lab frame rotation: azimuth about z, then elevation about the table's y axis.
    Home pose (0, 0): table x north, y east, z down; a field B_lab reads R^T B_lab on the table."""
    a, e = math.radians(az_deg), math.radians(el_deg)
    rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    ry = np.array([[math.cos(e), 0, math.sin(e)], [0, 1, 0], [-math.sin(e), 0, math.cos(e)]])
    return rz @ ry


def angles_to_words(angles_deg) -> list[int]:
    words: list[int] = []
    for angle in angles_deg:
        words += encode_int32(round(angle * MDEG_PER_DEG))
    return words


def words_to_angles(words) -> tuple[float, ...]:
    return tuple(decode_int32(words[i : i + 2]) / MDEG_PER_DEG for i in range(0, len(words), 2))


@dataclass(frozen=True)
class TurntableReading:
    t: float
    az_deg: float
    el_deg: float
    in_position: bool
    moving: bool
    fault: bool
    homed: bool


class Turntable(Device):
    kind = "turntable"

    def __init__(
        self,
        transport: ModbusTransport,
        *,
        name: str,
        clock: Clock | None = None,
        az_limits_deg: tuple[float, float],
        el_limits_deg: tuple[float, float],
        poll_s: float = 0.05,
        tol_deg: float = 0.01,
    ):
        super().__init__(name, clock)
        self.transport = transport
        self.limits_deg = {"az": tuple(az_limits_deg), "el": tuple(el_limits_deg)}
        self.poll_s = poll_s
        self.tol_deg = tol_deg
        self.model = ""
        self.firmware = ""
        self.device_limits_deg: tuple[float, ...] | None = None
        self._target_deg: tuple[float, float] | None = None

    def connect(self) -> None:
        self.transport.connect()
        self.model = self.transport.read_string(MODEL, MODEL_REGISTERS, operation="read model")
        if not self.model.startswith(MODEL_PREFIX):
            raise ProtocolError(
                self.name, "connect", f"model {self.model!r} is not a {MODEL_PREFIX} turntable"
            )
        major, minor = self.transport.read_holding(FIRMWARE, 2, operation="read firmware")
        self.firmware = f"{major}.{minor}"
        words = self.transport.read_holding(SOFT_LIMITS_MDEG, 8, operation="read soft limits")
        self.device_limits_deg = words_to_angles(words)

    def close(self) -> None:
        self.transport.close()

    def set(self, angles_deg) -> None:
        """Move to (az_deg, el_deg); limits are checked before anything is written."""
        az_deg, el_deg = self._checked(angles_deg)
        where = f"move to az {az_deg:.3f} el {el_deg:.3f} deg"
        status = self.transport.read_holding(STATUS, 1, operation=f"{where}: read status")[0]
        if status & STATUS_FAULT:
            raise DeviceFault(self.name, where, f"drive fault code {self._fault_code()}; clear it first")
        if not status & STATUS_HOMED:
            raise DeviceFault(self.name, where, "table is not homed; call home() first")
        self.transport.write_registers(
            TARGET_MDEG, angles_to_words((az_deg, el_deg)), operation=f"{where}: target"
        )
        self.transport.write_register(COMMAND, COMMAND_MOVE, operation=f"{where}: command")
        self._target_deg = (az_deg, el_deg)

    def read(self) -> TurntableReading:
        t = self.clock.now()
        words = self.transport.read_holding(
            POSITION_MDEG, STATUS + 1 - POSITION_MDEG, operation="read position"
        )
        az_deg, el_deg = words_to_angles(words[:4])
        status = words[STATUS - POSITION_MDEG]
        return TurntableReading(
            t,
            az_deg,
            el_deg,
            in_position=bool(status & STATUS_IN_POSITION),
            moving=bool(status & STATUS_MOVING),
            fault=bool(status & STATUS_FAULT),
            homed=bool(status & STATUS_HOMED),
        )

    def wait_settled(self, timeout_s: float = 60.0) -> TurntableReading:

        def settled(reading: TurntableReading) -> bool:
            if reading.fault:
                raise DeviceFault(self.name, "wait settled", f"drive fault code {self._fault_code()}")
            return reading.in_position and self._at_target(reading)

        def timed_out(reading: TurntableReading) -> DeviceTimeout:
            return DeviceTimeout(
                self.name,
                "wait settled",
                f"not in position after {timeout_s:g} s (at az {reading.az_deg:.3f} "
                f"el {reading.el_deg:.3f}, target {self._target_deg})",
            )

        return wait_until(self.clock, self.read, settled, timeout_s=timeout_s, poll_s=self.poll_s,
                          timed_out=timed_out)

    def home(self) -> None:
        self.transport.write_register(COMMAND, COMMAND_HOME, operation="home")
        self._target_deg = (0.0, 0.0)

    def stop(self) -> None:
        self.transport.write_register(COMMAND, COMMAND_STOP, operation="stop")
        self._target_deg = None

    def clear_fault(self) -> None:
        self.transport.write_register(COMMAND, COMMAND_CLEAR_FAULT, operation="clear fault")

    def safe_state(self) -> None:
        self.stop()

    def describe(self) -> dict:
        return {
            **super().describe(),
            "model": self.model,
            "firmware": self.firmware,
            "az_limits_deg": self.limits_deg["az"],
            "el_limits_deg": self.limits_deg["el"],
            "device_soft_limits_deg": self.device_limits_deg,
            **self.transport.describe(),
        }

    def _fault_code(self) -> int:
        return self.transport.read_holding(FAULT_CODE, 1, operation="read fault code")[0]

    def _at_target(self, reading: TurntableReading) -> bool:
        if self._target_deg is None:
            return True
        return (
            abs(reading.az_deg - self._target_deg[0]) <= self.tol_deg
            and abs(reading.el_deg - self._target_deg[1]) <= self.tol_deg
        )

    def _checked(self, angles_deg) -> tuple[float, float]:
        if any(isinstance(a, bool) or not isinstance(a, Real) for a in angles_deg):
            raise LimitError(f"{self.name}: angles must be numbers, got {list(angles_deg)!r}")
        values = tuple(float(a) for a in angles_deg)
        if len(values) != 2:
            raise LimitError(f"{self.name}: expected (az_deg, el_deg), got {len(values)} values")
        for axis, angle in zip(("az", "el"), values, strict=True):
            low, high = self.limits_deg[axis]
            if not math.isfinite(angle) or not low <= angle <= high:
                raise LimitError(
                    f"{self.name}: {axis} {angle:.3f} deg is outside {axis}_limits_deg [{low}, {high}]"
                )
        return values


# --- registration -----------------------------------------------------------------------------------
class TurntableOptions(registry.Options):
    az_limits_deg: tuple[float, float] = (-360.0, 360.0)
    el_limits_deg: tuple[float, float] = (-180.0, 180.0)
    rate_deg_s: float = Field(10.0, gt=0, description="slew rate, for move-time estimates")

    @field_validator("az_limits_deg", "el_limits_deg")
    @classmethod
    def _ordered(cls, value: tuple[float, float]) -> tuple[float, float]:
        if value[0] >= value[1]:
            raise ValueError("lower limit must be below the upper limit")
        return value


def _build(link: ModbusTransport, options: TurntableOptions, *, name: str, clock: Clock, **_) -> Turntable:
    return Turntable(link, name=name, clock=clock, az_limits_deg=options.az_limits_deg,
                     el_limits_deg=options.el_limits_deg)


registry.register(registry.DeviceSpec(
    role="field_source", type="turntable", options=TurntableOptions, transports=registry.MODBUS_KINDS,
    build=_build, simulator="drivers.sim.devices.turntable:simulate"))
