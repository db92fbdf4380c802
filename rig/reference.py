"""The true field at the DUT, from what the rig commands.

Coils (lab frame):      B = C @ I + ambient        C: coil constants 3x3 (nT/A), I: currents (A)
                        I = C^-1 (B - ambient)     (`currents_for_field`)
Turntable (table frame): B_sensor = R^T @ B_site,  R = Rz(az) @ Ry(el)  (drivers.sim.world.rotation_deg);
                        the table's home pose has x north, y east, z down, so B_site is NED.
Site field: a vector given in the station, measured by a reference magnetometer, or the World Magnetic
Model (WMM-2025, pygeomag) at the site's latitude, longitude, altitude and date, in nT north/east/down.

    ref = reference_for(station, ambient_nt=measured)  # CoilReference or TableReference
    ref.field_nt(target)                              # currents (coils) or (az, el) (turntable)
"""

from __future__ import annotations

import datetime as dt

import numpy as np

from drivers.sim.world import rotation_deg
from rig.config import Coils, SiteFromModel, SiteFromReference, SiteFromVector, Station, Turntable
from rig.errors import ConfigError


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
    def __init__(self, coil_constants_nt_per_a, ambient_nt):
        self.coil_constants = np.asarray(coil_constants_nt_per_a, float)
        self.ambient_nt = np.asarray(ambient_nt, float)

    def field_nt(self, currents_a) -> np.ndarray:
        return coil_field_nt(self.coil_constants, currents_a, self.ambient_nt)

    def currents_for(self, target_nt) -> np.ndarray:
        return currents_for_field(target_nt, self.coil_constants, self.ambient_nt)


class TableReference:
    def __init__(self, site_field_nt):
        self.site_field_nt = np.asarray(site_field_nt, float)

    def field_nt(self, angles_deg) -> np.ndarray:
        az_deg, el_deg = angles_deg
        return table_field_nt(self.site_field_nt, az_deg, el_deg)


def station_site_field_nt(table: Turntable) -> np.ndarray | None:
    """The site field the station file states (None when a reference magnetometer must measure it)."""
    site = table.site_field
    if isinstance(site, SiteFromVector):
        return np.asarray(site.vector_nt, float)
    if isinstance(site, SiteFromModel):
        return site_field_ned_nt(site.lat_deg, site.lon_deg, site.alt_km, site.date, site.model)
    assert isinstance(site, SiteFromReference)
    return None


def reference_for(station: Station, *, ambient_nt=None, site_field_nt=None) -> CoilReference | TableReference:
    """The reference for `station`. `ambient_nt` (coils) or `site_field_nt` (turntable) must be given when
    the station says to measure it; when given, they override the station's value."""
    source = station.field_source
    if isinstance(source, Coils):
        ambient = ambient_nt if ambient_nt is not None else source.ambient_nt
        if isinstance(ambient, str):
            raise ConfigError(f"station {station.name}: field_source.ambient_nt is 'measure': "
                              "measure it first")
        return CoilReference(source.constants, ambient)
    site = site_field_nt if site_field_nt is not None else station_site_field_nt(source)
    if site is None:
        raise ConfigError(f"station {station.name}: the site field must be measured by the reference "
                          "magnetometer first")
    return TableReference(site)
