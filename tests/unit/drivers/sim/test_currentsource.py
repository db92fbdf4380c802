"""The coil current source as it really is (drivers/sim/world/currentsource.py), from `sim.current_source`,
seen through the real controller driver: what flows and what the read-back registers report."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.coils import CoilController
from drivers.sim.devices.coils import CoilSim
from drivers.transports.modbus import ModbusTransport
from tests.unit.drivers.sim.benches import world_of

GAIN_PPM = np.array([300.0, -200.0, 100.0])
OFFSET_MA = np.array([0.5, -0.3, 0.0])
READBACK_PPM = np.array([-400.0, 250.0, 600.0])
MICROAMP = 1e-6  # the read-back registers' resolution


def controller(port: int, clock) -> CoilController:
    link = ModbusTransport(name="coils", host="127.0.0.1", port=port, timeout_s=0.5, clock=clock)
    return CoilController(link, name="coils", clock=clock, max_current_a=2.0)


def delivered_a(world) -> np.ndarray:
    """The currents the world's field shows: C^-1 (B - ambient), with no ambient."""
    return np.linalg.solve(world.coil_constants, world.lab_field_nt())


def test_the_read_back_is_off_the_delivered_current_by_its_stated_ppm(tmp_path):
    errors = {"gain_error_ppm": GAIN_PPM.tolist(), "offset_ma": OFFSET_MA.tolist(),
              "readback_error_ppm": READBACK_PPM.tolist()}
    world, clock = world_of(tmp_path, sim={"current_source": errors})
    set_a = np.array([1.2, -0.8, 1.9])
    with CoilSim(world) as sim:
        coils = controller(sim.port, clock)
        coils.connect()
        coils.set(set_a.tolist())
        clock.sleep(1.0)  # the regulation has settled (50 ms lag)
        reading = coils.read()
        coils.close()
    flowing = delivered_a(world)
    np.testing.assert_allclose(flowing, set_a * (1 + GAIN_PPM * 1e-6) + OFFSET_MA * 1e-3, rtol=0, atol=1e-12)
    read_back = np.array(reading.currents_a)
    np.testing.assert_allclose(read_back, flowing * (1 + READBACK_PPM * 1e-6), rtol=0, atol=MICROAMP)
    assert reading.setpoints_a == tuple(set_a)  # what the rig commanded, as written


def test_current_noise_makes_the_field_wander_by_noise_ma(tmp_path):
    noise_ma = np.array([0.2, 0.05, 0.0])
    world, _ = world_of(tmp_path, sim={"current_source": {"noise_ma": noise_ma.tolist()}})
    world.set_coil_currents([1.0, 1.0, 1.0])
    n = 20_000
    currents = np.array([delivered_a(world) for _ in range(n)])
    spread_ma = currents.std(axis=0) * 1e3
    # the RMS's relative standard deviation is 1 / sqrt(2 n) = 0.5 %: 5 sigma
    np.testing.assert_allclose(spread_ma[:2], noise_ma[:2], rtol=5 / math.sqrt(2 * n))
    assert spread_ma[2] == 0.0 and currents[:, 2].mean() == pytest.approx(1.0, abs=1e-15)


def test_an_output_that_is_off_carries_no_offset(tmp_path):
    world, clock = world_of(tmp_path, sim={"current_source": {"offset_ma": [0.5, 0.5, 0.5]}})
    with CoilSim(world) as sim:
        coils = controller(sim.port, clock)
        coils.set([0.1, 0.2, 0.3])
        coils.safe_state()
        np.testing.assert_array_equal(world.lab_field_nt(), 0.0)
        coils.close()
