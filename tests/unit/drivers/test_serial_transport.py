"""SerialTransport against a scripted pyserial-like port (and pyserial's own loop:// once)."""

from __future__ import annotations

import logging
import termios
import threading

import pytest
import serial

from drivers.clock import SimClock
from drivers.errors import DeviceNotFound, DeviceTimeout, OptionError, ProtocolError
from drivers.transports.serial import SerialLine, SerialTransport, line_time_s


class ScriptedPort:
    """The pyserial methods the transport uses. Each write must equal the next expected bytes of the
    transcript, byte for byte; its scripted reply then becomes readable. An empty buffer reads as b""
    at once (a timeout without the wait)."""

    def __init__(self, transcript=(), *, pending: bytes = b"", fail_with: BaseException | None = None):
        self.transcript = list(transcript)
        self.writes: list[bytes] = []
        self.rx = bytearray(pending)
        self.timeout = None
        self.closed = False
        self.fail_with = fail_with  # raised by every call once set: a pulled cable
        self.baudrate = 9600
        self.write_bauds: list[int] = []  # the port's baud rate at each write

    def _check(self):
        if self.fail_with is not None:
            raise self.fail_with

    @property
    def in_waiting(self) -> int:
        self._check()
        return len(self.rx)

    def write(self, data: bytes) -> int:
        self._check()
        self.writes.append(data)
        self.write_bauds.append(self.baudrate)
        assert self.transcript, f"unexpected write {data!r}: transcript finished"
        expected, reply = self.transcript.pop(0)
        assert data == expected, f"driver sent {data!r}, transcript expects {expected!r}"
        self.rx += reply
        return len(data)

    def read(self, size: int = 1) -> bytes:
        self._check()
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    def flush(self) -> None:
        self._check()

    def reset_input_buffer(self) -> None:
        self._check()
        self.rx.clear()

    def close(self) -> None:
        self.closed = True


def scripted_transport(*ports: ScriptedPort, name: str = "dut2", **kwargs) -> SerialTransport:
    """A transport whose successive opens return `ports` in order (then fail as a missing port)."""
    queue = list(ports)

    def opener(port, *, baudrate, **_):
        if not queue:
            raise serial.SerialException(f"could not open port {port}: No such file or directory")
        opened = queue.pop(0)
        opened.baudrate = baudrate
        return opened

    kwargs.setdefault("timeout_s", 0.01)
    return SerialTransport("/dev/ttyFAKE0", name=name, clock=SimClock(), opener=opener, **kwargs)


def test_read_line_splits_lines_and_keeps_the_rest():
    t = scripted_transport(ScriptedPort(pending=b"OK\r 12,345\rpart"))
    assert t.read_line() == b"OK\r"
    assert t.read_line() == b" 12,345\r"
    with pytest.raises(DeviceTimeout, match=r"dut2: wait reply: incomplete line b'part' within 0.01 s"):
        t.read_line(operation="wait reply")


def test_query_retries_a_malformed_reply_then_succeeds():
    port = ScriptedPort([(b"*00P\r", b"garbage\r"), (b"*00P\r", b"good\r")])
    t = scripted_transport(port)

    def parse(line: bytes) -> bytes:
        if line != b"good\r":
            raise ProtocolError("dut2", "poll sample", f"malformed {line!r}")
        return line

    assert t.query(b"*00P\r", operation="poll sample", parse=parse) == b"good\r"
    assert port.writes == [b"*00P\r", b"*00P\r"]


def test_query_without_reply_names_device_operation_and_tries():
    port = ScriptedPort([(b"*00P\r", b"")] * 3)
    t = scripted_transport(port)
    with pytest.raises(DeviceTimeout) as err:
        t.query(b"*00P\r", operation="poll sample", parse=bytes)
    assert str(err.value) == "dut2: poll sample: no reply within 0.01 s (after 3 tries)"
    assert len(port.writes) == 3


def test_stale_input_is_flushed_before_a_command():
    port = ScriptedPort([(b"*00#\r", b"SN1\r")], pending=b"old line\r")
    assert scripted_transport(port).query(b"*00#\r", operation="read serial", parse=bytes) == b"SN1\r"


@pytest.mark.parametrize(
    "error", [serial.SerialException("read failed: [Errno 5] Input/output error"), termios.error(5, "EIO")]
)
def test_lost_port_is_closed_and_reopened_on_the_next_try(error):
    dead = ScriptedPort([(b"*00P\r", b"")])
    dead.fail_with = error
    alive = ScriptedPort([(b"*00P\r", b"reply\r")])
    t = scripted_transport(dead, alive)
    assert t.query(b"*00P\r", operation="poll sample", parse=bytes) == b"reply\r"
    assert dead.closed and t.open_count == 2


def test_port_that_stays_missing_ends_in_device_not_found():
    dead = ScriptedPort(fail_with=OSError(5, "Input/output error"))
    t = scripted_transport(dead)
    with pytest.raises(DeviceNotFound) as err:
        t.query(b"*00P\r", operation="poll sample", parse=bytes)
    message = str(err.value)
    assert message.startswith("dut2: poll sample: cannot open /dev/ttyFAKE0")
    assert message.endswith("(after 3 tries)")
    assert not t.is_open


def test_raw_bytes_are_logged_at_debug(caplog):
    t = scripted_transport(ScriptedPort([(b"*00F\r", b"fw 1.4\r")]))
    with caplog.at_level(logging.DEBUG, logger="magrig.transport.serial"):
        t.query(b"*00F\r", operation="read firmware", parse=bytes)
    assert "dut2 > b'*00F\\r'" in caplog.text
    assert "dut2 < b'fw 1.4\\r'" in caplog.text


def test_discard_input_drops_a_stream_tail():
    t = scripted_transport(ScriptedPort(pending=b"  1,000  \r  2,0"))
    assert t.discard_input(0.01) == 15
    with pytest.raises(DeviceTimeout, match="no reply"):
        t.read_line()


def test_pyserial_loop_url_through_the_default_opener():
    t = SerialTransport("loop://", name="loopback", clock=SimClock(), baudrate=115200, timeout_s=0.05)
    t.write(b"*00P\r")
    assert t.read_line() == b"*00P\r"  # loop:// echoes
    t.close()
    assert not t.is_open


def test_unknown_port_is_device_not_found():
    t = SerialTransport("nosuchscheme://x", name="dut9", clock=SimClock())
    with pytest.raises(DeviceNotFound, match="dut9: open port: cannot open nosuchscheme://x"):
        t.open()


def test_line_time_of_a_sample_line():
    assert line_time_s(28, 115200) == pytest.approx(2.4306e-3, rel=1e-4)
    assert line_time_s(28, 9600) == pytest.approx(29.17e-3, rel=1e-3)


# --- a shared RS-485 line -------------------------------------------------------------------------
def shared_line(port: ScriptedPort) -> SerialLine:
    def opener(path, *, baudrate, **_):
        port.baudrate = baudrate
        return port

    return SerialLine("/dev/ttyRS485", baudrate=9600, opener=opener)


def test_devices_on_one_line_share_one_port_and_keep_their_own_names():
    port = ScriptedPort([(b"*01P\r", b""), (b"*02#\r", b"SN2\r")])
    line = shared_line(port)
    a = line.transport(1, name="dut1", clock=SimClock(), timeout_s=0.01, tries=1)
    b = line.transport(2, name="dut2", clock=SimClock(), timeout_s=0.01, tries=1)
    with pytest.raises(DeviceTimeout, match=r"^dut1: poll sample: no reply"):
        a.query(b"*01P\r", operation="poll sample", parse=bytes)
    assert b.query(b"*02#\r", operation="read serial", parse=bytes) == b"SN2\r"
    assert a.open_count == b.open_count == 1 and a.shared and b.shared
    a.close()
    assert not port.closed  # dut2 still has it open
    b.close()
    assert port.closed and not a.is_open


def test_a_device_id_is_taken_once_per_line():
    line = shared_line(ScriptedPort())
    line.transport(3, name="dut1")
    with pytest.raises(OptionError, match="dut2: device id 3 on /dev/ttyRS485 is already dut1's"):
        line.transport(3, name="dut2")


def test_a_session_keeps_the_line_from_other_threads():
    line = shared_line(ScriptedPort())
    a = line.transport(1, name="dut1")
    got: list[bool] = []

    def other_device() -> None:
        free = line.lock.acquire(blocking=False)
        if free:
            line.lock.release()
        got.append(free)

    with a.session():
        worker = threading.Thread(target=other_device)
        worker.start()
        worker.join()
    assert got == [False]
    worker = threading.Thread(target=other_device)
    worker.start()
    worker.join()
    assert got == [False, True]


def test_baud_rate_switch_applies_to_the_open_port_and_to_later_opens():
    port = ScriptedPort([(b"*00A\r", b"ASCII_ON\r")])
    t = scripted_transport(port, ScriptedPort())
    t.open()
    t.set_baudrate(19200)
    t.query(b"*00A\r", operation="probe", parse=bytes)
    assert port.write_bauds == [19200] and t.baudrate == 19200
    t.close()
    t.open()
    assert t.line.ser.baudrate == 19200
