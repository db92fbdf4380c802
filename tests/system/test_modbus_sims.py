"""Chamber, coils and turntable on one simulated RS-485 line (RTU framing, three unit ids)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.coils import CoilController
from drivers.sim.devices.chamber import ChamberSim
from drivers.sim.devices.coils import CoilSim
from drivers.sim.devices.modbus_server import ModbusSimServer
from drivers.sim.devices.turntable import TurntableSim
from drivers.sim.world import World
from drivers.transports.modbus import ModbusTransport
from drivers.turntable import Turntable
from drivers.watlow import WatlowF4T

pytestmark = pytest.mark.system


def test_three_devices_share_one_line():
    clock = SimClock()
    world = World(clock, field_source="coils")
    sims = [ChamberSim(world, "f4t", unit=1), CoilSim(world, unit=2), TurntableSim(world, unit=3)]
    server = ModbusSimServer([s.sim_device() for s in sims], framing="rtu")
    port = server.start()
    try:

        def link(name: str, unit: int) -> ModbusTransport:
            url = f"socket://127.0.0.1:{port}"
            return ModbusTransport(
                name=name, serial_port=url, baudrate=115200, unit=unit, timeout_s=0.3, clock=clock
            )

        chamber = WatlowF4T(
            link("chamber", 1),
            name="chamber",
            clock=clock,
            min_setpoint_c=-40,
            max_setpoint_c=125,
            max_ramp_c_per_min=5,
            safe_setpoint_c=25,
        )
        chamber.connect()
        chamber.set(40.0)
        chamber.close()  # one master on a serial line at a time: each driver opens, works, closes
        coils = CoilController(link("coils", 2), name="coils", clock=clock, max_current_a=1.0)
        coils.connect()
        coils.set([0.1, 0.2, -0.1])
        coils.wait_settled(timeout_s=2.0, tol_a=1e-4)
        coils.close()
        table = Turntable(
            link("turntable", 3),
            name="turntable",
            clock=clock,
            az_limits_deg=(-180, 180),
            el_limits_deg=(-90, 90),
        )
        table.connect()
        table.set((2.0, 0.0))
        table.wait_settled(timeout_s=5.0)
        table.close()
        np.testing.assert_allclose(world.lab_field_nt(), [5_000.0, 10_000.0, -5_000.0])
        assert world.setpoint_c == 40.0 and tuple(world.turntable_angles_deg()) == (2.0, 0.0)
        assert server.get_values(2, 0, 5)[0] == 0x4D41  # "MA" of the coil controller's model
    finally:
        server.stop()
