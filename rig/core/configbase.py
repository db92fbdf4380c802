"""What every station and plan model shares: strictness, vector types, transports, the device base.

A device config's transport is one of the kinds its driver's spec accepts (drivers/registry.py), or
`{kind: sim}`: the same driver then talks to its simulator (see rig/devices/simulated/bench.py).
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, model_validator

from drivers import registry
from rig.core.names import SafeName
from rig.core.numbers import BAUDRATE, TIMEOUT_S, Count, NonNegativeFloat, PositiveFloat, Vec3  # noqa: F401 - the config models'
from rig.core.ports import SerialPort
from rig.core.yamlload import KeyPathError

Mat3 = tuple[Vec3, Vec3, Vec3]  # finite numbers (rig/core/numbers.py)


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
    port: SerialPort
    baudrate: BAUDRATE = 9600
    parity: Literal["N", "E", "O"] = "N"
    timeout_s: TIMEOUT_S = 1.0


class Mux(Strict):
    """A TCA9548A/PCA9548A I2C switch in front of the device: its address (0x70..0x77) and channel."""

    address: Count(0x77, lower=0x70)
    channel: Count(7, lower=0)


class I2c(Strict):
    kind: Literal["i2c"]
    bus: Count(1_000, lower=0)
    address: Count(0x77, lower=0x03)
    mux: Mux | None = None


class Bridge(Strict):
    """An I2C device behind a USB-to-I2C bridge (drivers/transports/<kind>.py), on the bus itself or behind
    a switch. `sim: true` puts a simulated bridge there (drivers/sim/<kind>.py) with the simulated chip
    behind it; `faults:` then as for `{kind: sim}`. Devices naming the same bridge share its bus."""

    speed_hz: Count(400_000, lower=10_000) = 100_000
    address: Count(0x77, lower=0x03)
    mux: Mux | None = None
    sim: bool = False
    faults: SimFaults | None = None

    @model_validator(mode="after")
    def _faults_need_sim(self):
        if self.faults is not None and not self.sim:
            raise KeyPathError(("faults",), "faults are played by a simulated bridge only (sim: true)")
        return self

    @property
    def bus(self) -> str:
        """The bus this bridge makes, as devices sharing it and messages name it."""
        return f"{self.kind} {self.where}"  # type: ignore[attr-defined]


class Mcp2221(Bridge):
    kind: Literal["mcp2221"]
    serial: str | None = None  # USB serial number; left out: the only MCP2221A plugged in
    speed_hz: Count(400_000, lower=47_000) = 100_000  # the 8-bit divider reaches down to about 47 kHz

    @property
    def where(self) -> str:
        return self.serial or "(the only one)"


class Cp2112(Bridge):
    kind: Literal["cp2112"]
    serial: str | None = None

    @property
    def where(self) -> str:
        return self.serial or "(the only one)"


class Ft232h(Bridge):
    kind: Literal["ft232h"]
    url: str = "ftdi://ftdi:232h/1"  # pyftdi's form; ftdi://ftdi:232h:SERIAL/1 names one of several
    latency_ms: Count(255, lower=1) = 16  # the chip's latency timer (pyftdi's default 16)

    @property
    def where(self) -> str:
        return self.url


BRIDGE_KINDS = ("mcp2221", "cp2112", "ft232h")


class Serial(Strict):
    kind: Literal["serial"]
    port: SerialPort  # /dev/ttyUSB0, COM7, \\.\COM12 or a pyserial URL (rig/core/ports.py)
    baudrate: BAUDRATE = 115200
    timeout_s: TIMEOUT_S = 0.5


class FaultWindow(Strict):
    """A fault that starts `after_s` seconds of campaign time after the bench starts and lasts `for_s`
    (left out: to the end of the run)."""

    after_s: NonNegativeFloat = 0.0
    for_s: PositiveFloat | None = None


OneIn = Count(10**9, lower=2)  # one operation in this many fails


class SimFaults(Strict):
    """Faults a simulated device plays for a rehearsal (drivers/sim/devices/faults.py), seeded by
    `sim.seed`."""

    no_reply: OneIn | None = None
    exception: OneIn | None = None
    garbled: OneIn | None = None
    nack: OneIn | None = None
    unplug: FaultWindow | None = None
    stuck_temperature: FaultWindow | Literal[True] | None = None
    alarm: FaultWindow | None = None

    def given(self) -> list[str]:
        return [k for k in type(self).model_fields if getattr(self, k) is not None]


# What each protocol can do wrong (one in N operations); `unplug` every device can.
PROTOCOL_FAULTS = {
    "modbus": ("no_reply", "exception", "garbled"),  # a lost reply, an exception reply, a bad-CRC frame
    "serial": ("no_reply", "garbled"),  # a lost reply, a corrupted line
    "i2c": ("nack",),  # no ACK: OSError errno 121
}


def protocol_of(transports: tuple[str, ...]) -> str:
    return "modbus" if set(transports) & {"modbus_tcp", "modbus_rtu"} else transports[0]


class Sim(Strict):
    """Simulated device: the same driver talks its protocol to a simulator of `sim:`'s world.
    `faults:` makes it misbehave as its protocol allows (a rehearsal of a bad day in the lab)."""

    kind: Literal["sim"]
    faults: SimFaults | None = None
    # I2C devices behind a simulated switch share ONE simulated bus per `bus` number (without `mux`
    # each simulated chip keeps a bus of its own); serial devices naming the same `line` share one pty.
    bus: Count(1_000, lower=0) = 0
    address: Count(0x77, lower=0x03) | None = None
    mux: Mux | None = None
    line: SafeName | None = None

    @model_validator(mode="after")
    def _muxed_needs_address(self):
        if self.mux is not None and self.address is None:
            raise ValueError("a simulated device behind a switch (mux) needs its `address`")
        return self


TRANSPORTS: dict[str, type[Strict]] = {
    "modbus_tcp": ModbusTcp, "modbus_rtu": ModbusRtu, "i2c": I2c, "serial": Serial, "sim": Sim,
    "mcp2221": Mcp2221, "cp2112": Cp2112, "ft232h": Ft232h,
}


def transport_type(kinds: tuple[str, ...]) -> Any:
    """The pydantic type of a `transport:` key that takes `kinds` or sim, chosen by its `kind:`. An I2C
    device takes the USB-to-I2C bridges as well."""
    bridges = BRIDGE_KINDS if "i2c" in kinds else ()
    members = tuple(TRANSPORTS[k] for k in (*kinds, *bridges, "sim"))
    return Annotated[Union[members], Field(discriminator="kind")]  # noqa: UP007 - built at run time


ModbusTransport = transport_type(registry.MODBUS_KINDS)


class DeviceConfig(Strict):
    """A device of the station. `spec` is its driver's DeviceSpec; `device_options` the options its
    builder takes; `sim_request(world)` what its simulator is told."""

    role: ClassVar[str]

    @model_validator(mode="after")
    def _faults_it_can_have(self):
        faults = getattr(self.transport, "faults", None)  # type: ignore[attr-defined]
        if faults is not None:
            for key, problem in fault_problems(self, faults):
                raise KeyPathError(("transport", "faults", key), problem)
        return self

    @property
    def simulated(self) -> bool:
        t = self.transport  # type: ignore[attr-defined]
        return t.kind == "sim" or getattr(t, "sim", False) is True

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


def fault_problems(dev: DeviceConfig, faults: SimFaults) -> list[tuple[str, str]]:
    """[(fault key, why this device cannot have it)]: a kind its protocol cannot produce, a stuck
    temperature on a device that measures none, an alarm on a chamber without an alarm register."""
    spec = dev.spec
    protocol = protocol_of(spec.transports)
    allowed = PROTOCOL_FAULTS[protocol]
    out = []
    for key in faults.given():
        if key in ("no_reply", "exception", "garbled", "nack") and key not in allowed:
            out.append((key, f"a {spec.type} ({protocol}) cannot have {key} faults "
                             f"(its protocol allows: {', '.join(allowed)}, unplug)"))
        elif key == "stuck_temperature" and not (dev.role == "temperature" or spec.has_temperature):
            out.append((key, f"a {spec.type} measures no temperature"))
        elif key == "alarm" and (dev.role != "chamber" or getattr(dev, "alarm", None) is None):
            out.append((key, f"a {spec.type} has no alarm register to show it (name one in `alarm:`)"
                             if dev.role == "chamber" else f"only a chamber has an alarm, not a {spec.type}"))
    return out
