"""The serial magnetometer driver against its fake firmware on a real pty pair."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers.clock import SimClock
from drivers.serialmag import SerialMagnetometer
from drivers.sim.serialmag import SerialMagSim
from drivers.sim.world import DutTruth, World
from rig.errors import DeviceNotFound, DeviceTimeout

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
        sim.path, name="dut1", clock=world.clock, baudrate=115200, timeout_s=0.2, **kwargs
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
    assert mag.query_setup() == "ID=00 RATE=20 S/R=OFF FORMAT=ASCII"


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


def test_stream_n_samples_at_154_hz_then_the_stream_is_stopped(mag, sim, world):
    mag.set_rate(154)
    samples = mag.read_stream(20)
    assert len(samples) == 20 and sim.rate_hz == 154
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
    mag.set_rate(154)
    sim.garble_next(2, "flip")
    samples = mag.read_stream(5)
    assert len(samples) == 5 and sim.garbles_pending == 0
    for s in samples:
        assert_close_to_truth(s, world)


def test_wrong_entry_reply_is_retried(mag, sim, world):
    sim.wrong_entry_next(1)
    assert_close_to_truth(mag.read(), world)


def test_silent_device_ends_in_timeout_naming_device_and_operation(mag, sim):
    sim.drop_next(3)
    with pytest.raises(DeviceTimeout) as err:
        mag.poll_counts()
    assert str(err.value) == "dut1: poll sample: no reply within 0.2 s (after 3 tries)"
    assert sim.received[-3:] == [b"*00P"] * 3


def test_unplug_and_replug_between_reads_reconnects_and_reconfigures(mag, sim, world):
    mag.set_rate(50)
    sim.unplug()
    assert sim.replug() == mag.transport.port  # the same stable path
    assert sim.auto_set_reset is True and sim.rate_hz == 20  # power-cycled firmware
    assert_close_to_truth(mag.read(), world)  # with auto S/R left on, H_set - H_reset would be 0
    assert sim.auto_set_reset is False and sim.rate_hz == 50 and mag.transport.open_count == 2


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
        m = make_mag(s, world, set_reset="off", rate_hz=154)
        m.connect()
        m.transport.write(b"*00C\r")  # leave a stream running: stop() must end it
        m.transport.read_line(timeout_s=0.2)
        assert s.streaming
        m.close()
    assert set(threading.enumerate()) <= before
    with pytest.raises(DeviceNotFound, match="No such file"):
        make_mag(s, world).connect()
