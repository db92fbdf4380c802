"""Watlow F4T / F4 chamber drivers: literal frames, and the drivers against the pymodbus simulator.

Register addresses in the frames are the ones hardware-notes 3.1 / 3.2 document (PV 100, input error
101, SP 300, precision 606, units 901; F4T 2782, 2794, 2796, 2798, 2810, 27586); the alarm register is
the station's, given to the driver explicitly."""

from __future__ import annotations

import pytest

from drivers.chamber import F4_SETPOINT, F4T_SETPOINT, ChamberAlarm
from drivers.clock import SimClock
from drivers.errors import DeviceNotFound, DeviceTimeout, LimitError, OptionError, ProtocolError
from drivers.sim.devices.chamber import ChamberSim
from drivers.sim.devices.modbus_server import ScriptedPeer
from drivers.sim.world import World
from drivers.transports.modbus import ModbusTransport
from drivers.watlow import WatlowF4, WatlowF4T

LIMITS = dict(min_setpoint_c=-40.0, max_setpoint_c=125.0, max_ramp_c_per_min=5.0, safe_setpoint_c=25.0)


# a reply is waited for 2 s: a loaded machine may take tenths of a second to answer on loopback; a test of
# the timeout itself gives its own
def transport(port: int, clock, *, rtu: bool = False, timeout_s: float = 2.0) -> ModbusTransport:
    where = (
        {"serial_port": f"socket://127.0.0.1:{port}", "baudrate": 115200}
        if rtu
        else {"host": "127.0.0.1", "port": port}
    )
    return ModbusTransport(name="chamber", timeout_s=timeout_s, clock=clock, **where)


@pytest.fixture
def clock():
    return SimClock()


@pytest.fixture
def world(clock):
    return World(clock, air_c=22.0, ramp_c_per_min=3.0)


def f4t(port, clock, timeout_s: float = 2.0, **kw):
    return WatlowF4T(transport(port, clock, timeout_s=timeout_s), name="chamber", clock=clock, **LIMITS, **kw)


# --- transcripts ----------------------------------------------------------------------------------
def test_f4t_setpoint_frame_is_low_word_first(clock):
    # 85.0 degC = 0x42AA0000 -> FC16 at 2782 (0x0ADE) with registers [0x0000, 0x42AA]
    script = [
        (
            bytes.fromhex("0001 0000 000b 01 10 0ade 0002 04 0000 42aa"),
            bytes.fromhex("0001 0000 0006 01 10 0ade 0002"),
        )
    ]
    with ScriptedPeer(script) as peer:
        chamber = f4t(peer.port, clock)
        chamber.set(85.0)
        chamber.close()
    assert peer.received == [script[0][0]]


def test_f4t_read_touches_only_documented_registers(clock):
    script = [
        # 27586 (0x6BC2): 23.5 degC = 0x41BC0000, low word first
        (bytes.fromhex("0001 0000 0006 01 03 6bc2 0002"), bytes.fromhex("0001 0000 0007 01 03 04 0000 41bc")),
        # 2782 (0x0ADE) setpoint: -20.0 = 0xC1A00000
        (bytes.fromhex("0002 0000 0006 01 03 0ade 0002"), bytes.fromhex("0002 0000 0007 01 03 04 0000 c1a0")),
        # 2810 (0x0AFA) closed-loop setpoint: 10.0 = 0x41200000
        (bytes.fromhex("0003 0000 0006 01 03 0afa 0002"), bytes.fromhex("0003 0000 0007 01 03 04 0000 4120")),
    ]
    with ScriptedPeer(script) as peer:
        chamber = f4t(peer.port, clock)
        reading = chamber.read()
        chamber.close()
    assert peer.received == [request for request, _ in script]  # nothing else was asked
    assert (reading.air_c, reading.setpoint_c, reading.closed_loop_c) == (23.5, -20.0, 10.0)
    assert not reading.input_error and not reading.alarm and reading.t == clock.now()


def test_f4t_reads_the_alarm_register_only_when_the_station_names_it(clock):
    alarm = {"register": 1234, "kind": "bits", "bits": {0: "high limit", 2: "door open"}}
    reads = [
        (bytes.fromhex("0001 0000 0006 01 03 6bc2 0002"), bytes.fromhex("0001 0000 0007 01 03 04 0000 41bc")),
        (bytes.fromhex("0002 0000 0006 01 03 0ade 0002"), bytes.fromhex("0002 0000 0007 01 03 04 0000 41bc")),
        (bytes.fromhex("0003 0000 0006 01 03 0afa 0002"), bytes.fromhex("0003 0000 0007 01 03 04 0000 41bc")),
        # the station's alarm register 1234 (0x04D2) reads 0x000D: bits 0, 2, 3 (3 is not listed: ignored)
        (bytes.fromhex("0004 0000 0006 01 03 04d2 0001"), bytes.fromhex("0004 0000 0005 01 03 02 000d")),
    ]
    with ScriptedPeer(reads) as peer:
        chamber = f4t(peer.port, clock, alarm=alarm)
        reading = chamber.read()
        chamber.close()
    assert peer.received == [request for request, _ in reads]
    assert reading.alarm and reading.fault
    assert reading.problems == ("alarm: register 1234 = 0x000D (bit 0 high limit, bit 2 door open)",)


def test_f4t_ramp_frames(clock):
    script = [
        # ramp scale 2796 (0x0AEC) = 57 (degrees per minute)
        (bytes.fromhex("0001 0000 0006 01 06 0aec 0039"), bytes.fromhex("0001 0000 0006 01 06 0aec 0039")),
        # ramp rate 2798 (0x0AEE) = 2.0 = 0x40000000, low word first
        (
            bytes.fromhex("0002 0000 000b 01 10 0aee 0002 04 0000 4000"),
            bytes.fromhex("0002 0000 0006 01 10 0aee 0002"),
        ),
        # ramp action 2794 (0x0AEA) = 85 (ramp on set point changes)
        (bytes.fromhex("0003 0000 0006 01 06 0aea 0055"), bytes.fromhex("0003 0000 0006 01 06 0aea 0055")),
    ]
    with ScriptedPeer(script) as peer:
        chamber = f4t(peer.port, clock)
        chamber.set_ramp_rate(2.0)
        chamber.close()
    assert peer.received == [request for request, _ in script]


def test_f4_legacy_over_rtu_reads_precision_then_scales(clock):
    script = [
        (bytes.fromhex("01 03 025e 0001 e460"), bytes.fromhex("01 03 02 0001 7984")),  # 606 precision = 1
        (bytes.fromhex("01 03 0385 0001 95a7"), bytes.fromhex("01 03 02 0001 7984")),  # 901 units = degC
        (bytes.fromhex("01 06 012c 0352 c8f2"), bytes.fromhex("01 06 012c 0352 c8f2")),  # SP 300 = 850
        (
            bytes.fromhex("01 03 0064 0002 85d4"),
            bytes.fromhex("01 03 04 00e9 0000 2bc7"),
        ),  # PV 23.3, no error
        (bytes.fromhex("01 03 012c 0001 443f"), bytes.fromhex("01 03 02 0352 3949")),  # SP 85.0
    ]
    with ScriptedPeer(script) as peer:
        chamber = WatlowF4(transport(peer.port, clock, rtu=True), name="chamber", clock=clock, **LIMITS)
        chamber.connect()
        chamber.set(85.0)
        reading = chamber.read()
        chamber.close()
    assert peer.received == [request for request, _ in script]
    assert reading.air_c == pytest.approx(23.3) and reading.setpoint_c == 85.0 and not reading.fault


# --- against the simulator ------------------------------------------------------------------------
def test_setpoint_moves_the_world_air_on_simulated_time(world, clock):
    with ChamberSim(world, "f4t") as sim:
        chamber = f4t(sim.port, clock)
        chamber.connect()
        assert chamber.read().air_c == pytest.approx(22.0)
        chamber.set(85.0)
        clock.sleep(600.0)  # 10 min at 3 degC/min
        reading = chamber.read()
        assert reading.air_c == pytest.approx(52.0, abs=0.01) and reading.setpoint_c == 85.0
        chamber.set_ramp_rate(1.0)
        clock.sleep(600.0)
        assert chamber.read().air_c == pytest.approx(62.0, abs=0.01)
        chamber.safe_state()
        assert world.setpoint_c == 25.0
        chamber.close()


def test_limit_violation_writes_nothing(world, clock):
    with ChamberSim(world, "f4t") as sim:
        chamber = f4t(sim.port, clock)
        before = sim.register_values(F4T_SETPOINT, 2)
        seen = sim.server.requests_seen
        with pytest.raises(LimitError, match="chamber: setpoint 130.0 degC is above max_setpoint_c 125.0"):
            chamber.set(130.0)
        with pytest.raises(LimitError, match="below min_setpoint_c"):
            chamber.set(-41.0)
        with pytest.raises(LimitError, match="max_ramp_c_per_min"):
            chamber.set_ramp_rate(6.0)
        assert sim.server.requests_seen == seen
        assert sim.register_values(F4T_SETPOINT, 2) == before and world.setpoint_c == 22.0
        chamber.close()


def test_alarm_is_reported_from_the_configured_register_only(world, clock):
    alarm = ChamberAlarm(register=4321, kind="nonzero", meaning="lab alarm summary")
    with ChamberSim(world, "f4t", alarm=alarm) as sim:
        watched, blind = f4t(sim.port, clock, alarm=alarm), f4t(sim.port, clock)
        assert not watched.read().fault
        world.chamber_alarm = True
        reading = watched.read()
        assert reading.alarm and reading.problem == "alarm: register 4321 = 0x0001 (lab alarm summary)"
        seen = sim.server.requests_seen
        assert not blind.read().fault  # without the station's register the driver cannot know
        assert sim.server.requests_seen - seen == 3  # PV, SP, closed-loop SP: no alarm read
        watched.close()
        blind.close()


def test_f4_input_error_is_reported(world, clock):
    with ChamberSim(world, "f4") as sim:
        chamber = WatlowF4(transport(sim.port, clock), name="chamber", clock=clock, **LIMITS)
        chamber.connect()
        assert not chamber.read().fault
        sim.input_error = True
        reading = chamber.read()
        assert reading.input_error and not reading.alarm
        assert reading.problems == ("temperature input error (register 101 reads 1)",)
        chamber.close()


@pytest.mark.parametrize("register_map", ["f4t", "f4"])
@pytest.mark.parametrize("framing", ["tcp", "rtu"])
def test_devices_check_works_against_a_controller_that_refuses_undocumented_registers(
    world, clock, register_map, framing
):
    cls = WatlowF4T if register_map == "f4t" else WatlowF4
    with ChamberSim(world, register_map, framing=framing) as sim:
        link = transport(sim.port, clock, rtu=framing == "rtu")
        with pytest.raises(ProtocolError, match=r"exception reply 2 \(illegal data address\)"):
            link.read_holding(60000, 1)  # the simulator is strict: what no document lists does not exist
        chamber = cls(transport(sim.port, clock, rtu=framing == "rtu"), name="chamber", clock=clock, **LIMITS)
        chamber.connect()  # what `rig devices check` does: connect, safe state, describe, read
        chamber.safe_state()
        assert chamber.describe()["alarm"] is None
        reading = chamber.read()
        assert reading.setpoint_c == pytest.approx(25.0) and reading.air_c == pytest.approx(22.0)
        assert not reading.fault
        chamber.close()
        link.close()


def test_rate_above_the_rig_limit_is_a_problem(world, clock):
    world.ramp_c_per_min = 8.0  # a chamber that ramps faster than the station allows (5 degC/min)
    with ChamberSim(world, "f4") as sim:
        chamber = WatlowF4(transport(sim.port, clock), name="chamber", clock=clock, **LIMITS)
        chamber.connect()
        chamber.set(60.0)
        assert chamber.read().rate_c_per_min is None  # not known before a full window
        clock.sleep(30.0)
        assert not chamber.read().fault
        clock.sleep(30.0)
        reading = chamber.read()
        assert reading.rate_c_per_min == pytest.approx(8.0, abs=0.05)
        assert reading.problems == ("air changes at +8.00 degC/min, faster than max_ramp_c_per_min 5",)
        chamber.close()


def test_rate_within_the_limit_is_no_problem(world, clock):
    with ChamberSim(world, "f4t") as sim:  # the world ramps at 3 degC/min
        chamber = f4t(sim.port, clock)
        chamber.set(60.0)
        chamber.read()
        clock.sleep(120.0)
        reading = chamber.read()
        assert reading.rate_c_per_min == pytest.approx(3.0, abs=0.01) and not reading.fault
        chamber.close()


def test_leaving_a_reached_setpoint_is_a_problem_but_travelling_to_it_is_not(world, clock):
    with ChamberSim(world, "f4t") as sim:
        chamber = f4t(sim.port, clock, max_deviation_c=2.0)
        chamber.set(40.0)
        clock.sleep(60.0)
        assert not chamber.read().fault  # 25 degC on the way to 40: no fault
        clock.sleep(600.0)
        assert chamber.read().air_c == pytest.approx(40.0) and not chamber.read().fault
        # the air is driven away while the controller's set point still reads 40 (a failed compressor)
        world.set_chamber_setpoint(30.0)
        clock.sleep(60.0)  # 3 degC/min: 37 degC, 3 degC off
        reading = chamber.read()
        assert reading.setpoint_c == 40.0
        assert reading.problems == (
            "air 37.0 degC left its set point 40.0 degC by -3.0 degC (max_deviation_c 2)",
        )
        chamber.set(37.0)  # a new set point: on its way again
        assert not chamber.read().fault
        chamber.close()


def test_bad_alarm_option_names_the_key(clock):
    with pytest.raises(OptionError, match=r"^chamber: alarm\.register: Input should be greater than"):
        f4t(1, clock, alarm={"register": -1})
    with pytest.raises(OptionError, match=r"^chamber: alarm: Value error, kind 'bits' needs `bits`"):
        f4t(1, clock, alarm={"register": 5, "kind": "bits"})
    with pytest.raises(OptionError, match=r"^chamber: alarm\.colour: Unexpected keyword argument"):
        f4t(1, clock, alarm={"register": 5, "colour": "red"})


def test_controller_refuses_out_of_range_setpoint(world, clock):
    with ChamberSim(world, "f4t", range_c=(-70.0, 180.0)) as sim:
        link = transport(sim.port, clock)
        with pytest.raises(ProtocolError, match="exception reply 3 \\(illegal data value\\)"):
            link.write_float32(F4T_SETPOINT, 500.0, word_order="little")
        assert world.setpoint_c == 22.0
        link.close()


def test_timeout_names_device_and_operation(world, clock):
    with ChamberSim(world, "f4t") as sim:
        chamber = f4t(sim.port, clock, timeout_s=0.2)
        chamber.read()
        sim.silence(3)
        with pytest.raises(DeviceTimeout) as err:
            chamber.set(85.0)
        assert str(err.value) == "chamber: write setpoint 85.0 degC: no reply within 0.2 s (after 3 tries)"
        chamber.set(40.0)  # the link recovers once the device answers again
        assert world.setpoint_c == 40.0
        chamber.close()


def test_unplugged_chamber_is_not_found_then_recovers(world, clock):
    with ChamberSim(world, "f4t") as sim:
        chamber = f4t(sim.port, clock)
        chamber.read()
        sim.unplug()
        with pytest.raises(DeviceNotFound, match="chamber: read chamber temperature: connection refused"):
            chamber.read()
        sim.replug()
        assert chamber.read().air_c == pytest.approx(22.0)
        chamber.close()


@pytest.mark.parametrize(("decimals", "units_c"), [(0, True), (2, True), (1, False)])
def test_f4_legacy_scaling_and_units(world, clock, decimals, units_c):
    with ChamberSim(world, "f4", decimals=decimals, units_c=units_c, framing="rtu") as sim:
        chamber = WatlowF4(transport(sim.port, clock, rtu=True), name="chamber", clock=clock, **LIMITS)
        chamber.connect()
        chamber.set(-20.0)
        assert world.setpoint_c == pytest.approx(-20.0, abs=0.05)
        raw = sim.register_values(F4_SETPOINT, 1)[0]
        expected = -20.0 if units_c else -4.0  # -20 degC = -4 degF
        assert raw == (round(expected * 10**decimals) & 0xFFFF)
        reading = chamber.read()
        assert reading.setpoint_c == pytest.approx(-20.0, abs=0.05) and not reading.fault
        with pytest.raises(OptionError, match="no ramp-rate register"):
            chamber.set_ramp_rate(1.0)
        chamber.close()


def test_safe_setpoint_must_be_inside_limits(clock):
    with pytest.raises(OptionError, match="safe_setpoint_c 150"):
        WatlowF4T(transport(1, clock), name="chamber", clock=clock, **{**LIMITS, "safe_setpoint_c": 150.0})


def test_describe_names_model_and_link(world, clock):
    with ChamberSim(world, "f4t") as sim:
        info = f4t(sim.port, clock).describe()
    assert info["model"].startswith("Watlow F4T") and info["word_order"] == "little"
    assert info["link"] == f"tcp 127.0.0.1:{sim.port}" and info["max_setpoint_c"] == 125.0
