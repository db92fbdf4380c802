"""Opt-in hardware tests: `pytest tests/hw --station configs/stations/my-lab.yaml`. Skipped otherwise.

They only do what commissioning does: connect, make safe, read once; nothing moves or heats."""

from __future__ import annotations

import pytest

from rig.config import load_station
from rig.devices.build import check_devices, open_rig

pytestmark = pytest.mark.hw


def test_every_device_answers_and_identifies_itself(station_path):
    results = check_devices(load_station(station_path))
    failures = {name: error for name, _, _, error in results if error is not None}
    assert not failures, failures
    for name, describe, reading, _ in results:
        assert describe["name"] == name
        assert reading is not None


def test_open_rig_leaves_every_device_safe(station_path):
    station = load_station(station_path)
    rig = open_rig(station)
    try:
        assert rig.make_safe() == []
        coils = rig.field_source.read()
        if hasattr(coils, "setpoints_a"):
            assert coils.setpoints_a == (0.0, 0.0, 0.0) and not any(coils.enabled)
        chamber = rig.chamber.read()
        assert chamber.setpoint_c == pytest.approx(station.chamber.limits.safe_setpoint_c, abs=0.1)
    finally:
        rig.close()
