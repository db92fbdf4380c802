"""Two-axis turntable in the site's field: an orientation (az, el) turns the site field into the sensor.

Home pose (az = el = 0): table x north, y east, z down, so the site field (NED) is the table-frame field at
home. Sensor-frame field = R^T B_site, R = Rz(az) @ Ry(el) (drivers.turntable.rotation_deg). The site
field is a vector given in the station, the World Magnetic Model at the site, or measured by a reference
magnetometer at the start of the campaign.

A commissioned table (`commissioning: FILE`, written by `rig commission`; calib/commissioning/tablefit.py)
adds how its axes differ from the drawing: the elevation axis' tilt, the encoders' zero offsets and the
reference's mount. Its site field is then the one the commissioning measured, or, when the site field is
measured at the start of a run, that measurement carried through the commissioned axes.
"""

from __future__ import annotations

import datetime as dt
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, Discriminator, Field, Tag

from drivers.turntable import TurntableOptions
from rig.core.configbase import Strict
from rig.core.errors import ConfigError
from rig.core.names import SafeName
from rig.core.numbers import ANGLE_DEG, NT, NT_VEC, bounded
from rig.fieldsources.base import (
    DRIFT_MAX_NT,
    SETTLE_TIMEOUT_S,
    FieldSourceConfig,
    point_limit_error,
)
from rig.fieldsources.fieldmaths import TYPICAL_FIELD_NT, TableReference, site_field_ned_nt, table_field_nt
from rig.fieldsources.turntable import commissioning

ORIENTATION_KINDS = frozenset({"grid", "orientations"})
HOMING_TRAVEL_DEG = 720.0  # the longest way home: a full turn on each axis
MOVE_TRAVEL_DEG = 360.0  # the longest move the settle wait allows for


class SiteFromReference(Strict):
    """Measured with the table at home by a reference magnetometer on the table
    (rig/reference/sitefield.py)."""

    reference_magnetometer: SafeName
    drift_max_nt: NT = Field(
        DRIFT_MAX_NT, description="a site field that moves more than this between steps holds the run")

    def stated_nt(self) -> np.ndarray | None:
        return None  # measured at the start of the campaign


class SiteFromModel(Strict):
    model: Literal["wmm", "igrf"] = "wmm"
    lat_deg: bounded(lo=-90, hi=90)
    lon_deg: bounded(lo=-180, hi=360)
    alt_km: bounded(lo=-10.0, hi=1_000.0) = 0.0
    date: dt.date

    def stated_nt(self) -> np.ndarray | None:
        return site_field_ned_nt(self.lat_deg, self.lon_deg, self.alt_km, self.date, self.model)


class SiteFromVector(Strict):
    vector_nt: NT_VEC = Field(description="north, east, down")

    def stated_nt(self) -> np.ndarray | None:
        return np.asarray(self.vector_nt, float)


_SITE_TAGS = {SiteFromReference: "reference", SiteFromVector: "vector", SiteFromModel: "model"}


def _site_kind(value: Any) -> str | None:
    if isinstance(value, dict):
        for key, tag in (("reference_magnetometer", "reference"), ("vector_nt", "vector"),
                         ("lat_deg", "model"), ("model", "model")):
            if key in value:
                return tag
    elif isinstance(value, BaseModel):
        return _SITE_TAGS[type(value)]
    return None


SiteField = Annotated[
    Annotated[SiteFromReference, Tag("reference")]
    | Annotated[SiteFromModel, Tag("model")]
    | Annotated[SiteFromVector, Tag("vector")],
    Discriminator(
        _site_kind,
        custom_error_type="site_field",
        custom_error_message="give one of reference_magnetometer, vector_nt, or model with lat_deg/lon_deg",
    ),
]


class Turntable(FieldSourceConfig, TurntableOptions):
    field_kinds: ClassVar[frozenset[str]] = ORIENTATION_KINDS
    point_letter: ClassVar[str] = "O"
    described: ClassVar[str] = "a turntable"
    frame_text: ClassVar[str] = ("the turntable's frame, turning with the DUT (at home x north, y east, z "
                                 "down), the DUT as it was mounted on the table")
    declared_words: ClassVar[str] = "the turntable's axes as drawn"
    commissioned_words: ClassVar[str] = "the turntable's axes as `rig commission` measured them"
    measured_name: ClassVar[str] = "site field"

    kind: Literal["turntable"]
    name: SafeName = "turntable"
    az_limits_deg: tuple[ANGLE_DEG, ANGLE_DEG] = (-360.0, 360.0)  # the driver's, within +-720
    el_limits_deg: tuple[ANGLE_DEG, ANGLE_DEG] = (-180.0, 180.0)
    rate_deg_s: bounded(gt=0, hi=1_000.0) = Field(10.0, description="slew rate, for move-time estimates")
    site_field: SiteField
    ambient_gradient_nt_per_m: bounded(lo=0, hi=1e6) | None = Field(
        None, description="the largest lab-field gradient dB_i/dx_j over the table (+-, nT/m): the budget's "
        "'ambient gradient' between where the reference magnetometer measured the site field and each DUT "
        "as the table turns")
    def stated_site_field_nt(self) -> np.ndarray | None:
        """The site field the station file states (None when a reference magnetometer must measure it)."""
        return self.site_field.stated_nt()

    # --- plan ---------------------------------------------------------------------------------------
    def record(self, target) -> dict:
        return {"az_deg": target[0], "el_deg": target[1]}

    def nominal_field_nt(self, target) -> np.ndarray:
        site = self.stated_site_field_nt()
        return table_field_nt(TYPICAL_FIELD_NT if site is None else site, *target)

    def check_targets(self, plan_name, points, warnings) -> list[str]:
        for p in points:
            for value, key, (lo, hi) in zip(p.command, ("az_limits_deg", "el_limits_deg"),
                                            (self.az_limits_deg, self.el_limits_deg), strict=True):
                if not lo <= value <= hi:
                    raise point_limit_error(plan_name, p, f"angle {value:g} deg is outside "
                                            f"field_source.{key} [{lo:g}, {hi:g}]")
        return []

    def move_time_s(self, targets) -> float:
        """Both axes move at once, from home through every target in turn."""
        angles = np.array([(0.0, 0.0), *targets])
        return float(np.abs(np.diff(angles, axis=0)).max(axis=1).sum()) / self.rate_deg_s

    # --- run ----------------------------------------------------------------------------------------
    def reference(self, measured_nt=None, positions_mm=None, ambient_at_mm=None) -> TableReference:
        """`measured_nt`: the site field measured at the start (needed with a reference magnetometer).
        The field is uniform: every DUT on the table sees the same, whatever its position."""
        axes = None if self._commissioned is None else self._commissioned.table_params
        if measured_nt is not None:
            if axes is None:
                return TableReference.ideal(measured_nt)
            from calib.commissioning.tablefit import site_from_home

            return TableReference(np.concatenate([site_from_home(axes, measured_nt), axes[3:]]))
        if axes is not None:
            return TableReference(axes)
        site = self.stated_site_field_nt()
        if site is None:
            raise ConfigError("the site field must be measured by the reference magnetometer first")
        return TableReference.ideal(site)

    def settle_timeout_s(self) -> float:
        return SETTLE_TIMEOUT_S + MOVE_TRAVEL_DEG / self.rate_deg_s

    def prepare(self, device) -> None:
        """A table that lost its home (power cycle) is homed before the first move."""
        if not device.read().homed:
            device.home()
            device.wait_settled(SETTLE_TIMEOUT_S + HOMING_TRAVEL_DEG / self.rate_deg_s)

    # --- a measured site field ---------------------------------------------------------------------
    def needs_measurement(self) -> bool:
        return self.stated_site_field_nt() is None

    def measuring_magnetometer(self, reference_names) -> str | None:
        return getattr(self.site_field, "reference_magnetometer", None)

    def measurement_setting(self) -> tuple[float, ...]:
        return (0.0, 0.0)  # home: table x north, y east, z down, so the reading is the site field (NED)

    def drift_max_nt(self) -> float:
        return getattr(self.site_field, "drift_max_nt", DRIFT_MAX_NT)

    # --- the reference chain ------------------------------------------------------------------------
    commissioning_section: ClassVar[str] = "table"
    commissioning_covariance_size: ClassVar[int] = 7  # the table's parameters
                                                      # (calib/commissioning/tablefit.py)

    def commissioning_design(self, current_a, repeats):
        return commissioning.design(self, repeats)

    def fit_commissioning(self, readings, reference_position_mm) -> dict:
        return commissioning.fit(self, readings)

    def commissioning_lines(self, section) -> list[str]:
        return commissioning.summary_lines(section)

    def uncertainty_caveat(self) -> str | None:
        if self.commissioned is not None:
            return None
        return ("the turntable is not commissioned: its axes are taken as drawn, so the calibrations' "
                "uncertainty leaves out their tilts and zero offsets; `rig commission` measures them")

    def budget_chain(self, run, dut: str, ds):
        from rig.fieldsources.turntable.budget import TableChain

        return TableChain(run, dut, ds)

    def ambient_in_references(self, run, ds):
        from rig.fieldsources.turntable.budget import home_readings, home_sensitivity, table_rows

        params, angles = table_rows(run, ds)
        return home_readings(params), home_sensitivity(params, angles)

    # --- station and simulation --------------------------------------------------------------------
    def station_problems(self, dut_names, reference_names=()):
        name = self.measuring_magnetometer(reference_names)
        if name is not None and name not in reference_names:
            known = ", ".join(reference_names) or "none defined"
            where = " (a DUT cannot double as the reference)" if name in dut_names else ""
            return [(("site_field", "reference_magnetometer"),
                     f"no reference magnetometer named {name!r}{where}; add it under "
                     f"reference_magnetometers (defined: {known})")]
        return []

    def declared_world(self) -> dict:
        """What the station declares of the table and its site field, as the simulated world's keywords."""
        stated = self.stated_site_field_nt()
        return {"field_source": "turntable", "turntable_rate_deg_s": self.rate_deg_s,
                "site_field_nt": None if stated is None else np.asarray(stated, float)}
