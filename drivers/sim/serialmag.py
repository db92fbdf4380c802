"""Fake firmware of the HMR2300-style serial magnetometer (drivers/serialmag.py), on a pty pair.

    SerialMagSim(world, dut, device_id=0, *, reply_latency_s=0.002, line_baudrate=None,
                 serial_number="SM2300-0001", firmware="SM2300 fw 1.4", range_counts=30000, seed=0)
      .start() -> str   the port path a driver opens (a stable symlink to the pty slave, see replug)
      .stop()           stop the stream thread and the pty; also on leaving a `with` block

Physics: each sample is world.dut_raw_nt(dut, polarity), the bridge output after the last SET (+1) or
RESET (-1) pulse, or with auto S/R on the device's own (out_set - out_reset)/2. It is quantised at 15000
counts per gauss and clipped to +-range_counts (+-2 gauss).

Timing is real time (the pty is real I/O): replies leave `reply_latency_s` after the CR; continuous mode
emits at the commanded rate from its own thread. With `line_baudrate` set, every command and every line
sent is also held back for its 8N1 line time, so wall-clock figures include the wire time a real cable
would add.

Power-on defaults: rate 20 Hz, auto S/R on, polarity +1 (SET), not streaming, write-enable off.
Our choices where the HMR2300 manual is silent: setting commands (R=, TN, TF) without a preceding *ddWE
get "Re-enter"; WE enables exactly one setting command; binary mode (*ddB) is not simulated ("Re-enter").

Fault hooks (thread-safe, each counts down per command or per line):
    drop_next(n)              ignore the next n commands (the driver times out)
    garble_next(n, mode)      corrupt the next n sample lines sent: "flip" turns one digit into a letter,
                              "noise" puts junk bytes before the line, "truncate" sends the first half
                              without its CR (the rest of the line is lost)
    wrong_entry_next(n)       answer the next n commands with "Re-enter"
    unplug() / replug()       close the pty (the driver's port errors) / plug a new one in. replug()
                              serves the SAME path as before (the stable symlink moves to the new
                              /dev/pts/N, like a udev by-id link), and the firmware restarts at its
                              power-on defaults, so the driver must reconnect and reconfigure.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import threading
import time

import numpy as np

from drivers.registry import SimRequest, SimSerial
from drivers.serialmag import RATES_HZ
from drivers.sim.pty import PtyLink
from drivers.sim.world import World

COUNTS_PER_GAUSS = 15_000
NT_PER_GAUSS = 100_000.0
ESC = 0x1B
SAMPLE_LINE_BYTES = 28
_COMMAND = re.compile(rb"\*(\d\d)(.+)")
_MAX_COMMAND_BYTES = 64


def format_sample_line(counts) -> bytes:
    """28 bytes: per axis a sign byte, the magnitude in 6 bytes with a thousands comma, two spaces; CR."""
    fields = "".join(f"{'-' if c < 0 else ' '}{abs(int(c)):>6,}  " for c in counts)
    return (fields + "\r").encode("ascii")


class SerialMagSim:
    """The device's firmware: parses commands from the pty, replies and streams from the world."""

    def __init__(
        self,
        world: World,
        dut: str,
        device_id: int = 0,
        *,
        reply_latency_s: float = 0.002,
        line_baudrate: int | None = None,
        serial_number: str = "SM2300-0001",
        firmware: str = "SM2300 fw 1.4",
        range_counts: int = 30_000,
        seed: int = 0,
    ):
        self.world = world
        self.dut = dut
        self.device_id = device_id
        self.reply_latency_s = reply_latency_s
        self.line_baudrate = line_baudrate
        self.serial_number = serial_number
        self.firmware = firmware
        self.range_counts = range_counts
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()  # firmware state and the order of lines on the wire
        self._rx = bytearray()
        self._link: PtyLink | None = None
        self._tmpdir: str | None = None
        self._stream_thread: threading.Thread | None = None
        self._stream_stop = threading.Event()
        self._closing = threading.Event()
        self.received: list[bytes] = []  # every command line seen, for tests
        self._drop = self._wrong = self._garble = 0
        self._garble_mode = "flip"
        self._power_on()

    def _power_on(self) -> None:
        self.rate_hz = 20
        self.auto_set_reset = True
        self.polarity = 1
        self.write_enabled = False

    # --- life cycle -------------------------------------------------------------------------------
    def start(self) -> str:
        self._tmpdir = tempfile.mkdtemp(prefix="magrig-serialmag-")
        link_path = os.path.join(self._tmpdir, f"serialmag{self.device_id}")
        self._link = PtyLink(self._on_bytes, link_path=link_path)
        self._closing.clear()
        return self._link.plug()

    @property
    def path(self) -> str | None:
        return self._link.path if self._link else None

    @property
    def streaming(self) -> bool:
        return self._stream_thread is not None

    @property
    def garbles_pending(self) -> int:
        """Sample lines still to be garbled by garble_next()."""
        return self._garble

    @property
    def dropped_bytes(self) -> int:
        """Bytes lost because the driver did not read them (pty buffer full)."""
        return self._link.dropped_bytes if self._link else 0

    def stop(self) -> None:
        self._closing.set()
        self._stop_stream()
        if self._link is not None:
            self._link.unplug()
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            self._tmpdir = None

    def __enter__(self) -> SerialMagSim:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- fault hooks ------------------------------------------------------------------------------
    def drop_next(self, n: int = 1) -> None:
        with self._lock:
            self._drop = n

    def wrong_entry_next(self, n: int = 1) -> None:
        with self._lock:
            self._wrong = n

    def garble_next(self, n: int = 1, mode: str = "flip") -> None:
        if mode not in ("flip", "noise", "truncate"):
            raise ValueError(f"garble mode {mode!r}: use flip, noise or truncate")
        with self._lock:
            self._garble, self._garble_mode = n, mode

    def unplug(self) -> None:
        self._stop_stream()
        self._link.unplug()

    def replug(self) -> str:
        with self._lock:
            self._power_on()
            self._rx.clear()
        return self._link.plug()

    # --- input ------------------------------------------------------------------------------------
    def _on_bytes(self, data: bytes) -> None:
        for byte in data:
            if byte == ESC:
                self._stop_stream()
                self._rx.clear()
            elif byte == 0x0D:
                line, self._rx = bytes(self._rx), bytearray()
                self._on_command(line)
            elif byte != 0x0A and len(self._rx) < _MAX_COMMAND_BYTES:
                self._rx.append(byte)

    def _on_command(self, line: bytes) -> None:
        if self.line_baudrate:  # the command's own bytes (and its CR) take time on the wire
            self._closing.wait((len(line) + 1) * 10 / self.line_baudrate)
        with self._lock:
            self.received.append(line)
            if self._drop > 0:
                self._drop -= 1
                return
            if self._wrong > 0:
                self._wrong -= 1
                self._reply(b"Re-enter")
                return
            m = _COMMAND.fullmatch(line)
            if m is None:
                self._reply(b"Re-enter")
                return
            if int(m.group(1)) not in (self.device_id, 99):
                return  # another device on the bus
            reply = self._execute(m.group(2).decode("ascii", errors="replace"))
            if reply is not None:
                self._reply(reply)

    def _execute(self, body: str) -> bytes | None:
        """Firmware state machine; returns the reply line without CR (None: no reply)."""
        write_enabled, self.write_enabled = self.write_enabled, False
        if body == "P":
            return format_sample_line(self._counts())[:-1]
        if body == "C":
            self._start_stream()
            return None
        if body == "WE":
            self.write_enabled = True
            return b"OK"
        if body in ("]S", "]R"):
            self.polarity = 1 if body == "]S" else -1
            return b"SET" if body == "]S" else b"RST"
        if body == "#":
            return self.serial_number.encode()
        if body == "F":
            return self.firmware.encode()
        if body == "A":
            return b"ASCII_ON"
        if body == "Q":
            sr = "ON" if self.auto_set_reset else "OFF"
            return f"ID={self.device_id:02d} RATE={self.rate_hz} S/R={sr} FORMAT=ASCII".encode()
        if write_enabled and body in ("TN", "TF"):
            self.auto_set_reset = body == "TN"
            return b"OK"
        if write_enabled and body.startswith("R=") and body[2:].isdigit() and int(body[2:]) in RATES_HZ:
            self.rate_hz = int(body[2:])
            return b"OK"
        return b"Re-enter"

    # --- output -----------------------------------------------------------------------------------
    def _counts(self) -> np.ndarray:
        if self.auto_set_reset:
            raw_nt = (self.world.dut_raw_nt(self.dut, 1) - self.world.dut_raw_nt(self.dut, -1)) / 2
        else:
            raw_nt = self.world.dut_raw_nt(self.dut, self.polarity)
        counts = np.round(raw_nt * COUNTS_PER_GAUSS / NT_PER_GAUSS)
        return np.clip(counts, -self.range_counts, self.range_counts).astype(int)

    def _reply(self, line: bytes) -> None:
        if self.reply_latency_s > 0:
            self._closing.wait(self.reply_latency_s)
        self._send(line + b"\r")

    def _send(self, line: bytes, unless: threading.Event | None = None) -> None:
        """Put a line on the wire (after its line time, if emulated); skipped once `unless` is set."""
        if self.line_baudrate:
            (unless or self._closing).wait(len(line) * 10 / self.line_baudrate)
        with self._lock:
            if unless is not None and unless.is_set():
                return
            if self._garble > 0 and len(line) == SAMPLE_LINE_BYTES:
                self._garble -= 1
                line = self._garbled(line)
            self._link.write(line)

    def _garbled(self, line: bytes) -> bytes:
        if self._garble_mode == "noise":
            return bytes(self._rng.integers(0x20, 0x7F, 5, dtype=np.uint8)).replace(b"\r", b"#") + line
        if self._garble_mode == "truncate":
            return line[: len(line) // 2]
        digits = [i for i, b in enumerate(line) if 0x30 <= b <= 0x39]
        out = bytearray(line)
        out[digits[int(self._rng.integers(len(digits)))]] ^= 0x40  # '0'..'9' -> 'p'..'y'
        return bytes(out)

    # --- continuous mode --------------------------------------------------------------------------
    def _start_stream(self) -> None:
        if self._stream_thread is not None:
            return
        self._stream_stop.clear()
        self._stream_thread = threading.Thread(target=self._stream, name="serialmag stream", daemon=True)
        self._stream_thread.start()

    def _stream(self) -> None:
        next_t = time.monotonic() + self.reply_latency_s
        while not self._stream_stop.wait(max(0.0, next_t - time.monotonic())):
            with self._lock:
                if self._stream_stop.is_set():
                    return
                line = format_sample_line(self._counts())
                period_s = 1.0 / self.rate_hz
            self._send(line, unless=self._stream_stop)
            next_t = max(next_t + period_s, time.monotonic() - period_s)

    def _stop_stream(self) -> None:
        self._stream_stop.set()
        thread, self._stream_thread = self._stream_thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)


def simulate(req: SimRequest) -> SimSerial:
    return SimSerial(SerialMagSim(req.world, req.name), baudrate=9600, timeout_s=0.5)
