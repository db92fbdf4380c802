"""A simulated serial cable: a pty pair whose master end the fake firmware owns.

    PtyLink(on_receive, *, link_path=None)
      .plug() -> str     create the pty, start the reader thread; returns the path a driver opens
      .write(data)       firmware -> driver bytes (dropped, not blocked on, if the driver stops reading)
      .unplug()          stop the reader, close both ends: the driver's port fails like a pulled cable
      .plugged           True between plug() and unplug()
      .port_baudrate()   the baud rate the driver's end is set to (termios), None if unplugged

The driver opens the slave end with an ordinary `serial.Serial(path)`, so the real pyserial code path
runs (open, termios, select, read). The slave is put in raw mode first; otherwise the line discipline
echoes and translates CR/LF.

`link_path`: when given, `plug()` (re)points a symlink there at the current slave device and returns
the link, like a udev /dev/serial/by-id name; after unplug()/plug() the kernel may hand out a different
/dev/pts/N, but the link path stays the same, so a driver configured with it can reconnect. Without a
link, `plug()` returns the /dev/pts/N path itself. While unplugged the link is removed, so opening it
fails with "No such file or directory" as for a missing USB adapter.
"""

from __future__ import annotations

import logging
import os
import select
import termios
import threading
import tty
from collections.abc import Callable

log = logging.getLogger("magrig.sim.pty")
_BAUD_OF_SPEED = {
    getattr(termios, f"B{b}"): b for b in (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)
}


class PtyLink:
    def __init__(self, on_receive: Callable[[bytes], None], *, link_path: str | None = None):
        self._on_receive = on_receive
        self.link_path = link_path
        self._master: int | None = None
        self._slave: int | None = None
        self._wake_r: int | None = None
        self._wake_w: int | None = None
        self._thread: threading.Thread | None = None
        self._write_lock = threading.Lock()
        self.slave_path: str | None = None
        self.dropped_bytes = 0

    @property
    def plugged(self) -> bool:
        return self._master is not None

    @property
    def path(self) -> str | None:
        return self.link_path or self.slave_path

    def plug(self) -> str:
        if self.plugged:
            return self.path
        master, slave = os.openpty()
        tty.setraw(slave)
        # Kept open by us, so the master never sees EIO while the driver has the port closed.
        self._master, self._slave = master, slave
        os.set_blocking(master, False)
        self.slave_path = os.ttyname(slave)
        self._wake_r, self._wake_w = os.pipe()
        if self.link_path:
            self._remove_link()
            os.symlink(self.slave_path, self.link_path)
        self._thread = threading.Thread(target=self._reader, name=f"pty {self.slave_path}", daemon=True)
        self._thread.start()
        return self.path

    def _reader(self) -> None:
        master, wake = self._master, self._wake_r
        while True:
            ready, _, _ = select.select([master, wake], [], [])
            if wake in ready:
                return
            try:
                data = os.read(master, 4096)
            except BlockingIOError:
                continue
            except OSError:  # slave side gone for good
                return
            if data:
                try:
                    self._on_receive(data)
                except Exception:  # a firmware bug must not kill the cable silently
                    log.exception("pty firmware handler failed")

    def port_baudrate(self) -> int | None:
        """The speed the driver set on its end of the cable (a pty keeps it, like a UART would)."""
        if self._slave is None:
            return None
        try:
            speed = termios.tcgetattr(self._slave)[5]  # ospeed, a B* constant
        except termios.error:
            return None
        return _BAUD_OF_SPEED.get(speed)

    def write(self, data: bytes) -> None:
        """Send bytes to the driver. A full buffer (nobody reading) drops bytes like a UART overrun."""
        with self._write_lock:
            if self._master is None:
                return
            try:
                sent = os.write(self._master, data)
            except (BlockingIOError, OSError):
                sent = 0
            self.dropped_bytes += len(data) - sent

    def unplug(self) -> None:
        """Stop the reader thread and close everything; safe to call twice."""
        if not self.plugged:
            return
        os.write(self._wake_w, b"x")
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        with self._write_lock:
            for fd in (self._master, self._slave, self._wake_r, self._wake_w):
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._master = self._slave = self._wake_r = self._wake_w = None
        if self.link_path:
            self._remove_link()

    def _remove_link(self) -> None:
        if self.link_path and os.path.islink(self.link_path):
            os.unlink(self.link_path)
