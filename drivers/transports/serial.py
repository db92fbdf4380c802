"""Serial transport: line-oriented I/O with timeouts, bounded retries, reconnect and a raw-byte log.

Constructors (what the station YAML maps onto)::

    SerialTransport(port, *, name, clock=None, baudrate=9600, timeout_s=0.5, tries=3,
                    backoff_s=0.02, opener=None)                      # a port of its own
    line = SerialLine(port, *, baudrate=9600, opener=None)             # one RS-485 line, several devices
    line.transport(device_id, *, name, clock=None, timeout_s=0.5, tries=3, backoff_s=0.02)

- port: a device path ("/dev/ttyUSB0", a pty slave or a stable symlink to one) or a pyserial URL
  ("loop://", "socket://host:port", "rfc2217://..."), opened with `serial.serial_for_url`.
- name: the station's name for the device; every error names it ("dut2: poll sample: ...").
- clock: waits between retries go through it (I/O timeouts are wall time: the port is real).
- baudrate: 8N1 line rate; timeout_s: default read timeout of every call; tries: attempts per `query`.
- opener: `opener(port, baudrate=, timeout_s=)` returning an object with the pyserial methods used
  here (read, write, in_waiting, timeout, reset_input_buffer, close); tests pass a scripted fake.

Why the transport reads lines itself: pyserial's `readline()` returns a partial line at timeout, so a
line counts only when its terminator has arrived. Bytes after a terminator stay buffered for the next
call (continuous streams deliver several lines per read).

Unplugging shows up as OSError / SerialException (a subclass of OSError) on read or write. The transport
then closes the port and raises DeviceNotFound; the next attempt reopens the same path, so a device that
comes back under the same name (a udev by-id link, the simulator's stable link) is picked up again.
`open_count` tells a driver that a reopen happened (the device may have power-cycled: reconfigure it).

Shared line: a SerialLine is the cable: one pyserial handle, its baud rate, its receive buffer and one
lock. Each device on it gets its own SerialTransport from `line.transport(device_id, name=...)` (its own
name in errors, its own timeouts and tries); every call takes the line's lock, so one exchange never
interleaves with another device's, and `with transport.session():` holds the line for a sequence (a
SET/RESET read, a stream). The devices' replies carry no address, so routing is by turn: the reply on the
line belongs to the device whose command was just sent while it holds the line. Device ids are unique
per line. The port closes when the last of its devices closes it.
"""

from __future__ import annotations

import functools
import logging
import sys
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

from drivers.clock import Clock, RealClock
from drivers.errors import DeviceNotFound, DeviceTimeout, OptionError
from drivers.transports.retry import with_retries

T = TypeVar("T")
log = logging.getLogger("magrig.transport.serial")

BITS_PER_BYTE_8N1 = 10  # start + 8 data + stop


# A pulled cable shows up as OSError (SerialException is one) or, from termios calls, termios.error.
# Windows has no termios (pyserial raises SerialException there): only OSError.
try:
    from termios import error as _TermiosError

    PORT_ERRORS: tuple[type[BaseException], ...] = (OSError, _TermiosError)
except ImportError:
    PORT_ERRORS = (OSError,)


def line_time_s(n_bytes: int, baudrate: int) -> float:
    """Time `n_bytes` take on an 8N1 line."""
    return n_bytes * BITS_PER_BYTE_8N1 / baudrate


def _is_write_timeout(exc: BaseException) -> bool:
    """pyserial's write timeout (a SerialException, so an OSError too). pyserial is loaded where a port
    is opened; before that no error can be one of its classes."""
    pyserial = sys.modules.get("serial")
    return pyserial is not None and isinstance(exc, getattr(pyserial, "SerialTimeoutException", ()))


def _locked(method: Callable[..., T]) -> Callable[..., T]:
    """Run the method holding the line's lock: one device's exchange at a time on a shared line."""

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        with self.line.lock:
            return method(self, *args, **kwargs)

    return wrapper


def _open_with_pyserial(port: str, *, baudrate: int, timeout_s: float) -> Any:
    import serial  # here, not at import: pyserial's POSIX backend needs fcntl and termios

    return serial.serial_for_url(port, baudrate=baudrate, timeout=timeout_s, write_timeout=timeout_s)


class SerialLine:
    """One serial port (cable) and what belongs to it rather than to a device on it."""

    def __init__(self, port: str, *, baudrate: int = 9600, opener: Callable[..., Any] | None = None):
        self.port = port
        self.baudrate = baudrate
        self.opener = opener or _open_with_pyserial
        self.lock = threading.RLock()
        self.ser: Any = None
        self.port_timeout_s: float | None = None
        self.rx = bytearray()
        self.open_count = 0
        self.users: set[int] = set()  # ids of the transports that have the port open
        self.device_ids: dict[int, str] = {}

    def transport(self, device_id: int, *, name: str, **kwargs) -> SerialTransport:
        """The transport of device `device_id` on this line (kwargs: clock, timeout_s, tries, backoff_s)."""
        with self.lock:
            if self.device_ids.get(device_id, name) != name:
                raise OptionError(
                    f"{name}: device id {device_id} on {self.port} is already {self.device_ids[device_id]}'s"
                )
            self.device_ids[device_id] = name
        return SerialTransport(self.port, name=name, line=self, **kwargs)

    def close_port(self) -> None:
        """Close the port for every device on the line; never raises."""
        with self.lock:
            ser, self.ser = self.ser, None
            self.rx.clear()
            self.users.clear()
            if ser is not None:
                try:
                    ser.close()
                except Exception as exc:  # noqa: BLE001 - closing a dead port must not raise
                    log.debug("%s: close: %s", self.port, exc)


class SerialTransport:
    """One device's view of a serial port: its name, timeouts and retries. Thread-safe through the line's
    lock (a port of its own, or a SerialLine shared with other devices)."""

    def __init__(
        self,
        port: str,
        *,
        name: str,
        clock: Clock | None = None,
        baudrate: int = 9600,
        timeout_s: float = 0.5,
        tries: int = 3,
        backoff_s: float = 0.02,
        opener: Callable[..., Any] | None = None,
        line: SerialLine | None = None,
    ):
        self.line = line or SerialLine(port, baudrate=baudrate, opener=opener)
        self.port = self.line.port
        self.name = name
        self.clock = clock or RealClock()
        self.timeout_s = timeout_s
        self.tries = tries
        self.backoff_s = backoff_s

    # --- link -------------------------------------------------------------------------------------
    @property
    def baudrate(self) -> int:
        return self.line.baudrate

    @property
    def open_count(self) -> int:
        return self.line.open_count

    @property
    def shared(self) -> bool:
        return len(self.line.device_ids) > 1

    @property
    def is_open(self) -> bool:
        return self.line.ser is not None

    def session(self) -> threading.RLock:
        """`with transport.session():` keeps the line to this device for a sequence of exchanges."""
        return self.line.lock

    def open(self) -> None:
        """Open the port if it is not open. Raises DeviceNotFound if the port cannot be opened."""
        line = self.line
        with line.lock:
            line.users.add(id(self))
            if line.ser is not None:
                return
            try:
                line.ser = line.opener(line.port, baudrate=line.baudrate, timeout_s=self.timeout_s)
            except (*PORT_ERRORS, ValueError) as exc:
                line.users.discard(id(self))
                raise DeviceNotFound(self.name, "open port", f"cannot open {line.port}: {exc}") from exc
            line.port_timeout_s = self.timeout_s
            line.rx.clear()
            line.open_count += 1
        log.debug("%s: opened %s at %d baud", self.name, line.port, line.baudrate,
                  extra={"device": self.name})

    def close(self) -> None:
        """Release the port (closed when no other device on the line has it open); never raises."""
        with self.line.lock:
            self.line.users.discard(id(self))
            if not self.line.users:
                self.line.close_port()

    def set_baudrate(self, baudrate: int, *, operation: str = "set baud rate") -> None:
        """Send what is queued at the old rate, then switch the open port (and later opens) to `baudrate`."""
        with self.line.lock:
            self.line.baudrate = baudrate
            if self.line.ser is None:
                return
            try:
                self.line.ser.flush()
                self.line.ser.baudrate = baudrate
            except PORT_ERRORS as exc:
                raise self._lost(operation, exc) from exc
            self.line.rx.clear()
        log.debug("%s: %s now at %d baud", self.name, self.port, baudrate, extra={"device": self.name})

    def _lost(self, operation: str, exc: BaseException) -> DeviceNotFound:
        """The port went away (unplug): close it so the next attempt reopens it."""
        self.line.close_port()
        return DeviceNotFound(self.name, operation, f"port {self.port} lost: {exc}")

    def _port(self) -> Any:
        self.open()
        return self.line.ser

    # --- bytes ------------------------------------------------------------------------------------
    @_locked
    def write(self, data: bytes, *, operation: str = "write") -> None:
        """Send `data` once (no retry). A lost port raises DeviceNotFound after closing it."""
        ser = self._port()
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s > %r", self.name, data, extra={"device": self.name})
        try:
            ser.write(data)
        except PORT_ERRORS as exc:
            if _is_write_timeout(exc):
                raise DeviceTimeout(self.name, operation, f"write of {len(data)} bytes timed out") from exc
            raise self._lost(operation, exc) from exc

    @_locked
    def flush_input(self) -> None:
        """Drop whatever has arrived but not been read (stale replies, stream tail)."""
        self.line.rx.clear()
        ser = self._port()
        try:
            ser.reset_input_buffer()
        except PORT_ERRORS as exc:
            raise self._lost("flush input", exc) from exc

    def _set_port_timeout(self, seconds: float) -> None:
        if seconds != self.line.port_timeout_s:
            self.line.ser.timeout = seconds
            self.line.port_timeout_s = seconds

    @_locked
    def read_line(
        self, terminator: bytes = b"\r", timeout_s: float | None = None, *, operation: str = "read line"
    ) -> bytes:
        """The next complete line, terminator included. Raises DeviceTimeout if it is not complete
        within `timeout_s` (the partial bytes are dropped and named in the message)."""
        timeout = self.timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout
        ser = self._port()
        while True:
            end = self.line.rx.find(terminator)
            if end >= 0:
                end += len(terminator)
                line = bytes(self.line.rx[:end])
                del self.line.rx[:end]
                if log.isEnabledFor(logging.DEBUG):
                    log.debug("%s < %r", self.name, line, extra={"device": self.name})
                return line
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                partial = bytes(self.line.rx)
                self.line.rx.clear()
                what = f"incomplete line {partial!r}" if partial else "no reply"
                raise DeviceTimeout(self.name, operation, f"{what} within {timeout:g} s")
            try:
                # Blocking waits use the port's own timeout. Changing it costs system calls, so it is
                # changed only when far off: a call ends at most 10 % of its timeout late.
                if not 0.5 * remaining <= self.line.port_timeout_s <= remaining + 0.1 * timeout:
                    self._set_port_timeout(remaining)
                waiting = ser.in_waiting
                chunk = ser.read(waiting if waiting else 1)
            except PORT_ERRORS as exc:
                raise self._lost(operation, exc) from exc
            self.line.rx += chunk

    @_locked
    def discard_input(self, quiet_s: float = 0.05) -> int:
        """Read and drop bytes until the line has been quiet for `quiet_s` (e.g. the tail of a stream
        after it was stopped). Returns the number of bytes dropped."""
        dropped = len(self.line.rx)
        self.line.rx.clear()
        ser = self._port()
        try:
            self._set_port_timeout(quiet_s)
            while chunk := ser.read(max(1, ser.in_waiting)):
                dropped += len(chunk)
        except PORT_ERRORS as exc:
            raise self._lost("discard input", exc) from exc
        if dropped and log.isEnabledFor(logging.DEBUG):
            log.debug("%s: dropped %d stale bytes", self.name, dropped, extra={"device": self.name})
        return dropped

    # --- requests ---------------------------------------------------------------------------------
    @_locked
    def retry(self, op: Callable[[], T], *, operation: str, tries: int | None = None) -> T:
        """`op` with this transport's bounded retries; the final error names device and operation."""
        return with_retries(
            op,
            device=self.name,
            operation=operation,
            tries=self.tries if tries is None else tries,
            backoff_s=self.backoff_s,
            clock=self.clock,
        )

    @_locked
    def exchange(
        self, command: bytes, *, operation: str, terminator: bytes = b"\r", timeout_s: float | None = None
    ) -> bytes:
        """One try: drop stale input, send `command`, return the next complete reply line."""
        self.flush_input()
        self.write(command, operation=operation)
        return self.read_line(terminator, timeout_s, operation=operation)

    @_locked
    def query(
        self,
        command: bytes,
        *,
        operation: str,
        parse: Callable[[bytes], T],
        terminator: bytes = b"\r",
        timeout_s: float | None = None,
        tries: int | None = None,
    ) -> T:
        """`exchange` then `parse`, retried as a whole. `parse` raises ProtocolError for a malformed
        reply, so the retry re-sends the command."""

        def once() -> T:
            reply = self.exchange(command, operation=operation, terminator=terminator, timeout_s=timeout_s)
            return parse(reply)

        return self.retry(once, operation=operation, tries=tries)
