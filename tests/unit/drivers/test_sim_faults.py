"""The fault schedule (drivers/sim/devices/faults.py) and the simulators' hooks it drives."""

from __future__ import annotations

import pytest

from drivers.chamber import ChamberAlarm
from drivers.clock import SimClock
from drivers.errors import DeviceNotFound, DeviceTimeout, ProtocolError
from drivers.sim.devices.chamber import ChamberSim
from drivers.sim.devices.faults import DeviceFaults, Window
from drivers.sim.devices.tmp117 import TMP117Sim
from drivers.sim.transports.i2c_bus import FakeSMBus
from drivers.sim.world import World
from drivers.tmp117 import TMP117
from drivers.transports.modbus import ModbusTransport
from drivers.watlow import WatlowF4T
from rig.devices.simulated.world import mount_truth

LIMITS = dict(min_setpoint_c=-40.0, max_setpoint_c=125.0, max_ramp_c_per_min=5.0, safe_setpoint_c=25.0)


@pytest.fixture
def clock():
    return SimClock()


def draws(faults: DeviceFaults, n: int) -> list[str | None]:
    return [faults.draw() for _ in range(n)]


def test_the_same_seed_and_device_draw_the_same_faults(clock):
    rates = {"no_reply": 10, "garbled": 20}
    a, b = (DeviceFaults("coils", clock, one_in=rates, seed=7) for _ in range(2))
    other = DeviceFaults("chamber", clock, one_in=rates, seed=7)
    assert draws(a, 500) == draws(b, 500) != draws(other, 500)


def test_one_in_n_is_about_that_often(clock):
    faults = DeviceFaults("coils", clock, one_in={"exception": 50}, seed=1)
    n = sum(k == "exception" for k in draws(faults, 20_000))
    assert 300 < n < 500  # 400 expected; binomial sd 20
    assert faults.fired["exception"] == n and len(faults.history) == n


def test_windows_follow_the_clock(clock):
    faults = DeviceFaults("x", clock, unplug=Window(100, 50), alarm=Window(10), stuck=Window(0, 20))
    assert faults.draw() is None and not faults.alarm() and faults.stuck()
    clock.sleep(100)
    assert faults.draw() == "unplug" and faults.alarm() and not faults.stuck()
    clock.sleep(50)
    assert faults.draw() is None and faults.alarm()  # an alarm without for_s stays


def test_a_stuck_window_freezes_the_last_value_shown(clock):
    faults = DeviceFaults("tmp0", clock, stuck=Window(10, 10))
    assert faults.shown_temperature(20.0) == 20.0
    clock.sleep(10)
    assert faults.shown_temperature(21.0) == 20.0
    clock.sleep(10)
    assert faults.shown_temperature(22.0) == 22.0


def test_bad_rates_are_refused(clock):
    with pytest.raises(ValueError, match="one in N >= 2"):
        DeviceFaults("x", clock, one_in={"no_reply": 1})
    with pytest.raises(ValueError, match="kinds are"):
        DeviceFaults("x", clock, one_in={"fire": 10})


def test_i2c_nack_faults_reach_the_driver_as_retries_then_not_found(clock):
    world = World(clock, air_c=22.0)
    world.add_dut("dut", mount_truth())
    bus = FakeSMBus()
    bus.attach(0x48, TMP117Sim(world, "dut"))
    faults = DeviceFaults("tmp0", clock, unplug=Window(100))
    bus.set_faults(0x48, faults)
    sensor = TMP117(bus, 0x48, name="tmp0", clock=clock)
    sensor.connect()
    assert sensor.read().temp_c == pytest.approx(22.0, abs=0.01)
    clock.sleep(100)
    with pytest.raises(DeviceNotFound, match="tmp0: .*no ACK at 0x48"):
        sensor.read()
    assert faults.fired["unplug"] >= 3  # every try was NACKed


def test_modbus_exception_and_lost_reply_are_retried_and_an_alarm_window_shows(clock):
    world = World(clock, air_c=22.0)
    alarm = ChamberAlarm(register=60000, kind="nonzero", meaning="alarm summary")
    sim = ChamberSim(world, "f4t", alarm=alarm)
    sim.faults = DeviceFaults("chamber", clock, one_in={"exception": 3, "no_reply": 3}, seed=3,
                              alarm=Window(60, 60))
    with sim:
        link = ModbusTransport(name="chamber", host="127.0.0.1", port=sim.port, timeout_s=0.2, clock=clock,
                               tries=8)
        chamber = WatlowF4T(link, name="chamber", clock=clock, alarm=alarm, **LIMITS)
        for _ in range(5):
            assert not chamber.read().fault
        clock.sleep(60)
        assert chamber.read().alarm
        clock.sleep(60)
        assert not chamber.read().fault
        chamber.close()
    assert sim.faults.fired["exception"] > 0 and sim.faults.fired["no_reply"] > 0


def test_modbus_garbled_and_unplugged_replies_fail_as_the_transport_says(clock):
    world = World(clock, air_c=22.0)
    sim = ChamberSim(world, "f4t")
    sim.faults = DeviceFaults("chamber", clock, one_in={"garbled": 2}, seed=5, unplug=Window(10))
    with sim:
        link = ModbusTransport(name="chamber", host="127.0.0.1", port=sim.port, timeout_s=0.2, clock=clock,
                               tries=1)
        chamber = WatlowF4T(link, name="chamber", clock=clock, **LIMITS)
        outcomes = []
        for _ in range(6):
            try:
                chamber.read()
                outcomes.append("ok")
            except (DeviceTimeout, ProtocolError):
                outcomes.append("garbled")
        assert "garbled" in outcomes and "ok" in outcomes
        assert sim.faults.fired["garbled"] > 0
        clock.sleep(10)
        setpoint = world.setpoint_c
        with pytest.raises(DeviceTimeout):
            chamber.set(30.0)
        assert world.setpoint_c == setpoint  # an unplugged device takes nothing in
        chamber.close()
