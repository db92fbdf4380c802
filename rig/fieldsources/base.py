"""The field-source interface: everything the plan, `rig check`, the campaign and the simulated station
ask of a field source, so that none of them asks which kind it is.

A field source is the station's `field_source:` (a pydantic model with `kind:`) and knows:
- `field_kinds`: the plan field sets (`fields.kind`) it can make; `targets(fields)` expands one;
- `record(target)`: how a point's target is stored; `point_letter`: F (fields) or O (orientations);
- `reference(measured_nt)`: the Reference that turns a target into the device's setting and the
  device's readback into the reference field (rig/fieldsources/fieldmaths.py);
- `nominal_field_nt(target)`: the field at the sensor for design checks; `move_time_s(targets)`;
  `settle_timeout_s()`; `check_targets(...)`: limit checks for `rig check`;
- `prepare(device)`: what to do before the first move (home a table); `declared_world()`: what the station
  declares of its field, as the simulated world's keywords (the simulated bench adds the `sim:` truth);
- `station_problems(dut_names, reference_names)`: cross-references into the rest of the station.
A field source whose reference needs a measured quantity (ambient "measure", a site field from a
reference magnetometer; rig/reference/sitefield.py does the measuring) says so:
- `needs_measurement()`; `measured_name` ("ambient field", "site field"); `measuring_magnetometer(refs)`:
  which reference magnetometer measures it; `measurement_setting()`: the device setting to measure at
  (coils at 0 A, table at home); `drift_max_nt()`: how far it may move between temperature steps;
  `check_measured(plan_name, points, measured_nt)`: the plan's limits again, with the measured value.
Its driver (drivers/registry.py, role "field_source", type = kind) gets the model itself as options.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from pydantic import Field, PrivateAttr

from drivers import registry
from rig.core.configbase import DeviceConfig, ModbusTransport
from rig.core.errors import ConfigError, LimitError
from rig.core.names import SafeName
from rig.core.numbers import MODBUS_UNIT, bounded
from rig.core.yamlload import blamed

if TYPE_CHECKING:
    from rig.core.points import Point

SETTLE_TIMEOUT_S = 5.0  # readbacks reach their setpoints well within this; movers add their travel
DRIFT_MAX_NT = 200.0  # a lab's ambient moves a few tens of nT in hours; more means something changed


def point_limit_error(plan_name: str, point: Point, what: str) -> LimitError:
    """A limit a plan's point breaks; `err.point` lets the plan check name the plan key and line."""
    err = LimitError(f"plan {plan_name}: point {point.id} {what}")
    err.point = point  # type: ignore[attr-defined]
    return err


class FieldSourceConfig(DeviceConfig):
    role: ClassVar[str] = "field_source"
    field_kinds: ClassVar[frozenset[str]] = frozenset()
    point_letter: ClassVar[str] = "F"
    described: ClassVar[str] = "a field source"  # for messages: "needs coils", "needs a turntable"

    kind: str
    name: SafeName
    transport: ModbusTransport
    unit: MODBUS_UNIT = Field(1, description="Modbus device id")
    commissioning: str | None = Field(
        None, description="`rig commission`'s file (relative to the station file): what it measured")
    max_age_days: bounded(gt=0, hi=100 * 365.0) = Field(
        180.0, description="`rig run` refuses a commissioning file older than this")
    # rig.config.commissioning_file.Commissioning, once loaded (rig/config/loading.py)
    _commissioned: Any = PrivateAttr(None)

    def with_commissioning(self, commissioned) -> FieldSourceConfig:
        """A copy that uses what `commissioned` (rig.config.commissioning_file.Commissioning) measured."""
        copy = self.model_copy()
        copy._commissioned = commissioned
        return copy

    @property
    def commissioned(self):
        return self._commissioned

    @property
    def device_type(self) -> str:
        return self.kind

    @property
    def device_options(self) -> Any:
        return self  # the driver's options model is a base class of this one

    def sim_request(self, world) -> registry.SimRequest:
        return registry.SimRequest(world, self.name, self.kind, self, unit=self.unit)

    # --- plan ---------------------------------------------------------------------------------------
    def targets(self, fields, plan_name: str, station_name: str) -> list[tuple[float, ...]]:
        """The targets of the plan's field set, in plan order; ConfigError if this source cannot make
        that kind of field set."""
        if fields.kind not in self.field_kinds:
            what = (f"{fields.kind!r} needs {makers_of(fields.kind)}; station {station_name} has "
                    f"{self.described} (use one of {', '.join(sorted(self.field_kinds))})")
            raise blamed(ConfigError(f"plan {plan_name}: fields.kind: {what}"), ("fields", "kind"), what)
        try:
            return fields.targets()
        except ValueError as exc:
            path = ("fields", "directions") if fields.kind == "directions" else ("fields",)  # a zero one
            raise blamed(ConfigError(f"plan {plan_name}: fields.{fields.kind}: {exc}"), path,
                         str(exc)) from None

    def record(self, target: tuple[float, ...]) -> dict:
        raise NotImplementedError

    def nominal_field_nt(self, target: tuple[float, ...]) -> np.ndarray:
        raise NotImplementedError

    def check_targets(self, plan_name: str, points: list[Point], warnings: list[str]) -> list[str]:
        """Raise LimitError naming the point and the limit; return lines for `rig check`'s summary."""
        return []

    def move_time_s(self, targets: list[tuple[float, ...]]) -> float:
        return 0.0

    # --- run ----------------------------------------------------------------------------------------
    def reference(self, measured_nt=None, positions_mm=None, ambient_at_mm=None):
        raise NotImplementedError

    def settle_timeout_s(self) -> float:
        return SETTLE_TIMEOUT_S

    def prepare(self, device) -> None:
        """Called once on the connected device before the first move."""

    # --- a measured ambient / site field ------------------------------------------------------------
    measured_name: ClassVar[str] = "field"
    measures_gradient: ClassVar[bool] = False  # whether `rig commission` reads the other references too

    def needs_measurement(self) -> bool:
        """True when `reference()` needs a value measured at the start of the campaign."""
        return False

    def measuring_magnetometer(self, reference_names: Sequence[str]) -> str | None:
        """The name of the reference magnetometer that measures it (None when nothing is measured)."""
        return None

    def measurement_setting(self) -> tuple[float, ...]:
        """The device setting the measurement is taken at (the field source's own field off / home)."""
        raise NotImplementedError

    def own_field_nt(self, readback, readback_se, position_mm) -> tuple[np.ndarray, np.ndarray] | None:
        """(field, standard error) nT the source itself still makes at `position_mm` at its measurement
        setting, from the mean read-back there and its standard error (`setting_readback`); None: none."""
        return None

    def drift_max_nt(self) -> float:
        """How far the measured value may move between temperature steps before the run holds."""
        return DRIFT_MAX_NT

    def check_measured(self, plan_name: str, points: list[Point], measured_nt) -> None:
        """The plan's limits again once the measured value is known; LimitError naming point and limit."""

    # --- the reference chain (rig/reference/): what each kind answers for itself ----------------------
    commissioning_section: ClassVar[str] = ""  # its section of the commissioning file ("coils", "table")
    commissioning_covariance_size: ClassVar[int] = 0  # the size of that section's covariance

    def commissioning_design(self, current_a: float | None,
                             repeats: int) -> list[tuple[tuple[float, ...], str]]:
        """The settings `rig commission` measures the reference at, each with what it drives (messages)."""
        raise NotImplementedError

    def commissioning_reference_problem(self, position_mm) -> str | None:
        """Why a reference magnetometer at `position_mm` cannot commission this source (None: it can)."""
        return None

    def commissioning_place_problem(self, position_mm) -> str | None:
        """Why the reference cannot commission this source at one more place `position_mm` (None: it can)."""
        return f"cannot be used: {self.described} is commissioned at one place only"

    def commissioning_with_place(self, section: dict, readings, position_mm, created_utc: str,
                                 settings: list[dict], reference_tolerance_mm: float) -> dict:
        """The commissioning file's section with one more place of the reference measured (`readings`
        there; `settings` their records) and what all its places show fitted again."""
        raise NotImplementedError

    def setting_readback(self, reading) -> tuple[float, ...] | None:
        """What the device reports of its setting, recorded with every commissioning setting (coils: the
        read-back currents the runs use); None: nothing beyond the setting."""
        return None

    def fit_commissioning(self, readings, reference_position_mm) -> dict:
        """The commissioning file's section, fitted from `readings` (rig.fieldsources.commissioning.Reading);
        DeviceFault naming the axis that does not behave."""
        raise NotImplementedError

    @classmethod
    def commissioning_section_problem(cls, section) -> tuple[tuple, str] | None:
        """(key path, what is wrong) with a commissioning file's section of this kind, beyond its schema."""
        return None

    def commissioning_lines(self, section) -> list[str]:
        """What `rig commission` prints of the section it wrote."""
        return []

    def chain_record(self, positions_mm: dict) -> dict:
        """What a session records of this source's reference chain beyond the commissioning file."""
        return {}

    def reference_check_lines(self, station, plan, warnings: list[str]) -> list[str]:
        """`rig check`'s lines on the reference chain; LimitError where the plan's accuracy target fails."""
        return []

    # --- what a calibration states of its reference (rig/analysis/measurand.py) ------------------------
    frame_text: ClassVar[str] = "the field source's frame"  # the frame of B, as a calibration file states it
    declared_words: ClassVar[str] = "the field source's declared values"  # its field without a commissioning
    commissioned_words: ClassVar[str] = "the field source as `rig commission` measured it"

    def reference_chain_statement(self, reference_names: Sequence[str]) -> dict:
        """What a calibration's reference field rests on (its file's `reference_chain`): `traceable` when
        the source was commissioned (measured with a calibrated reference magnetometer by `rig
        commission`), in words, with the commissioning file and its reference named."""
        com = self.commissioned
        measured = self.needs_measurement()
        ref = self.measuring_magnetometer(reference_names) if measured else None
        stated = "the commissioning or the station" if com is not None else "the station"
        field = (f"the {self.measured_name} measured during the run by reference magnetometer {ref}"
                 if measured else f"the {self.measured_name} as {stated} states it")
        if com is None:
            return {"traceable": False, "text": f"{self.declared_words} only (not commissioned); {field}",
                    "commissioning": None}
        record = com.as_record()
        used = com.record.reference_magnetometer
        return {"traceable": True,
                "text": f"{self.commissioned_words} with reference magnetometer {used.name} ({used.type}, "
                        f"calibration {used.calibration}); {field}",
                "commissioning": {"path": record["path"], "sha256": record["sha256"]},
                "reference_magnetometer": {"name": used.name, "type": used.type,
                                           "calibration": used.calibration,
                                           "calibration_sha256": used.calibration_sha256}}

    def uncertainty_caveat(self) -> str | None:
        """One line on what will dominate the calibrations' uncertainty before the run starts (e.g. an
        uncommissioned source's declared tolerance), or None: `rig run` and `rig check` print it first."""
        return None

    def budget_chain(self, run, dut: str, ds):
        """The budget's sources of the reference field for one DUT's data: an object whose
        `sources(notes)` lists calib.uncertainty.propagation InputSources (rig/budget/run_inputs.py RunInputs
        is
        `run`)."""
        raise NotImplementedError

    def measures_ambient(self) -> bool:
        """True when the ambient (the coils add to it; a table turns it) is measured during the run, at the
        start, each temperature step and the end: its drift is then modelled (rig/reference/ambient.py)."""
        return self.needs_measurement()

    def ambient_in_references(self, run, ds):
        """(the ambient each sample's reference was made with (N,3), how a change of it moves the
        reference (N,3,3), None: one to one), or None when the session does not say."""
        return None

    # --- station and simulation --------------------------------------------------------------------
    def station_problems(self, dut_names: set[str],
                         reference_names: Sequence[str] = ()) -> list[tuple[tuple, str]]:
        return []

    def declared_world(self) -> dict:
        """What the station declares of the field this source makes, as keywords of the simulated world
        (drivers/sim/world/__init__.py); the simulated bench (rig/devices/simulated/bench.py) lays the
        station's `sim:` truth over them. None: not declared (measured during the run)."""
        raise NotImplementedError


def makers_of(field_kind: str) -> str:
    """Which field sources make a plan's `fields.kind`, for messages ("coils", "a turntable")."""
    kinds = FieldSourceConfig.__subclasses__()  # one per kind (rig/fieldsources/__init__.py KINDS)
    return " or ".join(k.described for k in kinds if field_kind in k.field_kinds) or "no field source"


def only_reference(reference_names: Sequence[str]) -> str | None:
    """The station's reference magnetometer when it has exactly one (None otherwise)."""
    return reference_names[0] if len(reference_names) == 1 else None
