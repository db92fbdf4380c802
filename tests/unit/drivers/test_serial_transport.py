"""SerialTransport against a scripted pyserial-like port (and pyserial's own loop:// once)."""

from __future__ import annotations

import logging
import termios

import pytest
import serial

from drivers.clock import SimClock
from drivers.errors import DeviceNotFound, DeviceTimeout, ProtocolError
from drivers.transports.serial import SerialTransport, line_time_s


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

    def reset_input_buffer(self) -> None:
        self._check()
        self.rx.clear()

    def close(self) -> None:
        self.closed = True


def scripted_transport(*ports: ScriptedPort, name: str = "dut2", **kwargs) -> SerialTransport:
    """A transport whose successive opens return `ports` in order (then fail as a missing port)."""
    queue = list(ports)

    def opener(port, **_):
        if not queue:
            raise serial.SerialException(f"could not open port {port}: No such file or directory")
        return queue.pop(0)

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
