"""What every station and plan model shares: strictness, vector types, transports, the device base.

A device config's transport is one of the kinds its driver's spec accepts (drivers/registry.py), or
`{kind: sim}`: the same driver then talks to its simulator (see rig/simstation.py).
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, model_validator

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


class Mux(Strict):
    """A TCA9548A/PCA9548A I2C switch in front of the device: its address (0x70..0x77) and channel."""

    address: int = Field(ge=0x70, le=0x77)
    channel: int = Field(ge=0, le=7)


class I2c(Strict):
    kind: Literal["i2c"]
    bus: int = Field(ge=0)
    address: int = Field(ge=0x03, le=0x77)
    mux: Mux | None = None


class Serial(Strict):
    kind: Literal["serial"]
    port: str
    baudrate: int = Field(115200, gt=0)
    timeout_s: PositiveFloat = 0.5


class Sim(Strict):
    """Simulated device: the same driver talks its protocol to a simulator of `sim:`'s world."""

    kind: Literal["sim"]
    # I2C devices behind a simulated switch share ONE simulated bus per `bus` number (without `mux`
    # each simulated chip keeps a bus of its own); serial devices naming the same `line` share one pty.
    bus: int = Field(0, ge=0)
    address: int | None = Field(None, ge=0x03, le=0x77)
    mux: Mux | None = None
    line: str | None = None

    @model_validator(mode="after")
    def _muxed_needs_address(self):
        if self.mux is not None and self.address is None:
            raise ValueError("a simulated device behind a switch (mux) needs its `address`")
        return self


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
