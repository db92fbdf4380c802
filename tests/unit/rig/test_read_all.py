"""rig/devices/interleave.py: a blocking device (a serial magnetometer) is read beside the interleaved ones
on a real clock, where both wait on their wires (in a worker thread), and after them on a simulated clock,
where nothing does (in the calling thread: threads would only take turns at the interpreter); either way
every reading comes back in the devices' order."""

from __future__ import annotations

import threading

import pytest

from drivers.clock import RealClock, SimClock
from rig.devices.interleave import read_all


class Blocking:
    def __init__(self):
        self.started = threading.Event()
        self.thread = None

    def read(self):
        self.thread = threading.current_thread()
        self.started.set()
        return "serial"


class Stepped:
    """At its first transfer, gives the blocking reading up to WAIT_S of real time to begin, and notes
    whether it did."""

    def __init__(self, other: Blocking):
        self.other, self.saw = other, None

    def read_steps(self):
        self.saw = self.other.started.wait(WAIT_S)
        yield 0.01
        return "i2c"


WAIT_S = 0.5  # ample for a worker thread to start, on any machine


@pytest.mark.parametrize("clock, overlapped", [(RealClock(), True), (SimClock(0.0), False)])
def test_blocking_devices_overlap_the_interleave_on_a_real_clock_only(clock, overlapped):
    serial = Blocking()
    stepped = Stepped(serial)
    got = read_all({"mmc": stepped, "ser": serial}, clock)
    assert list(got.items()) == [("mmc", "i2c"), ("ser", "serial")]
    assert stepped.saw is overlapped and serial.started.is_set()
    assert (serial.thread is threading.current_thread()) is not overlapped
