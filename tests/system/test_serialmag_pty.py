"""The serial magnetometer driver against its fake firmware on a real pty pair."""

from __future__ import annotations

import re
import struct
import threading

import numpy as np
import pytest
import serial

from drivers.clock import SimClock
from drivers.errors import ProtocolError
from drivers.serialmag import SerialMagnetometer
from drivers.sim.devices.serialmag import SerialMagLine, SerialMagSim
from drivers.sim.world import DutTruth, World
from drivers.transports.serial import SerialLine
from rig.core.errors import DeviceNotFound, DeviceTimeout

pytestmark = pytest.mark.system

NOISE_NT = 20.0
BRIDGE_OFFSET_NT = np.array([3000.0, -2000.0, 1500.0])
# (out_set - out_reset)/2 averages two noisy outputs; plus half a count (3.3 nT) of quantisation.
TOLERANCE_NT = 5 * NOISE_NT / np.sqrt(2) + 4.0


@pytest.fixture
def world():
    clock = SimClock()
    w = World(clock, seed=3)
    truth = DutTruth(
        S=np.diag([1.02, 0.98, 1.01]), K=np.zeros((3, 3)), b_nt=np.array([120.0, -80.0, 40.0]),
        kb_nt_per_c=np.zeros(3), bridge_offset_nt=BRIDGE_OFFSET_NT, noise_nt=NOISE_NT,
    )
    w.add_dut("dut1", truth)
    w.set_coil_currents([0.5, -0.2, 1.0])  # about (25, -10, 50) uT
    return w


@pytest.fixture
def sim(world):
    with SerialMagSim(world, "dut1", reply_latency_s=0.001) as s:
        yield s


def make_mag(sim, world, **kwargs) -> SerialMagnetometer:
    return SerialMagnetometer.from_port(
        sim.path, name="dut1", clock=world.clock, baudrate=9600, timeout_s=0.2, **kwargs
    )


@pytest.fixture
def mag(sim, world):
    m = make_mag(sim, world)
    m.connect()
    yield m
    m.safe_state()
    m.close()


def truth_nt(world):
    """Noise-free offset-free bridge reading and bridge offset, from the world's own model."""
    out_set = world.dut_raw_nt("dut1", 1, noisy=False)
    out_reset = world.dut_raw_nt("dut1", -1, noisy=False)
    return (out_set - out_reset) / 2, (out_set + out_reset) / 2


def assert_close_to_truth(sample, world):
    field_nt, offset_nt = truth_nt(world)
    np.testing.assert_allclose(sample.field_nt, field_nt, atol=TOLERANCE_NT)
    if sample.offset_nt is not None:
        np.testing.assert_allclose(sample.offset_nt, offset_nt, atol=TOLERANCE_NT)


def test_identity_and_configuration(mag, sim):
    info = mag.describe()
    assert info["serial_number"] == "SM2300-0001" and info["firmware"] == "SM2300 fw 1.4"
    assert sim.auto_set_reset is False and sim.rate_hz == 20
    assert mag.query_setup() == "ID=00 RATE=20 S/R=OFF FORMAT=ASCII BAUD=9600"


def test_set_reset_read_recovers_world_truth_and_the_bridge_offset(mag, world):
    sample = mag.read()
    assert_close_to_truth(sample, world)
    np.testing.assert_allclose(sample.offset_nt, BRIDGE_OFFSET_NT, atol=TOLERANCE_NT)
    # Without the pulse pair, a plain poll is off by the bridge offset: the cancellation matters.
    plain_nt = np.array(mag.poll_counts()) * 100_000 / 15_000
    assert np.all(np.abs(plain_nt - truth_nt(world)[0] - BRIDGE_OFFSET_NT) < TOLERANCE_NT * np.sqrt(2))


def test_auto_set_reset_mode_polls_the_cancelled_field(sim, world):
    m = make_mag(sim, world, set_reset="auto")
    m.connect()
    try:
        sample = m.read()
        assert sim.auto_set_reset is True and sample.offset_nt is None
        assert_close_to_truth(sample, world)
    finally:
        m.close()


def test_stream_n_samples_at_60_hz_at_19200_baud_then_the_stream_is_stopped(mag, sim, world):
    mag.set_rate(60)
    assert sim.baud == 19200 and mag.transport.baudrate == 19200  # switched with *99!BR=F first
    samples = mag.read_stream(20)
    assert len(samples) == 20 and sim.rate_hz == 60
    for s in samples:
        assert_close_to_truth(s, world)
    assert not sim.streaming
    assert_close_to_truth(mag.read(), world)  # no stream tail left in the way


@pytest.mark.parametrize("mode", ["flip", "noise", "truncate"])
def test_garbled_sample_lines_are_recovered(mag, sim, world, mode):
    sim.garble_next(1, mode)
    assert_close_to_truth(mag.read(), world)
    assert sim.garbles_pending == 0


def test_garbled_lines_in_a_stream_are_skipped(mag, sim, world):
    mag.set_rate(60)
    sim.garble_next(2, "flip")
    samples = mag.read_stream(5)
    assert len(samples) == 5 and sim.garbles_pending == 0
    for s in samples:
        assert_close_to_truth(s, world)


def test_wrong_entry_reply_is_retried(mag, sim, world):
    sim.wrong_entry_next(1)
    assert_close_to_truth(mag.read(), world)


def test_on_a_simulated_clock_world_time_replies_at_once_and_leaves_the_clock_alone(world):
    """A latency far beyond the driver's timeout: slept in real time it fails the read; as world time on a
    simulated clock the reply leaves at once and the world's clock does not move."""
    for world_time in (False, True):
        with SerialMagSim(world, "dut1", reply_latency_s=0.5, world_time=world_time) as slow:
            m = make_mag(slow, world, tries=1)
            try:
                t0 = world.clock.now()
                if world_time:
                    m.connect()
                    assert_close_to_truth(m.read(), world)
                    assert world.clock.now() == t0
                else:
                    with pytest.raises(DeviceTimeout):
                        m.connect()
            finally:
                m.close()


def test_silent_device_ends_in_timeout_naming_device_and_operation(mag, sim):
    sim.drop_next(3)
    with pytest.raises(DeviceTimeout) as err:
        mag.poll_counts()
    assert str(err.value) == "dut1: poll sample: no reply within 0.2 s (after 3 tries)"
    assert sim.received[-3:] == [b"*00P"] * 3


def test_unplug_and_replug_between_reads_reconnects_and_reconfigures(mag, sim, world):
    mag.set_rate(50)
    assert sim.baud == 19200
    sim.unplug()
    assert sim.replug() == mag.transport.port  # the same stable path
    assert sim.auto_set_reset is True and sim.rate_hz == 20 and sim.baud == 9600  # power-cycled firmware
    assert_close_to_truth(mag.read(), world)  # with auto S/R left on, H_set - H_reset would be 0
    assert sim.auto_set_reset is False and sim.rate_hz == 50 and mag.transport.open_count == 2
    assert sim.baud == mag.transport.baudrate == 19200  # found again at 9600, then switched


def test_port_missing_then_back(mag, sim, world):
    sim.unplug()
    with pytest.raises(DeviceNotFound, match=r"^dut1: reset pulse: cannot open .*\(after 3 tries\)$"):
        mag.read()
    mag.safe_state()  # must not raise on a dead port
    sim.replug()
    assert_close_to_truth(mag.read(), world)


def test_safe_state_stops_a_running_stream(mag, sim, world):
    mag.transport.write(b"*00C\r")
    mag.transport.read_line(timeout_s=0.2)  # the stream is running
    mag.safe_state()
    assert not sim.streaming
    assert_close_to_truth(mag.read(), world)


def test_stop_leaves_no_thread_and_no_port(world):
    before = set(threading.enumerate())
    with SerialMagSim(world, "dut1") as s:
        m = make_mag(s, world, set_reset="off", rate_hz=30)
        m.connect()
        m.transport.write(b"*00C\r")  # leave a stream running: stop() must end it
        m.transport.read_line(timeout_s=0.2)
        assert s.streaming
        m.close()
    assert set(threading.enumerate()) <= before
    with pytest.raises(DeviceNotFound, match="No such file"):
        make_mag(s, world).connect()


# --- the simulator answers as the datasheet says (hardware-notes 2.3) ------------------------------
def raw_exchange(port: serial.Serial, command: bytes) -> bytes:
    """Send one command; everything that comes back within the port timeout (b"" for silence)."""
    port.reset_input_buffer()
    port.write(command)
    return port.read_until(b"\r")


def test_simulator_replies_per_the_datasheet_table(world):
    with SerialMagSim(world, "dut1", device_id=3, reply_latency_s=0.0) as sim:
        port = serial.Serial(sim.path, 9600, timeout=0.2)
        try:
            transcript = [
                (b"*03TN\r", b"Re-enter\r"),  # a setting without *ddWE first
                (b"*03WE\r", b"OK\r"),
                (b"*03TN\r", b"S/R_ON\r"),
                (b"*03WE\r", b"OK\r"),
                (b"*03TF\r", b"S/R_OFF\r"),
                (b"*03WE\r", b"OK\r"),
                (b"*03R=25\r", b"OK\r"),
                (b"*03R=25\r", b"Re-enter\r"),  # WE enables one setting only
                (b"*03]S\r", b"SET\r"),
                (b"*03]R\r", b"RST\r"),
                (b"*03WE\r", b"OK\r"),
                (b"*03ZN\r", b"ZERO_ON\r"),
                (b"*03WE\r", b"OK\r"),
                (b"*03ZF\r", b"ZERO_OFF\r"),
                (b"*03WE\r", b"OK\r"),
                (b"*03VN\r", b"AVG_ON\r"),
                (b"*03WE\r", b"OK\r"),
                (b"*03VF\r", b"AVG_OFF\r"),
                (b"*03A\r", b"ASCII_ON\r"),
                (b"*03XYZ\r", b"Re-enter\r"),  # not understood
                (b"*04P\r", b""),  # another device's id: silence
                (b"*99WE\r", b""),  # every device: acted on, no reply
            ]
            assert [raw_exchange(port, cmd) for cmd, _ in transcript] == [reply for _, reply in transcript]
            assert sim.rate_hz == 25 and not sim.auto_set_reset and sim.polarity == -1
            line = raw_exchange(port, b"*03P\r")
            field = rb"[ -](?: {5}\d| {4}\d\d| {3}\d{3}| \d,\d{3}|\d\d,\d{3})  "  # thousands comma
            assert re.fullmatch(field * 3 + rb"\r", line), line
            assert raw_exchange(port, b"*03B\r") == b"BINARY_ON\r"
            port.write(b"*03P\r")
            frame = port.read(7)  # 7 bytes: X, Y, Z int16 big-endian, CR (layout not verified)
            assert len(frame) == 7 and frame[6:] == b"\r"
            assert all(abs(c) < 30_000 for c in struct.unpack(">hhh", frame[:6]))
        finally:
            port.close()


def test_simulator_ignores_commands_at_the_wrong_baud_rate(world):
    with SerialMagSim(world, "dut1", reply_latency_s=0.0) as sim:
        port = serial.Serial(sim.path, 19200, timeout=0.2)
        try:
            assert raw_exchange(port, b"*00A\r") == b""  # the device listens at 9600
            port.baudrate = 9600
            assert raw_exchange(port, b"*99WE\r") == b""
            assert raw_exchange(port, b"*99!BR=F\r") == b""
            assert sim.baud == 19200 and raw_exchange(port, b"*00A\r") == b""
            port.baudrate = 19200
            assert raw_exchange(port, b"*00A\r") == b"ASCII_ON\r"
        finally:
            port.close()


# --- several HMR2300s on one RS-485 line ---------------------------------------------------------
@pytest.fixture
def two_on_a_line(world):
    world.add_dut("dut2", DutTruth.random(np.random.default_rng(5), noise_nt=NOISE_NT))
    sims = [SerialMagSim(world, "dut1", device_id=1, reply_latency_s=0.001),
            SerialMagSim(world, "dut2", device_id=2, reply_latency_s=0.001)]
    with SerialMagLine(sims) as line:
        yield line, sims


def test_two_devices_share_one_port_and_each_answers_its_own_id(two_on_a_line, world):
    sim_line, (sim1, sim2) = two_on_a_line
    line = SerialLine(sim_line.path, baudrate=9600)
    mag1 = SerialMagnetometer.on_line(line, name="dut1", device_id=1, clock=world.clock, timeout_s=0.2)
    mag2 = SerialMagnetometer.on_line(line, name="dut2", device_id=2, clock=world.clock, timeout_s=0.2)
    mag1.connect()
    mag2.connect()
    assert mag1.transport.open_count == mag2.transport.open_count == 1  # one port for both
    assert_close_to_truth(mag1.read(), world)
    field2 = world.dut_raw_nt("dut2", 1, noisy=False) - world.dut_raw_nt("dut2", -1, noisy=False)
    np.testing.assert_allclose(mag2.read().field_nt, field2 / 2, atol=TOLERANCE_NT)
    assert b"*02P" in sim1.received and b"*01P" in sim2.received  # one wire: each hears the other's polls
    mag2.set_rate(50)  # both devices go to 19200 together: *99!BR=F
    assert sim1.baud == sim2.baud == 19200 and line.baudrate == 19200
    assert_close_to_truth(mag1.read(), world)  # dut1 still talks, at the new rate
    assert sim1.rate_hz == 20 and sim2.rate_hz == 50
    mag1.close()
    mag2.close()


def test_threads_reading_two_devices_on_one_line_do_not_mix_replies(two_on_a_line, world):
    sim_line, _ = two_on_a_line
    line = SerialLine(sim_line.path, baudrate=9600)
    mags = [SerialMagnetometer.on_line(line, name=f"dut{i}", device_id=i, clock=world.clock, timeout_s=0.2)
            for i in (1, 2)]
    for m in mags:
        m.connect()
    errors: list[BaseException] = []

    def reader(m: SerialMagnetometer) -> None:
        try:
            for _ in range(5):
                m.read()
        except BaseException as exc:  # reported to the test thread
            errors.append(exc)

    threads = [threading.Thread(target=reader, args=(m,)) for m in mags]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    for m in mags:
        m.close()


def test_a_device_that_refuses_a_setting_raises_a_protocol_error(mag, sim):
    sim.wrong_entry_next(6)  # WE and R= answered Re-enter on every try
    with pytest.raises(ProtocolError, match=r"^dut1: set rate: device answered Re-enter \(command refused\)"):
        mag.set_rate(25)
    assert sim.rate_hz == 20
