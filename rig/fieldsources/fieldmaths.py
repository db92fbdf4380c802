"""The true field at the DUT, from what the rig commands: the maths every field source uses.

Coils (lab frame):      B = C @ I + ambient        C: coil constants 3x3 (nT/A), I: currents (A)
                        I = C^-1 (B - ambient)     (`currents_for_field`, with C at the centre)
                        a DUT off the centre sees B = C(r) @ I + ambient, C(r) from the coil geometry
                        (rig/fieldsources/coils/config.py, coils/geometry.py)
Turntable (table frame): B_sensor = R^T @ B_site,  R = Rz(az) @ Ry(el)  (drivers.turntable.rotation_deg);
                        the table's home pose has x north, y east, z down, so B_site is NED. A
                        commissioned table (calib/commissioning/tablefit.py) adds its axes' tilt and zero
                        offsets.
Site field: a vector given in the station, measured by a reference magnetometer, or the World Magnetic
Model (WMM-2025, pygeomag) at the site's latitude, longitude, altitude and date, in nT north/east/down.

A Reference turns a plan target into the device's setting (`command`), and the device's readback into
the field at the sensor (`field_nt(readback(reading))`):

    ref = reference_for(station)        # station.field_source.reference(measured_nt)
    device.set(ref.command(target)); ref.field_nt(ref.readback(device.read()))
    ref.fields_nt(setting, duts)          # {DUT: field where it sits}, each field worked out once
"""

from __future__ import annotations

import datetime as dt

import numpy as np

from drivers.turntable import rotation_deg
from rig.core.errors import ConfigError

TYPICAL_FIELD_NT = (19_136.0, 891.0, 45_594.0)  # WMM at 52 N 5 E, 2026: used when nothing is stated


def coil_field_nt(coil_constants_nt_per_a, currents_a, ambient_nt) -> np.ndarray:
    return np.asarray(coil_constants_nt_per_a, float) @ np.asarray(currents_a, float) + np.asarray(
        ambient_nt, float
    )


def currents_for_field(target_nt, coil_constants_nt_per_a, ambient_nt) -> np.ndarray:
    """Coil currents (A) that make the total field `target_nt` (lab frame, nT)."""
    c = np.asarray(coil_constants_nt_per_a, float)
    return np.linalg.solve(c, np.asarray(target_nt, float) - np.asarray(ambient_nt, float))


def table_field_nt(site_field_nt, az_deg: float, el_deg: float) -> np.ndarray:
    """Field in the table (sensor mount) frame with the table at (az, el)."""
    return rotation_deg(az_deg, el_deg).T @ np.asarray(site_field_nt, float)


def site_field_ned_nt(lat_deg: float, lon_deg: float, alt_km: float, date: dt.date,
                      model: str = "wmm") -> np.ndarray:
    """Main field at a site from the World Magnetic Model (WMM-2025, valid 2025.0-2030.0), nT NED."""
    if model != "wmm":
        raise ConfigError(f"site field model {model!r} is not available here; use model: wmm")
    from pygeomag import GeoMag

    start = dt.date(date.year, 1, 1)
    days = (dt.date(date.year + 1, 1, 1) - start).days
    decimal_year = date.year + (date - start).days / days
    try:
        result = GeoMag().calculate(lat_deg, lon_deg, alt_km, decimal_year)
    except Exception as exc:  # pygeomag raises bare exceptions outside the model's life span
        raise ConfigError(f"site field: WMM cannot be evaluated for {date}: {exc}") from None
    return np.array([result.x, result.y, result.z])


class CoilReference:
    """Targets are total fields at the centre (lab frame); the device's setting is three currents.
    `matrices` ({DUT name: coil matrix where it sits}) gives each DUT the field at its own position, and
    `ambient_offsets` ({DUT name: nT}) the lab field's gradient between where the ambient was measured and
    the DUT, where the commissioning measured it."""

    def __init__(self, coil_constants_nt_per_a, ambient_nt, matrices: dict[str, np.ndarray] | None = None,
                 ambient_offsets: dict[str, np.ndarray] | None = None):
        self.coil_constants = np.asarray(coil_constants_nt_per_a, float)
        self.ambient_nt = np.asarray(ambient_nt, float)
        self.matrices = matrices or {}
        self.ambient_offsets = ambient_offsets or {}

    def field_nt(self, currents_a, where: str | None = None) -> np.ndarray:
        """The field at DUT `where` (at the centre for None or a DUT without a matrix of its own)."""
        field = coil_field_nt(self.matrices.get(where, self.coil_constants), currents_a, self.ambient_nt)
        offset = self.ambient_offsets.get(where)
        return field if offset is None else field + offset

    def fields_nt(self, currents_a, duts) -> dict[str, tuple[float, ...]]:
        """field_nt at each of `duts`, as tuples: worked out once per coil matrix (the DUTs without a
        position share the centre's), not once per DUT."""
        by_matrix: dict[int, np.ndarray] = {}
        out = {}
        for dut in duts:
            matrix = self.matrices.get(dut, self.coil_constants)
            if id(matrix) not in by_matrix:
                by_matrix[id(matrix)] = coil_field_nt(matrix, currents_a, self.ambient_nt)
            offset = self.ambient_offsets.get(dut)
            field = by_matrix[id(matrix)] if offset is None else by_matrix[id(matrix)] + offset
            out[dut] = tuple(field.tolist())
        return out

    def record(self) -> dict:
        """What a point stores of the reference it was taken with (the ambient in use)."""
        return {"ambient_nt": [float(v) for v in self.ambient_nt]}

    def currents_for(self, target_nt) -> np.ndarray:
        return currents_for_field(target_nt, self.coil_constants, self.ambient_nt)

    def command(self, target) -> np.ndarray:
        return self.currents_for(target)

    @staticmethod
    def readback(reading) -> tuple[float, float, float]:
        return reading.currents_a


class TableReference:
    """Targets are (az, el) orientations, which are also the device's setting. The table is
    calib.commissioning.tablefit's seven parameters: the ideal table in `site_field_nt` (`ideal`), or a
    commissioned one."""

    def __init__(self, params):
        self.params = np.asarray(params, float)

    @classmethod
    def ideal(cls, site_field_nt) -> TableReference:
        return cls(np.concatenate([np.asarray(site_field_nt, float), np.zeros(4)]))

    @property
    def site_field_nt(self) -> np.ndarray:
        return self.params[:3]

    def record(self) -> dict:
        """What a point stores of the reference it was taken with (the table's parameters in use)."""
        return {"table_params": [float(v) for v in self.params]}

    def field_nt(self, angles_deg, where: str | None = None) -> np.ndarray:
        """The field on the table at (az, el); the same for every DUT on it (a uniform site field)."""
        from calib.commissioning.tablefit import table_field_nt as fitted_field

        return fitted_field(self.params, [angles_deg])[0]

    def fields_nt(self, angles_deg, duts) -> dict[str, tuple[float, ...]]:
        """field_nt at each of `duts`, as tuples (one field for all)."""
        field = tuple(self.field_nt(angles_deg).tolist())
        return dict.fromkeys(duts, field)

    @staticmethod
    def command(target) -> tuple[float, ...]:
        return tuple(target)

    @staticmethod
    def readback(reading) -> tuple[float, float]:
        return reading.az_deg, reading.el_deg


def reference_for(station, measured_nt=None):
    """The station's reference. `measured_nt` (the ambient for coils, the site field for a turntable)
    must be given when the station says to measure it; when given, it overrides the station's value."""
    try:
        return station.field_source.reference(measured_nt, station.positions_mm(),
                                              station.ambient_position_mm())
    except ConfigError as exc:
        raise ConfigError(f"station {station.name}: {exc}") from None
