"""The simulated chamber as it really is (drivers/sim/world/chamberair.py), from the station's `sim.chamber`:
its own rate, its overshoot, and the field its heater and compressor add while they run."""

from __future__ import annotations

import numpy as np
import pytest

from tests.unit.drivers.sim.benches import world_of

HEATER_NT = np.array([0.0, 0.0, 400.0])
COMPRESSOR_NT = np.array([150.0, -80.0, 0.0])
CHAMBER = {"max_rate_c_per_min": 2.0, "overshoot_c": 0.8, "heater_field_nt": HEATER_NT.tolist(),
           "compressor_field_nt": COMPRESSOR_NT.tolist()}


def trace(world, clock, setpoint_c: float, seconds: int):
    """(air, what the chamber adds at the coil centre) every second after a new set point."""
    world.set_chamber_setpoint(setpoint_c)
    air, added = [], []
    for _ in range(seconds):
        clock.sleep(1.0)
        air.append(world.chamber_air_c())
        added.append(world.lab_field_nt())  # the ambient is zero and the coils are off
    return np.array(air), np.array(added)


def heater_on(added: np.ndarray) -> np.ndarray:
    return np.isclose(added[:, 2], HEATER_NT[2])


def compressor_on(added: np.ndarray) -> np.ndarray:
    return np.isclose(added[:, 0], COMPRESSOR_NT[0])


def test_the_air_keeps_to_the_chambers_own_rate_and_overshoots_by_overshoot_c(tmp_path):
    world, clock = world_of(tmp_path, sim={"chamber": CHAMBER})  # the station allows 5 degC/min
    air, _ = trace(world, clock, 60.0, 3600)
    assert np.max(np.abs(np.diff(air))) <= 2.0 / 60.0 + 1e-12
    assert np.max(air) - 60.0 == pytest.approx(0.8, rel=0.03)
    assert air[-1] == pytest.approx(60.0, abs=0.01)  # and settles
    down, _ = trace(world, clock, 20.0, 3600)
    assert np.max(np.abs(np.diff(down))) <= 2.0 / 60.0 + 1e-12
    assert 20.0 - np.min(down) == pytest.approx(0.8, rel=0.03)


def test_a_slow_ramp_overshoots_in_proportion(tmp_path):
    world, clock = world_of(tmp_path, sim={"chamber": CHAMBER})
    world.set_chamber_ramp(0.5)  # a quarter of the chamber's rate
    air, _ = trace(world, clock, 40.0, 6000)
    assert np.max(air) - 40.0 == pytest.approx(0.8 / 4, rel=0.05)


def test_heater_and_compressor_fields_switch_as_a_chamber_runs_them(tmp_path):
    world, clock = world_of(tmp_path, sim={"chamber": CHAMBER})
    air, added = trace(world, clock, 60.0, 3600)
    # only heater, compressor or both: nothing else reaches the coil centre
    for got in added:
        assert any(np.allclose(got, h * HEATER_NT + c * COMPRESSOR_NT) for h in (0, 1) for c in (0, 1))
    rising = np.flatnonzero(np.diff(air, prepend=air[0]) >= 2.0 / 60.0 - 1e-9)  # heating at full rate
    assert rising.size > 600 and np.all(heater_on(added[rising])) and not np.any(compressor_on(added))
    held = heater_on(added[-600:])  # holding at 60 degC: the heater trims, on for a share of each cycle
    assert 0.1 < np.mean(held) < 0.5 and np.count_nonzero(np.diff(held.astype(int))) >= 40
    air, added = trace(world, clock, 30.0, 1200)  # cooling at full rate: compressor on, heater off
    falling = np.flatnonzero(np.diff(air, prepend=air[0]) <= -2.0 / 60.0 + 1e-9)
    assert falling.size > 600 and not np.any(heater_on(added[falling]))
    assert np.all(compressor_on(added[falling]))
    air, added = trace(world, clock, -20.0, 7200)  # held below room: both run, the heater switching
    assert np.all(compressor_on(added[-600:]))
    assert 0.1 < np.mean(heater_on(added[-600:])) < 0.9


def test_the_field_reaches_every_dut(tmp_path):
    duts = {"a": {"position_mm": [50, 0, 0]}, "b": {"position_mm": [-50, 20, 0]}}
    for d in duts.values():
        d["sim"] = {"truth": {"S": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "noise_nt": 0}
    world, clock = world_of(tmp_path, sim={"chamber": CHAMBER}, duts=duts)
    world.set_chamber_setpoint(60.0)
    clock.sleep(600.0)  # heating at full rate: the heater is on
    for name in duts:
        np.testing.assert_allclose(world.lab_field_nt(name), HEATER_NT)
