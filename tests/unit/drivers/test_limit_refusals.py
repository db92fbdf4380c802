"""Each moving driver refuses a command outside its limits, or not a finite number, before it sends a
single request: the simulator counts no request and its registers and world stay as they were. A limit
that is itself NaN refuses everything (a check written as "refuse unless provably inside")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.chamber import F4T_RAMP_RATE, F4T_SETPOINT
from drivers.clock import SimClock
from drivers.coils import SETPOINT_UA, CoilController
from drivers.errors import LimitError, OptionError
from drivers.sim.devices.chamber import ChamberSim
from drivers.sim.devices.coils import CoilSim
from drivers.sim.devices.turntable import TurntableSim
from drivers.sim.world import World
from drivers.transports.modbus import ModbusTransport
from drivers.turntable import TARGET_MDEG, Turntable
from drivers.watlow import WatlowF4T

NAN, INF = float("nan"), float("inf")
CHAMBER = dict(min_setpoint_c=-40.0, max_setpoint_c=85.0, max_ramp_c_per_min=5.0, safe_setpoint_c=25.0)


@pytest.fixture
def clock():
    return SimClock()


def link(name: str, port: int, clock) -> ModbusTransport:
    return ModbusTransport(name=name, host="127.0.0.1", port=port, timeout_s=2.0, clock=clock)


@pytest.mark.parametrize("call, value, limits", [
    ("set", 200.0, {}), ("set", -41.0, {}), ("set", NAN, {}), ("set", INF, {}), ("set", -INF, {}),
    ("set", True, {}), ("set", "25", {}),
    ("set_ramp_rate", 50.0, {}), ("set_ramp_rate", INF, {}), ("set_ramp_rate", NAN, {}),
    ("set_ramp_rate", 0.0, {}), ("set_ramp_rate", True, {}),
    ("set_ramp_rate", 1.0, {"max_ramp_c_per_min": NAN}),
])
def test_chamber_refuses_before_writing(call, value, limits, clock):
    world = World(clock, air_c=22.0, ramp_c_per_min=3.0)
    with ChamberSim(world, "f4t") as sim:
        chamber = WatlowF4T(link("chamber", sim.port, clock), name="chamber", clock=clock,
                            **{**CHAMBER, **limits})
        before = sim.register_values(F4T_SETPOINT, 2), sim.register_values(F4T_RAMP_RATE, 2)
        seen = sim.server.requests_seen
        with pytest.raises(LimitError, match="^chamber: "):
            getattr(chamber, call)(value)
        assert sim.server.requests_seen == seen
        assert (sim.register_values(F4T_SETPOINT, 2), sim.register_values(F4T_RAMP_RATE, 2)) == before
        assert world.setpoint_c == 22.0
        chamber.close()


@pytest.mark.parametrize("currents, max_current_a", [
    ([0.0, 0.0, 10.0], 2.0), ([NAN, 0.0, 0.0], 2.0), ([0.0, -INF, 0.0], 2.0), ([True, 0.0, 0.0], 2.0),
    ([0.1, 0.0, 0.0], NAN), ([0.0, 0.0, 2.0 + 1e-9], 2.0),
])
def test_coils_refuse_before_writing(currents, max_current_a, clock):
    world = World(clock, field_source="coils")
    with CoilSim(world) as sim:
        coils = CoilController(link("coils", sim.port, clock), name="coils", clock=clock,
                               max_current_a=max_current_a)
        seen = sim.server.requests_seen
        with pytest.raises(LimitError, match="^coils: "):
            coils.set(currents)
        assert sim.server.requests_seen == seen
        assert sim.register_values(SETPOINT_UA, 6) == [0] * 6
        np.testing.assert_array_equal(world.lab_field_nt(), 0.0)
        coils.close()


@pytest.mark.parametrize("angles, az_limits", [
    ((190.0, 0.0), (-180.0, 180.0)), ((NAN, 0.0), (-180.0, 180.0)), ((0.0, INF), (-180.0, 180.0)),
    ((0.0, False), (-180.0, 180.0)), ((0.0, 0.0), (NAN, 180.0)),
])
def test_turntable_refuses_before_writing(angles, az_limits, clock):
    world = World(clock, field_source="turntable", turntable_rate_deg_s=10.0)
    with TurntableSim(world) as sim:
        table = Turntable(link("turntable", sim.port, clock), name="turntable", clock=clock,
                          az_limits_deg=az_limits, el_limits_deg=(-90.0, 90.0))
        before = sim.register_values(TARGET_MDEG, 4)
        seen = sim.server.requests_seen
        with pytest.raises(LimitError, match="^turntable: "):
            table.set(angles)
        assert sim.server.requests_seen == seen
        assert sim.register_values(TARGET_MDEG, 4) == before
        assert not world.turntable_moving()
        table.close()


@pytest.mark.parametrize("key", ["min_setpoint_c", "max_setpoint_c"])
def test_a_chamber_with_a_nan_setpoint_limit_is_not_built(key, clock):
    with pytest.raises(OptionError, match="safe_setpoint_c 25.0 is outside"):
        WatlowF4T(link("chamber", 1, clock), name="chamber", clock=clock, **{**CHAMBER, key: NAN})


def test_a_nan_limit_message_still_names_the_limit(clock):
    chamber = WatlowF4T(link("chamber", 1, clock), name="chamber", clock=clock,
                        **{**CHAMBER, "max_ramp_c_per_min": NAN})
    with pytest.raises(LimitError, match="max_ramp_c_per_min nan"):
        chamber.set_ramp_rate(1.0)
    assert math.isnan(chamber.max_ramp_c_per_min)
