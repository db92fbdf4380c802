"""The DUTs' temperatures stepped as arrays (drivers/sim/world/dutthermal.py): each DUT follows its own lags
and play, exactly, whatever the others are."""

from __future__ import annotations

import math

import pytest

from drivers.sim.world.dutthermal import DutTemperatures


def three_duts() -> tuple[DutTemperatures, list[int]]:
    temps = DutTemperatures()
    ids = [
        temps.add(start_c=20.0, lag_s=300.0, sensor_lag_s=0.0, air_offset_c=0.0, play_band_c=None),
        temps.add(start_c=10.0, lag_s=600.0, sensor_lag_s=120.0, air_offset_c=1.5, play_band_c=None),
        temps.add(start_c=25.0, lag_s=100.0, sensor_lag_s=0.0, air_offset_c=-0.5, play_band_c=5.0),
    ]
    return temps, ids


def test_each_element_follows_the_air_at_its_place_through_its_own_lag():
    temps, (a, b, c) = three_duts()
    temps.step(air_c=40.0, dt=150.0)
    assert temps.element_c[a] == pytest.approx(40.0 + (20.0 - 40.0) * math.exp(-150.0 / 300.0), abs=1e-12)
    assert temps.element_c[b] == pytest.approx(41.5 + (10.0 - 41.5) * math.exp(-150.0 / 600.0), abs=1e-12)
    assert temps.element_c[c] == pytest.approx(39.5 + (25.0 - 39.5) * math.exp(-150.0 / 100.0), abs=1e-12)


def test_a_sensor_without_a_lag_reads_its_element_and_one_with_a_lag_trails_it():
    temps, (a, b, c) = three_duts()
    temps.step(air_c=40.0, dt=30.0)
    assert temps.sensor_c[a] == temps.element_c[a] and temps.sensor_c[c] == temps.element_c[c]
    element = temps.element_c[b]
    assert temps.sensor_c[b] == pytest.approx(element + (10.0 - element) * math.exp(-30.0 / 120.0), abs=1e-12)
    assert 10.0 < temps.sensor_c[b] < element  # heating: the sensor behind its element


def test_the_play_moves_with_the_element_saturates_and_only_where_there_is_hysteresis():
    temps, (a, b, c) = three_duts()
    temps.step(air_c=26.5, dt=1.0)  # the third's place is 26.0: its element gains under 1 degC
    gained = temps.element_c[c] - 25.0
    assert 0.0 < gained < 1.0 and temps.play[c] == pytest.approx(2.0 * gained / 5.0, abs=1e-12)
    temps.step(air_c=60.0, dt=1000.0)  # tens of degrees up: saturated
    assert temps.play[c] == 1.0
    temps.step(air_c=-20.0, dt=1000.0)  # and as far down
    assert temps.play[c] == -1.0
    assert temps.play[a] == temps.play[b] == 0.0
