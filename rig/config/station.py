"""Station files (what is on the bench): strict models built from the device registry.

    name; sim (the simulated world, rig/config/sim.py);
    chamber {type, transport, unit, limits}; field_source {kind: coils | turntable, ...};
    duts [{name, type, transport, options, temp_source}];
    temperature_sensors [{name, type, transport, beside}];
    reference_magnetometers [{name, type, transport, options, calibration, temp_source?, samples}].

The `type:` values, each type's options (`limits:` of a chamber, `options:` of a magnetometer) and the
transport kinds it takes come from its driver's spec (drivers/registry.py); field sources come from
rig/fieldsources/. Simulation is explicit: a device is simulated exactly when its transport is
`{kind: sim}` (`device.simulated`), and `Station.simulated_devices()` is what a session records. Nothing
falls back to a simulator on failure.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Union

import numpy as np
from pydantic import Field, create_model, model_validator

from drivers import registry
from drivers.chamber import ChamberAlarm, ChamberSettings
from rig.config.notify import Notify
from rig.config.sim import SimWorld
from rig.core import names
from rig.core.configbase import DeviceConfig, Strict, transport_type
from rig.core.errors import ConfigError
from rig.core.names import SafeName
from rig.core.numbers import DAY_S, MODBUS_UNIT, NT_MAX, Count, bounded, bounded_vec3
from rig.core.yamlload import KeyPathError
from rig.fieldsources import FieldSource


class ChamberConfig(DeviceConfig):
    role: ClassVar[str] = "chamber"

    name: SafeName = "chamber"
    unit: MODBUS_UNIT = Field(1, description="Modbus device id")

    alarm: ChamberAlarm | None = Field(
        None, description="the controller's alarm register, where the lab has one (Watlow maps give none)")

    @property
    def device_options(self) -> Any:
        return ChamberSettings(self.limits, self.alarm)  # type: ignore[attr-defined]

    def sim_request(self, world) -> registry.SimRequest:
        return registry.SimRequest(world, self.name, self.device_type, self.device_options, unit=self.unit)


POSITION_MM = bounded_vec3(10_000.0)
SAME_PLACE_MM = 1.0  # two sensors closer than this would overlap: a mistake in the station file
DEFAULT_GRADIENT_C_PER_C = 0.002  # a probe glued beside the DUT: 0.1 degC apart at 50 degC from 25


class DutExpect(Strict):
    """What the lab states of a DUT for planning while nothing has measured it (rig/planning/inputs.py):
    one plain reading's noise per axis (its datasheet's RMS noise) and its temperature's lag behind the
    chamber air, first order."""

    noise_nt: bounded(gt=0, hi=NT_MAX)
    thermal_lag_s: bounded(gt=0, hi=DAY_S)


class DutConfig(DeviceConfig):
    role: ClassVar[str] = "magnetometer"

    name: SafeName
    temp_source: str = Field(description='a temperature sensor\'s name, or "self" (the chip\'s own sensor)')
    position_mm: POSITION_MM | None = Field(
        None, description="where its sensing element sits in the coil set (x, y, z mm); default: the centre")
    position_tolerance_mm: bounded(lo=0, hi=1000.0) = Field(
        1.0, description="how well position_mm is known (+-, mm): the budget's 'position'")
    temp_accuracy_c: bounded(lo=0, hi=100.0) | None = Field(
        None, description="accuracy (+-) of its temperature source; default: the datasheet's")
    temp_gradient_c_per_c: bounded(lo=0, hi=1.0) = Field(
        DEFAULT_GRADIENT_C_PER_C, description="how far (+-) the element may differ from its temperature "
        "source, per degC away from 25 degC")
    expect: DutExpect | None = Field(
        None, description="its noise and lag as the lab states them, for planning until measured")

    @model_validator(mode="before")
    @classmethod
    def _options_of_the_type(cls, data: Any) -> Any:
        """An option of another type is named as such, not just as an unknown key."""
        if isinstance(data, dict) and isinstance(data.get("options"), dict):
            spec = registry.spec(cls.role, data["type"])
            allowed = spec.options.model_fields
            for key in data["options"]:
                if key not in allowed:
                    known = ", ".join(sorted(allowed))
                    raise KeyPathError(("options", key), f"not an option of {spec.type} (allowed: {known})")
        return data

    @model_validator(mode="after")
    def _own_temperature(self):
        if self.temp_source == "self" and not self.spec.has_temperature:
            raise KeyPathError(("temp_source",),
                               f"{self.device_type} has no temperature sensor; name a TMP117")
        return self


class ReferenceMagnetometerConfig(DutConfig):
    """A calibrated magnetometer at the DUT position that measures the ambient (coils off) or the site
    field (table at home): any magnetometer type, never a DUT (not fitted, not in the outputs). Its
    calibration file (relative to the station file) is applied to every reading
    (rig/reference/sitefield.py)."""

    calibration: str = Field(description="its calibration file, relative to the station file")
    temp_source: str | None = Field(  # type: ignore[assignment]
        None, description='a temperature sensor or "self"; needed when the calibration has temperature terms')
    samples: Count(100_000, lower=2) = Field(100, description="readings averaged per measurement")


class TemperatureSensorConfig(DeviceConfig):
    role: ClassVar[str] = "temperature"

    name: SafeName
    beside: str = Field(description="the DUT this sensor is mounted next to")

    def sim_request(self, world) -> registry.SimRequest:
        return registry.SimRequest(world, self.name, self.device_type, self.device_options,
                                   beside=self.beside)


def _by_type(base: type[DeviceConfig], options_key: str) -> Any:
    """One model per registered type of `base.role` (its options model under `options_key`), chosen by
    the `type:` key."""
    members = []
    for spec in registry.specs(base.role):
        fields: dict[str, Any] = {
            "type": (Literal[spec.type], ...),
            "transport": (transport_type(spec.transports), ...),
            options_key: (spec.options, ...) if options_key == "limits" else (spec.options, spec.options()),
        }
        members.append(create_model(f"{base.__name__}_{spec.type}", __base__=base, **fields))
    return Annotated[Union[tuple(members)], Field(discriminator="type")]  # noqa: UP007 - built at run time


Chamber = _by_type(ChamberConfig, "limits")
Dut = _by_type(DutConfig, "options")
TemperatureSensor = _by_type(TemperatureSensorConfig, "options")
ReferenceMagnetometer = _by_type(ReferenceMagnetometerConfig, "options")


class Station(Strict):
    name: SafeName
    sim: SimWorld = SimWorld()
    chamber: Chamber
    field_source: FieldSource
    duts: list[Dut] = Field(min_length=1)
    temperature_sensors: list[TemperatureSensor] = []
    reference_magnetometers: list[ReferenceMagnetometer] = []
    notify: Notify | None = None  # word to the operator (rig/config/notify.py); a plan's notify: replaces it

    @model_validator(mode="after")
    def _references(self):
        named = list(self._named_devices())
        seen: set[str] = set()
        for path, dev in named:
            if dev.name in seen:
                raise KeyPathError((*path, "name"), f"device name {dev.name!r} is used twice")
            seen.add(dev.name)
        clash = names.collision(dev.name for _, dev in named)  # one file or C symbol for two devices
        if clash:
            raise KeyPathError((*named[clash[0]][0], "name"), f"device name {clash[1]}")
        sensors = {s.name for s in self.temperature_sensors}
        duts = {d.name for d in self.duts}
        for i, d in enumerate(self.duts):
            if d.temp_source != "self" and d.temp_source not in sensors:
                known = ", ".join(sorted(sensors)) or "none defined"
                raise KeyPathError(("duts", i, "temp_source"),
                                   f"no temperature sensor {d.temp_source!r} (sensors: {known}; or 'self')")
        references = [r.name for r in self.reference_magnetometers]
        for i, r in enumerate(self.reference_magnetometers):
            if r.temp_source not in (None, "self") and r.temp_source not in sensors:
                raise KeyPathError(("reference_magnetometers", i, "temp_source"),
                                   f"no temperature sensor {r.temp_source!r} (or 'self', or leave it out)")
        for i, s in enumerate(self.temperature_sensors):
            if s.beside not in duts and s.beside not in references:
                raise KeyPathError(("temperature_sensors", i, "beside"), f"no DUT named {s.beside!r}")
        for name in self.sim.duts:
            if name not in duts and name not in references:
                raise KeyPathError(("sim", "duts", name), f"no DUT named {name!r} in duts")
            if name in references and "truth" in self.sim.duts[name].model_fields_set and \
                    self.sim.duts[name].truth == "random":
                raise KeyPathError(("sim", "duts", name, "truth"), "a reference magnetometer's truth is its "
                                   "calibration file: state S, b_nt... to match it, or leave truth out")
        for path, message in self.field_source.station_problems(duts, references):
            raise KeyPathError(("field_source", *path), message)
        return self

    @model_validator(mode="after")
    def _wiring(self):
        """Address clashes on an I2C segment, device ids and baud rates on a serial line."""
        from rig.config.wiring import problems

        for path, message in problems(self):
            raise KeyPathError(path, message)
        return self

    @model_validator(mode="after")
    def _simulated_coil_keys(self):
        """sim.current_source and sim.coil_loops bend coils (a field source with a `geometry` key); the
        loops also need a geometry to be loops of."""
        coils = "geometry" in type(self.field_source).model_fields
        for key in ("current_source", "coil_loops"):
            if getattr(self.sim, key) is not None and not coils:
                raise KeyPathError(("sim", key), f"needs coils, not {self.field_source.described}")
        if self.sim.coil_loops is not None and self.sim.coil_geometry is None and \
                getattr(self.field_source, "geometry", None) is None:
            raise KeyPathError(("sim", "coil_loops"), "needs a coil geometry to place the loops: give "
                               "sim.coil_geometry or field_source.geometry")
        return self

    @model_validator(mode="after")
    def _positions(self):
        """Every stated position inside the coil set (declared and simulated geometry) and no two
        sensors at one place."""
        geometries = [g for g in (getattr(self.field_source, "geometry", None), self.sim.coil_geometry)
                      if g is not None]
        placed: list[tuple[tuple, str, np.ndarray]] = []
        for path, dev in self._named_devices():
            position = getattr(dev, "position_mm", None)
            if position is None:
                continue
            for geometry in geometries:
                if not geometry.encloses(position):
                    simulated = geometry is self.sim.coil_geometry
                    where = "sim.coil_geometry" if simulated else "field_source.geometry"
                    raise KeyPathError((*path, "position_mm"), f"{_fmt_mm(position)} is outside the coil set "
                                       f"({where}: {geometry.shape}, size_m {list(geometry.size_m)}, "
                                       f"spacing_m {list(geometry.spacing_m)})")
            here = np.asarray(position, float)
            for _, other, there in placed:
                if np.linalg.norm(here - there) < SAME_PLACE_MM:
                    raise KeyPathError((*path, "position_mm"), f"{_fmt_mm(position)} is where {other} sits "
                                       f"(two sensors closer than {SAME_PLACE_MM:g} mm)")
            placed.append((path, dev.name, here))
        return self

    def positions_mm(self) -> dict[str, tuple[float, float, float] | None]:
        """{DUT or reference magnetometer name: its stated position (None: the centre)}."""
        return {d.name: d.position_mm for d in (*self.duts, *self.reference_magnetometers)}

    def ambient_position_mm(self) -> tuple[float, float, float] | None:
        """Where the field source's ambient is measured: its measuring reference magnetometer's position
        (None: the centre, and where the ambient is stated)."""
        name = self.field_source.measuring_magnetometer([r.name for r in self.reference_magnetometers])
        return self.positions_mm().get(name) if name is not None else None

    def _named_devices(self):
        yield ("chamber",), self.chamber
        yield ("field_source",), self.field_source
        for i, d in enumerate(self.duts):
            yield ("duts", i), d
        for i, s in enumerate(self.temperature_sensors):
            yield ("temperature_sensors", i), s
        for i, r in enumerate(self.reference_magnetometers):
            yield ("reference_magnetometers", i), r

    def devices(self) -> list[DeviceConfig]:
        return [dev for _, dev in self._named_devices()]

    def simulated_devices(self) -> dict[str, bool]:
        """{device name: simulated?} - recorded in every session."""
        return {dev.name: dev.simulated for dev in self.devices()}

    def dut(self, name: str) -> DutConfig:
        for d in self.duts:
            if d.name == name:
                return d
        raise ConfigError(f"station {self.name}: no DUT named {name!r}")


def _fmt_mm(position) -> str:
    return "position (" + ", ".join(f"{x:g}" for x in position) + ") mm"
