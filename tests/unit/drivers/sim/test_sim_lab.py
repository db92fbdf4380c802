"""configs/stations/sim-lab.yaml: it loads with its commissioning, and its world has every deviation on."""

from __future__ import annotations

import numpy as np

from drivers.clock import SimClock
from rig.config import CONFIGS_DIR
from rig.config.loading import load_campaign
from rig.devices.simulated.world import make_world


def test_the_lab_station_turns_every_deviation_on():
    stations, plans = CONFIGS_DIR / "stations", CONFIGS_DIR / "plans"
    station = load_campaign(plans / "demo.yaml", stations / "sim-lab.yaml").station
    # its own commissioning file, found, checked and applied: the rig's matrix is the measured one
    assert np.allclose(station.field_source.constants, station.sim.coil_constants_nt_per_a, atol=20.0)
    world = make_world(station, SimClock())
    assert world.chamber.omega > 0 and world.chamber.makes_field and world.ramp_c_per_min < 3.0
    assert world.current_source is not None
    assert world.lab.gradient is not None and world.lab.steps is not None
    assert set(world.coil_loops) == {0, 1, 2}
    assert not any(loop.is_zero() for loop in world.coil_loops.values())
    duts = [d.name for d in station.duts]
    assert len(duts) >= 4
    for name in duts:
        state = world.duts[name]
        truth = state.truth
        assert truth.deviations is not None and np.all(truth.deviations.hysteresis_offset_nt != 0)
        assert np.any(truth.deviations.K2_per_c2) and np.any(truth.deviations.cubic_ppm_at_50ut)
        assert state.has_play and state.offset_noise is not None and truth.air_offset_c != 0
