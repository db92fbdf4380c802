"""drivers/base.py each_by_line and make_all_safe: the devices of each serial line go in a thread of that
line, at the same time as the other lines and the rest, each group in its order; failures are kept per
device and never stop another line."""

from __future__ import annotations

import threading

import pytest

from drivers.base import each_by_line, make_all_safe
from drivers.errors import DeviceError


class _Line:
    """Stands for a drivers/transports/serial.py SerialLine: only its identity matters here."""


class _Transport:
    def __init__(self, line):
        self.line = line


class _Dev:
    def __init__(self, name, line=None, act=None):
        self.name = name
        if line is not None:
            self.transport = _Transport(line)
        self.act = act or (lambda: None)

    def safe_state(self):
        self.act()


def test_the_lines_go_at_the_same_time_and_each_keeps_its_order():
    a, b = _Line(), _Line()
    meet = threading.Barrier(3, timeout=10)  # passes only when both lines and the rest are in it at once
    seen: list[tuple[str, str]] = []

    def act(dev):
        seen.append((dev.name, threading.current_thread().name))
        if dev.name.endswith("1"):
            meet.wait()

    devices = [_Dev("coil1"), _Dev("a1", a), _Dev("b1", b), _Dev("a2", a), _Dev("coil2"), _Dev("b2", b)]
    assert each_by_line(devices, act) == {}
    names = [name for name, _ in seen]
    for first, then in (("a1", "a2"), ("b1", "b2"), ("coil1", "coil2")):
        assert names.index(first) < names.index(then)
    here = threading.current_thread().name
    assert {thread for name, thread in seen if name.startswith("coil")} == {here}
    assert here not in {thread for name, thread in seen if not name.startswith("coil")}


def test_a_failure_stops_its_own_line_only_when_asked():
    a, b = _Line(), _Line()
    done: list[str] = []

    def act(dev):
        if dev.name == "a1":
            raise DeviceError(dev.name, "connect", "no reply")
        done.append(dev.name)

    devices = [_Dev("a1", a), _Dev("a2", a), _Dev("b1", b), _Dev("x")]
    errors = each_by_line(devices, act, stop_at_error=True)
    assert list(errors) == [0] and "no reply" in str(errors[0])
    assert sorted(done) == ["b1", "x"]  # a2 waits behind its line's failure; the other line goes on
    done.clear()
    assert list(each_by_line(devices, act)) == [0] and sorted(done) == ["a2", "b1", "x"]


def test_make_all_safe_names_every_failure_in_the_devices_order(caplog):
    line = _Line()

    def fails():
        raise DeviceError("dut", "safe state", "cable pulled")

    devices = [_Dev("s1", line, fails), _Dev("coils"), _Dev("s2", line, fails), _Dev("chamber", None, fails)]
    assert make_all_safe(devices) == ["s1", "s2", "chamber"]
    assert sum("safe_state failed" in r.getMessage() for r in caplog.records) == 3


def test_ctrl_c_here_waits_for_the_lines_then_goes_on_up():
    line = _Line()
    finished = threading.Event()

    def act(dev):
        if dev.name == "here":
            raise KeyboardInterrupt
        threading.Event().wait(0.05)
        finished.set()

    with pytest.raises(KeyboardInterrupt):
        each_by_line([_Dev("s1", line), _Dev("here")], act)
    assert finished.is_set()  # no line thread is left running behind the interrupt
