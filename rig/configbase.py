"""What every station and plan model shares: strictness, vector types, transports, the device base.

A device config's transport is one of the kinds its driver's spec accepts (drivers/registry.py), or
`{kind: sim}`: the same driver then talks to its simulator (see rig/simstation.py).
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Union

from pydantic import BaseModel, ConfigDict, Field

from drivers import registry
from rig.numbers import BAUDRATE, TIMEOUT_S, Count, PositiveFloat, Vec3  # noqa: F401 - the config models'

Mat3 = tuple[Vec3, Vec3, Vec3]  # finite numbers (rig/numbers.py)


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


# --- transports ---------------------------------------------------------------------------------------
class ModbusTcp(Strict):
    kind: Literal["modbus_tcp"]
    host: str
    port: Count(65535) = 502
    timeout_s: TIMEOUT_S = 1.0


class ModbusRtu(Strict):
    kind: Literal["modbus_rtu"]
    port: str
    baudrate: BAUDRATE = 9600
    parity: Literal["N", "E", "O"] = "N"
    timeout_s: TIMEOUT_S = 1.0


class I2c(Strict):
    kind: Literal["i2c"]
    bus: Count(1_000, lower=0)
    address: Count(0x77, lower=0x03)


class Serial(Strict):
    kind: Literal["serial"]
    port: str
    baudrate: BAUDRATE = 115200
    timeout_s: TIMEOUT_S = 0.5


class Sim(Strict):
    """Simulated device: the same driver talks its protocol to a simulator of `sim:`'s world."""

    kind: Literal["sim"]


TRANSPORTS: dict[str, type[Strict]] = {
    "modbus_tcp": ModbusTcp, "modbus_rtu": ModbusRtu, "i2c": I2c, "serial": Serial, "sim": Sim,
}


def transport_type(kinds: tuple[str, ...]) -> Any:
    """The pydantic type of a `transport:` key that takes `kinds` or sim, chosen by its `kind:`."""
    members = tuple(TRANSPORTS[k] for k in (*kinds, "sim"))
    return Annotated[Union[members], Field(discriminator="kind")]  # noqa: UP007 - built at run time


ModbusTransport = transport_type(registry.MODBUS_KINDS)


class DeviceConfig(Strict):
    """A device of the station. `spec` is its driver's DeviceSpec; `device_options` the options its
    builder takes; `sim_request(world)` what its simulator is told."""

    role: ClassVar[str]

    @property
    def simulated(self) -> bool:
        return self.transport.kind == "sim"  # type: ignore[attr-defined]

    @property
    def device_type(self) -> str:
        return self.type  # type: ignore[attr-defined]

    @property
    def spec(self) -> registry.DeviceSpec:
        return registry.spec(self.role, self.device_type)

    @property
    def device_options(self) -> Any:
        return self.options  # type: ignore[attr-defined]

    def sim_request(self, world) -> registry.SimRequest:
        return registry.SimRequest(world, self.name, self.device_type, self.device_options)  # type: ignore[attr-defined]
