"""What every station and plan model shares: strictness, vector types, transports, the device base.

A device config's transport is one of the kinds its driver's spec accepts (drivers/registry.py), or
`{kind: sim}`: the same driver then talks to its simulator (see rig/simstation.py).
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Union

from pydantic import BaseModel, ConfigDict, Field

from drivers import registry

Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]
PositiveFloat = Annotated[float, Field(gt=0)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


# --- transports ---------------------------------------------------------------------------------------
class ModbusTcp(Strict):
    kind: Literal["modbus_tcp"]
    host: str
    port: int = Field(502, ge=1, le=65535)
    timeout_s: PositiveFloat = 1.0


class ModbusRtu(Strict):
    kind: Literal["modbus_rtu"]
    port: str
    baudrate: int = Field(9600, gt=0)
    parity: Literal["N", "E", "O"] = "N"
    timeout_s: PositiveFloat = 1.0


class I2c(Strict):
    kind: Literal["i2c"]
    bus: int = Field(ge=0)
    address: int = Field(ge=0x03, le=0x77)


class Serial(Strict):
    kind: Literal["serial"]
    port: str
    baudrate: int = Field(115200, gt=0)
    timeout_s: PositiveFloat = 0.5


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
