"""The reference field: coil math, the turntable rotation (same as the simulated world), and the WMM."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.sim.world import World
from rig.config import DEFAULT_STATION, Station, load_station
from rig.core.errors import ConfigError
from rig.fieldsources.fieldmaths import (
    CoilReference,
    TableReference,
    coil_field_nt,
    currents_for_field,
    reference_for,
    site_field_ned_nt,
    table_field_nt,
)

COILS = np.array([[40_000.0, 300.0, -120.0], [-250.0, 41_000.0, 80.0], [60.0, -90.0, 39_500.0]])
AMBIENT = np.array([15_000.0, -700.0, 42_000.0])


def test_coil_field_by_hand():
    assert np.allclose(coil_field_nt(COILS, [1.0, 0.0, 0.0], AMBIENT), [55_000.0, -950.0, 42_060.0])


def test_currents_for_field_inverts_the_coil_model():
    target = np.array([30_000.0, -20_000.0, 10_000.0])
    currents = currents_for_field(target, COILS, AMBIENT)
    assert np.allclose(COILS @ currents + AMBIENT, target)
    ref = CoilReference(COILS, AMBIENT)
    assert np.allclose(ref.field_nt(ref.currents_for(target)), target)


def test_coil_reference_matches_the_simulated_world():
    world = World(SimClock(), ambient_nt=AMBIENT, coil_constants_nt_per_a=COILS)
    ref = CoilReference(COILS, AMBIENT)
    currents = ref.currents_for([-25_000.0, 5_000.0, 48_000.0])
    world.set_coil_currents(currents)
    assert np.allclose(world.lab_field_nt(), [-25_000.0, 5_000.0, 48_000.0])


@pytest.mark.parametrize(("az", "el", "expected"), [
    (0, 0, (1.0, 2.0, 3.0)),
    (90, 0, (2.0, -1.0, 3.0)),   # table turned +90 deg about z: north now lies along the table's -y
    (0, 90, (-3.0, 2.0, 1.0)),   # tilted 90 deg about y
    (180, 0, (-1.0, -2.0, 3.0)),
])
def test_table_rotation_by_hand(az, el, expected):
    assert np.allclose(table_field_nt([1.0, 2.0, 3.0], az, el), expected)


def test_table_reference_matches_the_simulated_world():
    site = np.array([19_136.0, 891.0, 45_594.0])
    clock = SimClock()
    world = World(clock, field_source="turntable", site_field_nt=site)
    ref = TableReference.ideal(site)
    for az, el in [(30.0, 10.0), (-135.0, 75.0), (250.0, -40.0)]:
        world.set_turntable_target(az, el)
        clock.sleep(60.0)
        assert np.allclose(world.lab_field_nt(), ref.field_nt((az, el)))
        assert np.isclose(np.linalg.norm(ref.field_nt((az, el))), np.linalg.norm(site))


def test_wmm_at_the_hardware_notes_test_point():
    field = site_field_ned_nt(52.0, 5.0, 0.1, dt.date(2026, 1, 1))
    assert np.allclose(field, [19_136.2, 891.4, 45_594.0], atol=1.0)


def test_wmm_outside_its_life_span_and_unknown_models():
    with pytest.raises(ConfigError, match="WMM cannot be evaluated"):
        site_field_ned_nt(52.0, 5.0, 0.1, dt.date(2040, 1, 1))
    with pytest.raises(ConfigError, match="use model: wmm"):
        site_field_ned_nt(52.0, 5.0, 0.1, dt.date(2026, 1, 1), model="igrf")


def _table_station(site_field: dict) -> Station:
    data = load_station(DEFAULT_STATION).model_dump()
    data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"}, "site_field": site_field}
    return Station.model_validate(data)


def test_reference_for_each_kind_of_station():
    sim = load_station(DEFAULT_STATION)
    coils = reference_for(sim)
    assert isinstance(coils, CoilReference)
    assert np.allclose(coils.ambient_nt, sim.field_source.ambient_nt)
    model = reference_for(_table_station({"model": "wmm", "lat_deg": 52, "lon_deg": 5, "alt_km": 0.1,
                                          "date": "2026-01-01"}))
    assert np.allclose(model.site_field_nt, [19_136.2, 891.4, 45_594.0], atol=1.0)
    vector = reference_for(_table_station({"vector_nt": [1.0, 2.0, 3.0]}))
    assert np.allclose(vector.field_nt((90.0, 0.0)), [2.0, -1.0, 3.0])


def test_measured_quantities_must_be_supplied():
    data = load_station(DEFAULT_STATION).model_dump()
    data["reference_magnetometers"] = [{"name": "ref0", "type": "mmc5983ma", "transport": {"kind": "sim"},
                                        "calibration": "ref0.yaml"}]
    data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"},
                            "site_field": {"reference_magnetometer": "ref0"}}
    station = Station.model_validate(data)
    with pytest.raises(ConfigError, match="reference magnetometer"):
        reference_for(station)
    assert np.allclose(reference_for(station, [5.0, 0, 0]).site_field_nt, [5.0, 0, 0])
    data = load_station(DEFAULT_STATION).model_dump()
    data["reference_magnetometers"] = station.model_dump()["reference_magnetometers"]
    data["field_source"]["ambient_nt"] = "measure"
    measuring = Station.model_validate(data)
    with pytest.raises(ConfigError, match="measure it first"):
        reference_for(measuring)
    assert np.allclose(reference_for(measuring, AMBIENT).ambient_nt, AMBIENT)
