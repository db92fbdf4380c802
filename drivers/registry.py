"""Device specs: what the rest of the project needs to know about each device type, declared once by its
driver module.

    spec = registry.spec("magnetometer", "mmc5983ma")
    opts = spec.options.model_validate({"bandwidth_hz": 200})     # the station's `options:` for it
    dev = spec.build(link, opts, name="mmc0", clock=clock, set_reset=True)
    spec.sample_time_s(opts, set_reset_pair=True)                # for `rig check`'s duration estimate

A spec names its role (ROLES), its station `type`, its options model (pydantic, in the driver module), the
transport kinds it accepts (besides `sim`), how it is built on an opened link, its simulator (a
"module:function" string resolved only when a station asks for a simulated device, so production code
never imports drivers.sim), its timing, and whether it measures its own temperature.

Links a builder receives: a drivers.transports.modbus.ModbusTransport (Modbus devices), an `I2cLink`, or
a `SerialLink`. A simulator function takes a `SimRequest` and returns a `SimModbus`, `SimI2c` or
`SimSerial` endpoint; the station builder turns that into the same link kinds.

Adding a device type: its driver module ends with `registry.register(DeviceSpec(...))`, and its module
name goes into DRIVER_MODULES below (the one registration line).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, get_args

from pydantic import BaseModel, BeforeValidator, ConfigDict, model_validator

from drivers.base import Device

ROLES = ("chamber", "field_source", "magnetometer", "temperature")
DRIVER_MODULES = (
    "drivers.watlow",
    "drivers.coils",
    "drivers.turntable",
    "drivers.mmc5983ma",
    "drivers.hmc5883l",
    "drivers.serialmag",
    "drivers.tmp117",
)
MODBUS_KINDS = ("modbus_tcp", "modbus_rtu")


class KeyPathError(ValueError):
    """Raised inside a model validator to blame a key below the model, e.g. ("duts", 1, "temp_source");
    rig/core/yamlload.py turns it into `FILE: key.path: message (line N)`."""

    def __init__(self, path: tuple[str | int, ...], message: str):
        super().__init__(message)
        self.path = tuple(path)
        self.message = message


def _mentions(annotation: Any, types: tuple[type, ...]) -> bool:
    """Whether one of `types` appears anywhere in a field's type (float in `tuple[float, float]`)."""
    return annotation in types or any(_mentions(a, types) for a in get_args(annotation))


def _checks_itself(annotation: Any, metadata: list) -> bool:
    """Whether a field's type carries its own before-validator (a subclass's stricter number type, e.g.
    rig's bounded floats): that one then judges the value."""
    return any(isinstance(m, BeforeValidator) for m in metadata) or any(
        isinstance(a, BeforeValidator) or _checks_itself(a, []) for a in get_args(annotation))


def _bad_number(value: Any, allow_bool: bool, path: tuple = ()) -> tuple[tuple, str] | None:
    """(index path, what is wrong) for a number, or a list of them, an option is given: a boolean where a
    number belongs, or inf/NaN (also spelt as text, which pydantic would read as a float)."""
    if isinstance(value, bool):
        return None if allow_bool else (path, f"expected a number, got {str(value).lower()}")
    if isinstance(value, float) and not math.isfinite(value):
        return path, f"must be a finite number, got {value}"
    if isinstance(value, str):
        try:
            number = float(value)
        except ValueError:
            return None
        return None if math.isfinite(number) else (path, f"must be a finite number, got {value.strip()!r}")
    if isinstance(value, list | tuple):
        for i, item in enumerate(value):
            problem = _bad_number(item, allow_bool, (*path, i))
            if problem:
                return problem
    return None


class Options(BaseModel):
    """Base of every options model: unknown keys are refused, and so are booleans where a number belongs
    and inf/NaN in any number field (a NaN limit would compare false and let everything through)."""

    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="before")
    @classmethod
    def _finite_numbers(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        for name, field in cls.model_fields.items():
            key = field.alias or name
            if key not in data or not _mentions(field.annotation, (int, float)):
                continue
            if _checks_itself(field.annotation, field.metadata):
                continue  # a stricter number type of its own names the item itself
            problem = _bad_number(data[key], _mentions(field.annotation, (bool,)))
            if problem:
                raise KeyPathError((key, *problem[0]), problem[1])
        return data


class NoOptions(Options):
    pass


@dataclass(frozen=True)
class I2cLink:
    bus: Any  # smbus2.SMBus or a simulated bus with the same methods
    address: int


@dataclass(frozen=True)
class SerialLink:
    port: str
    baudrate: int
    timeout_s: float
    line: Any = None  # a drivers.transports.serial.SerialLine several devices share (by device id)


@dataclass(frozen=True)
class SimRequest:
    """What a simulator is told about the device it stands in for."""

    world: Any  # drivers.sim.world.World
    name: str  # the device's name (for a magnetometer: its name in the world)
    type: str
    options: Any
    unit: int = 1  # Modbus device id
    beside: str | None = None  # temperature sensors: the DUT they are mounted next to


@dataclass
class SimModbus:
    server: Any  # start() -> TCP port on 127.0.0.1, stop()


@dataclass
class SimI2c:
    chip: Any  # register model to attach to a simulated bus
    address: int


@dataclass
class SimSerial:
    firmware: Any  # start() -> pty path, stop()
    baudrate: int = 9600
    timeout_s: float = 0.5


Builder = Callable[..., Device]  # build(link, options, *, name, clock, set_reset) -> Device


@dataclass(frozen=True)
class I2cProbe:
    """How a bus scan (drivers/busscan.py) recognises the chip: the addresses it can answer at, and a
    look at its identification registers through a plain smbus2-like bus, `identify(bus, address)`:
    what the chip is ("MEMSIC MMC5983MA (product id 0x30 at 0x2F)"), or None when it is not this chip."""

    addresses: tuple[int, ...]
    identify: Callable[[Any, int], str | None]


@dataclass(frozen=True)
class SerialProbe:
    """How a port scan recognises the device: `identify(line, device_id, timeout_s)` on a
    drivers.transports.serial.SerialLine gives {"model", "serial_number", "firmware"}, or None when
    nothing answers at that id; `device_ids` to try; the line's possible `baudrates`; `quiet(line)`, once
    per baud rate before the ids are asked (stop what a device may be streaming)."""

    identify: Callable[[Any, int, float], dict | None]
    device_ids: tuple[int, ...]
    baudrates: tuple[int, ...]
    quiet: Callable[[Any], None] | None = None


@dataclass(frozen=True)
class DeviceSpec:
    role: str
    type: str
    options: type[BaseModel]
    transports: tuple[str, ...]
    build: Builder
    simulator: str  # "drivers.sim.<module>:<function>", function(SimRequest) -> SimModbus|SimI2c|SimSerial
    has_temperature: bool = False
    temperature_accuracy_c: float | None = None  # +- over its range, where its datasheet states one
    sample_time: Callable[[Any, bool], float] | None = None  # (options, set_reset_pair) -> s per reading
    rates_hz: tuple[float, ...] = ()
    probe: I2cProbe | SerialProbe | None = None  # how `rig devices scan` recognises it
    manufacturer: str | None = None  # who makes it (a calibration certificate names the item's maker)

    def sample_time_s(self, options, set_reset_pair: bool) -> float:
        """Estimated time for one reading (duration estimates; the driver sets the real pace)."""
        return 0.0 if self.sample_time is None else self.sample_time(options, set_reset_pair)

    def load_simulator(self) -> Callable[[SimRequest], Any]:
        module, _, function = self.simulator.partition(":")
        return getattr(importlib.import_module(module), function)


_SPECS: dict[tuple[str, str], DeviceSpec] = {}
_loaded = False


def register(spec: DeviceSpec) -> DeviceSpec:
    if spec.role not in ROLES:
        raise ValueError(f"device spec {spec.type}: role {spec.role!r} is not one of {ROLES}")
    _SPECS[(spec.role, spec.type)] = spec
    return spec


def _load() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        for module in DRIVER_MODULES:
            importlib.import_module(module)


def specs(role: str) -> list[DeviceSpec]:
    """Every registered spec of `role`, in registration order."""
    _load()
    return [s for (r, _), s in _SPECS.items() if r == role]


def probes(kind: type[I2cProbe] | type[SerialProbe]) -> list:
    """The distinct probes of one kind (a driver registered under two types declares one probe)."""
    _load()
    out: list = []
    for s in _SPECS.values():
        if isinstance(s.probe, kind) and s.probe not in out:
            out.append(s.probe)
    return out


def spec(role: str, type_: str) -> DeviceSpec:
    _load()
    try:
        return _SPECS[(role, type_)]
    except KeyError:
        known = ", ".join(s.type for s in specs(role))
        raise KeyError(f"no {role} of type {type_!r} (known: {known})") from None

