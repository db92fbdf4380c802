"""Coil current controller: literal frames of our map, and the driver against the pymodbus simulator."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.coils import OUTPUT_ENABLE, SETPOINT_UA, CoilController
from drivers.errors import DeviceFault, DeviceTimeout, LimitError, OptionError, ProtocolError
from drivers.sim.devices.coils import CoilSim
from drivers.sim.devices.modbus_server import ScriptedPeer
from drivers.sim.devices.turntable import TurntableSim
from drivers.sim.world import World
from drivers.transports.modbus import ModbusTransport


@pytest.fixture
def clock():
    return SimClock()


@pytest.fixture
def world(clock):
    return World(clock, field_source="coils")  # 50 000 nT/A on each axis, no ambient


def controller(port: int, clock, max_current_a: float = 1.0) -> CoilController:
    link = ModbusTransport(name="coils", host="127.0.0.1", port=port, timeout_s=2.0, clock=clock)
    return CoilController(link, name="coils", clock=clock, max_current_a=max_current_a)


# --- transcripts ----------------------------------------------------------------------------------
def test_set_writes_three_int32_microamp_setpoints_then_enables(clock):
    script = [
        # FC16 at 100: +0.5 A = 500000 uA = 0x0007A120, -0.25 A = 0xFFFC2F70, +0.1 A = 0x000186A0
        (
            bytes.fromhex("0001 0000 0013 01 10 0064 0006 0c 0007a120 fffc2f70 000186a0"),
            bytes.fromhex("0001 0000 0006 01 10 0064 0006"),
        ),
        # FC16 at 112: outputs on
        (
            bytes.fromhex("0002 0000 000d 01 10 0070 0003 06 0001 0001 0001"),
            bytes.fromhex("0002 0000 0006 01 10 0070 0003"),
        ),
    ]
    with ScriptedPeer(script) as peer:
        coils = controller(peer.port, clock)
        coils.set([0.5, -0.25, 0.1])
        coils.close()
    assert peer.received == [request for request, _ in script]


def test_read_decodes_readback_enable_and_fault_bits(clock):
    reply = bytes.fromhex(
        "0001 0000 0027 01 03 24"
        "0007a120 00000000 000186a0"  # setpoints 0.5, 0, 0.1 A
        "0007a0f4 00000000 000186a0"  # readback 0.499956, 0, 0.1 A
        "0001 0000 0001"  # enables
        "0003 0004 000b"  # status: x on+settled, y over-temperature, z on+settled+compliance
    )
    script = [(bytes.fromhex("0001 0000 0006 01 03 0064 0012"), reply)]
    with ScriptedPeer(script) as peer:
        coils = controller(peer.port, clock)
        reading = coils.read()
        coils.close()
    assert peer.received == [script[0][0]]
    assert reading.setpoints_a == (0.5, 0.0, 0.1)
    assert reading.currents_a == (0.499956, 0.0, 0.1)
    assert reading.enabled == (True, False, True)
    assert reading.faults == {"y:over_temperature", "z:compliance"}
    assert reading.settled == (True, False, True)  # status bit 1


# --- against the simulator ------------------------------------------------------------------------
def test_currents_make_the_field_and_settle(world, clock):
    with CoilSim(world) as sim:
        coils = controller(sim.port, clock)
        coils.connect()
        coils.set([0.5, -0.25, 0.1])
        np.testing.assert_allclose(world.lab_field_nt(), [25_000.0, -12_500.0, 5_000.0])
        first = coils.read()
        assert first.currents_a[0] < 0.5  # the readback lags the setpoint
        reading = coils.wait_settled(timeout_s=2.0, tol_a=1e-5)
        np.testing.assert_allclose(reading.currents_a, [0.5, -0.25, 0.1], atol=1e-5)
        assert reading.enabled == (True, True, True) and not reading.faults
        assert clock.now() > first.t  # waiting went through the simulated clock
        coils.close()


def test_limit_violation_writes_nothing(world, clock):
    with CoilSim(world) as sim:
        coils = controller(sim.port, clock, max_current_a=1.0)
        seen = sim.server.requests_seen
        with pytest.raises(LimitError, match="current \\+1.5000 A on axis y exceeds max_current_a 1.0 A"):
            coils.set([0.0, 1.5, 0.0])
        with pytest.raises(LimitError, match="axis z"):
            coils.set([0.0, 0.0, float("nan")])
        with pytest.raises(LimitError, match="expected 3 currents"):
            coils.set([0.1, 0.2])
        assert sim.server.requests_seen == seen
        assert sim.register_values(SETPOINT_UA, 6) == [0] * 6
        np.testing.assert_array_equal(world.lab_field_nt(), 0.0)


def test_compliance_fault_stops_wait_settled(world, clock):
    with CoilSim(world, compliance_limit_a=0.8) as sim:
        coils = controller(sim.port, clock)
        coils.connect()
        assert coils.compliance_limit_a == (0.8, 0.8, 0.8)
        coils.set([0.9, 0.0, 0.0])
        with pytest.raises(DeviceFault, match="coils: wait settled: controller reports x:compliance"):
            coils.wait_settled(timeout_s=2.0)
        assert world.lab_field_nt()[0] == pytest.approx(0.8 * 50_000.0)
        coils.close()


def test_over_temperature_trips_an_axis_until_cleared(world, clock):
    with CoilSim(world) as sim:
        coils = controller(sim.port, clock)
        coils.set([0.2, 0.2, 0.2])
        sim.trip_over_temperature(1)
        reading = coils.read()
        assert reading.faults == {"y:over_temperature"} and reading.enabled == (True, False, True)
        assert world.lab_field_nt()[1] == 0.0
        coils.clear_faults()
        coils.set([0.2, 0.2, 0.2])
        assert coils.wait_settled(timeout_s=2.0).enabled == (True, True, True)
        assert world.lab_field_nt()[1] == pytest.approx(10_000.0)
        coils.close()


def test_safe_state_zeroes_then_switches_off(world, clock):
    with CoilSim(world) as sim:
        coils = controller(sim.port, clock)
        coils.set([0.3, 0.0, -0.3])
        coils.safe_state()
        coils.safe_state()  # safe to repeat
        assert sim.register_values(SETPOINT_UA, 6) == [0] * 6
        assert sim.register_values(OUTPUT_ENABLE, 3) == [0, 0, 0]
        assert not world.coils_enabled
        np.testing.assert_array_equal(world.lab_field_nt(), 0.0)
        coils.close()


def test_slow_source_times_out_on_the_clock(world, clock):
    with CoilSim(world, settle_tau_s=100.0) as sim:
        coils = controller(sim.port, clock)
        coils.set([0.5, 0.0, 0.0])
        start = clock.now()
        expected = r"coils: wait settled: readback .* not within \(0.001, 0.001, 0.001\) A"
        with pytest.raises(DeviceTimeout, match=expected):
            coils.wait_settled(timeout_s=0.5, tol_a=1e-3)
        assert clock.now() - start == pytest.approx(0.5, abs=0.02)
        coils.close()


def test_exception_reply_on_set_is_a_protocol_error(world, clock):
    with CoilSim(world) as sim:
        coils = controller(sim.port, clock)
        sim.fail_next(1, 3)
        with pytest.raises(ProtocolError, match="coils: write setpoints .*exception reply 3"):
            coils.set([0.1, 0.0, 0.0])
        coils.close()


def test_connect_checks_identity_and_rating(world, clock):
    with TurntableSim(world) as table:
        with pytest.raises(ProtocolError, match="is not a MAGRIG-HC3 controller"):
            controller(table.port, clock).connect()
    with CoilSim(world, rated_current_a=3.0) as sim:
        with pytest.raises(OptionError, match="max_current_a 5.0 A exceeds the controller's rating 3.0 A"):
            controller(sim.port, clock, max_current_a=5.0).connect()
        coils = controller(sim.port, clock)
        coils.connect()
        info = coils.describe()
        assert info["model"].startswith("MAGRIG-HC3") and info["firmware"] == "1.2"
        coils.close()
