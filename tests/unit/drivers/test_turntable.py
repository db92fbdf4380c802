"""2-axis turntable: literal frames of our map, and the driver against the pymodbus simulator."""

from __future__ import annotations

import pytest

from drivers.clock import SimClock
from drivers.errors import DeviceFault, DeviceTimeout, LimitError, ProtocolError
from drivers.sim.devices.modbus_server import ScriptedPeer
from drivers.sim.devices.turntable import TurntableSim
from drivers.sim.world import World
from drivers.transports.modbus import ModbusTransport
from drivers.turntable import TARGET_MDEG, Turntable


@pytest.fixture
def clock():
    return SimClock()


@pytest.fixture
def world(clock):
    return World(clock, field_source="turntable", turntable_rate_deg_s=10.0)


def table(port: int, clock, *, rtu: bool = False) -> Turntable:
    where = (
        {"serial_port": f"socket://127.0.0.1:{port}", "baudrate": 115200}
        if rtu
        else {"host": "127.0.0.1", "port": port}
    )
    link = ModbusTransport(name="turntable", timeout_s=2.0, clock=clock, **where)
    return Turntable(
        link, name="turntable", clock=clock, az_limits_deg=(-180.0, 180.0), el_limits_deg=(-90.0, 90.0)
    )


# --- transcripts ----------------------------------------------------------------------------------
def test_move_frames(clock):
    script = [
        # status 109 (0x6D): in-position + homed
        (bytes.fromhex("0001 0000 0006 01 03 006d 0001"), bytes.fromhex("0001 0000 0005 01 03 02 0009")),
        # targets at 104 (0x68): az 90.000 deg = 90000 mdeg = 0x00015F90, el -45.500 deg = 0xFFFF4E44
        (
            bytes.fromhex("0002 0000 000f 01 10 0068 0004 08 00015f90 ffff4e44"),
            bytes.fromhex("0002 0000 0006 01 10 0068 0004"),
        ),
        # command 108 (0x6C) = 1, move
        (bytes.fromhex("0003 0000 0006 01 06 006c 0001"), bytes.fromhex("0003 0000 0006 01 06 006c 0001")),
    ]
    with ScriptedPeer(script) as peer:
        tt = table(peer.port, clock)
        tt.set((90.0, -45.5))
        tt.close()
    assert peer.received == [request for request, _ in script]


def test_read_decodes_positions_and_status(clock):
    reply = bytes.fromhex(
        "0001 0000 0017 01 03 14"
        "00003039 ffffec78"  # position az 12.345, el -5.000 deg
        "00003039 ffffec78"  # targets
        "0000"  # command
        "000a"  # status: moving + homed
    )
    script = [(bytes.fromhex("0001 0000 0006 01 03 0064 000a"), reply)]
    with ScriptedPeer(script) as peer:
        tt = table(peer.port, clock)
        reading = tt.read()
        tt.close()
    assert peer.received == [script[0][0]]
    assert (reading.az_deg, reading.el_deg) == (12.345, -5.0)
    assert reading.moving and reading.homed and not reading.in_position and not reading.fault


# --- against the simulator ------------------------------------------------------------------------
def test_moves_and_reports_in_position(world, clock):
    with TurntableSim(world) as sim:
        tt = table(sim.port, clock)
        tt.connect()
        tt.set((90.0, -45.5))
        assert tt.read().moving
        reading = tt.wait_settled(timeout_s=30.0)
        assert (reading.az_deg, reading.el_deg) == (90.0, -45.5) and reading.in_position
        assert clock.now() - reading.t < 0.1 and 9.0 <= world.clock.now() - 1_767_225_600.0 < 9.5
        assert tuple(world.turntable_angles_deg()) == (90.0, -45.5)
        tt.close()


def test_limits_checked_before_anything_is_written(world, clock):
    with TurntableSim(world) as sim:
        tt = table(sim.port, clock)
        before = sim.register_values(TARGET_MDEG, 4)
        seen = sim.server.requests_seen
        with pytest.raises(LimitError, match="turntable: az 190.000 deg is outside az_limits_deg"):
            tt.set((190.0, 0.0))
        with pytest.raises(LimitError, match="el -95.000 deg is outside el_limits_deg \\[-90.0, 90.0\\]"):
            tt.set((0.0, -95.0))
        assert sim.server.requests_seen == seen
        assert sim.register_values(TARGET_MDEG, 4) == before
        assert not world.turntable_moving()


def test_device_soft_limits_refuse_what_the_station_allows(world, clock):
    with TurntableSim(world, el_limits_deg=(-45.0, 45.0)) as sim:
        tt = table(sim.port, clock)
        with pytest.raises(ProtocolError, match="exception reply 3"):
            tt.set((0.0, 60.0))
        assert not world.turntable_moving()
        tt.close()


def test_stop_mid_move_then_safe_state(world, clock):
    with TurntableSim(world) as sim:
        tt = table(sim.port, clock)
        tt.set((100.0, 0.0))
        clock.sleep(2.0)
        tt.stop()
        reading = tt.wait_settled(timeout_s=1.0)
        assert reading.az_deg == pytest.approx(20.0, abs=0.01) and reading.in_position
        clock.sleep(5.0)
        assert tt.read().az_deg == pytest.approx(20.0, abs=0.01)
        tt.safe_state()
        tt.close()


def test_unhomed_table_must_home_first(world, clock):
    world.table_deg[:] = (30.0, 10.0)
    world.table_target_deg[:] = (30.0, 10.0)
    with TurntableSim(world, homed=False) as sim:
        tt = table(sim.port, clock)
        with pytest.raises(DeviceFault, match="not homed; call home\\(\\) first"):
            tt.set((10.0, 0.0))
        tt.home()
        reading = tt.wait_settled(timeout_s=10.0)
        assert reading.homed and (reading.az_deg, reading.el_deg) == (0.0, 0.0)
        tt.set((10.0, 0.0))
        assert tt.wait_settled(timeout_s=5.0).az_deg == 10.0
        tt.close()


def test_drive_fault_is_reported(world, clock):
    with TurntableSim(world) as sim:
        tt = table(sim.port, clock)
        tt.set((50.0, 0.0))
        clock.sleep(1.0)
        world.table_fault = True
        with pytest.raises(DeviceFault, match="turntable: wait settled: drive fault code 1"):
            tt.wait_settled(timeout_s=10.0)
        with pytest.raises(DeviceFault, match="clear it first"):
            tt.set((0.0, 0.0))
        tt.clear_fault()
        tt.set((0.0, 0.0))
        assert tt.wait_settled(timeout_s=10.0).az_deg == 0.0
        tt.close()


def test_wait_settled_times_out_on_the_clock(world, clock):
    with TurntableSim(world) as sim:
        tt = table(sim.port, clock)
        tt.set((180.0, 0.0))  # 18 s at 10 deg/s
        with pytest.raises(DeviceTimeout, match="turntable: wait settled: not in position after 2 s"):
            tt.wait_settled(timeout_s=2.0)
        tt.close()


def test_rtu_framing_against_the_simulator(world, clock):
    with TurntableSim(world, framing="rtu") as sim:
        tt = table(sim.port, clock, rtu=True)
        tt.connect()
        assert tt.describe()["device_soft_limits_deg"] == (-360.0, 360.0, -90.0, 90.0)
        tt.set((-3.0, 1.5))
        assert tt.wait_settled(timeout_s=10.0).el_deg == 1.5
        tt.close()
