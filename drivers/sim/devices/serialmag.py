"""Fake firmware of the Honeywell HMR2300 serial magnetometer (drivers/serialmag.py), on a pty pair.

    SerialMagSim(world, dut, device_id=0, *, reply_latency_s=0.002, line_time=False, world_time=False,
                 serial_number="SM2300-0001", firmware="SM2300 fw 1.4", range_counts=30000, seed=0)
      .start() -> str   a line of its own; the port path a driver opens (a stable symlink to the pty slave)
      .stop()           stop the stream thread and the pty; also on leaving a `with` block
    SerialMagLine([sim_a, sim_b, ...])   several devices (distinct ids) behind ONE pty, like an RS-485 line
      .start() -> str, .stop(), .unplug(), .replug(), .path, .dropped_bytes

Replies follow the datasheet command table in hardware-notes 2.3:
    *ddWE -> OK          *ddR=nnn -> OK          *dd]S / *dd]R -> SET / RST
    *ddTN / TF -> S/R_ON / S/R_OFF     *ddZN / ZF -> ZERO_ON / ZERO_OFF     *ddVN / VF -> AVG_ON / AVG_OFF
    *ddA / *ddB -> ASCII_ON / BINARY_ON          anything not understood -> Re-enter
R=, TN/TF, ZN/ZF, VN/VF and !BR= need a *ddWE just before them; without it the answer is Re-enter (the
notes: "a device that did not get it may answer Re-enter"). WE enables exactly one command.
A device answers only its own id; id 99 addresses every device, which act on it without replying (the
notes say 99 is for commands that need no reply; what a real unit sends back is not stated).
Where the notes give the command but no reply, the replies are ours: `#` and `F` answer one text line,
`Q` a one-line summary, `!BR=S|F` nothing. D, SP, RST and H are not simulated (Re-enter).

Samples: ASCII 28 bytes, three 7-byte fields with the thousands comma, two spaces each, CR; 15000 counts
per gauss. Binary (after *ddB): 7 bytes, X, Y, Z as signed 16-bit big-endian, then CR: that layout is
inferred in the notes, not verified byte by byte.

Baud: the device starts at 9600 (our assumption: the notes give 9600 and 19200 as the rates, not the
power-on one) and `*99!BR=F` / `*99!BR=S` switch it to 19200 / 9600. Commands arriving while the driver's
end of the pty is set to another rate are not understood at all (a UART at the wrong rate sees framing
errors): no reply.

Physics: each sample is world.dut_raw_nt(dut, polarity), the bridge output after the last SET (+1) or
RESET (-1) pulse, or with auto S/R on the device's own (out_set - out_reset)/2. It is quantised at 15000
counts per gauss and clipped to +-range_counts (+-2 gauss). ZN stores the present reading as the zero;
VN only records the flag (averaging is not modelled).

Timing: replies leave `reply_latency_s` after the CR (the notes: about 2 ms); continuous mode emits at the
commanded rate from its own thread. With `line_time`, every command and every line sent is also held back
for its 8N1 time at the device's baud rate. These waits are real time (the pty is real I/O), unless
`world_time` (the rig's simulated stations) and the world's clock is simulated: then the bytes leave at
once, and the waits stay out of the simulated time as they always were (charged to the shared clock from
this thread, they would add to the I2C DUTs' waits of the same sample instead of overlapping them).

Power-on defaults: rate 20 Hz, auto S/R on, polarity +1 (SET), ASCII, 9600 baud, not streaming,
write-enable off.

Fault hooks (thread-safe, each counts down per command or per line):
    drop_next(n)              ignore the next n commands (the driver times out)
    garble_next(n, mode)      corrupt the next n sample lines sent: "flip" turns one digit into a letter,
                              "noise" puts junk bytes before the line, "truncate" sends the first half
                              without its CR (the rest of the line is lost)
    wrong_entry_next(n)       answer the next n commands with "Re-enter"
    faults                    a drivers.sim.devices.faults.DeviceFaults drawn once per command addressed to
    this
                              device that has a reply: "no_reply" (the command acts, its reply is
                              lost), "unplug" (nothing
                              acts, nothing answers), "garbled" (a sample line gets a digit turned into a
                              letter; any other reply is cut short, without its CR)
    unplug() / replug()       close the pty (the driver's port errors) / plug a new one in. replug()
                              serves the SAME path as before (the stable symlink moves to the new
                              /dev/pts/N, like a udev by-id link), and the firmware restarts at its
                              power-on defaults, so the driver must reconnect and reconfigure.
"""

from __future__ import annotations

import os
import re
import shutil
import struct
import tempfile
import threading
import time
from collections.abc import Sequence

import numpy as np

from drivers.registry import SimRequest, SimSerial
from drivers.sim.transports.pty import PtyLink
from drivers.sim.world import World

COUNTS_PER_GAUSS = 15_000
NT_PER_GAUSS = 100_000.0
# The simulator keeps its own copy of the datasheet's rate list on purpose: a simulator that imported the
# driver's table would agree with any mistake in it.
RATES_HZ = (10, 20, 25, 30, 40, 50, 60, 100, 123, 154)
BAUD_OF_CODE = {"S": 9600, "F": 19200}  # *99!BR=S / *99!BR=F
POWER_ON_BAUD = 9600
ESC = 0x1B
SAMPLE_LINE_BYTES = 28
BROADCAST_ID = 99
NEEDS_WRITE_ENABLE = ("R=", "TN", "TF", "ZN", "ZF", "VN", "VF", "!BR=")
TOGGLE_REPLIES = {  # command -> (attribute, value, datasheet reply)
    "TN": ("auto_set_reset", True, b"S/R_ON"),
    "TF": ("auto_set_reset", False, b"S/R_OFF"),
    "ZN": ("zero_on", True, b"ZERO_ON"),
    "ZF": ("zero_on", False, b"ZERO_OFF"),
    "VN": ("averaging", True, b"AVG_ON"),
    "VF": ("averaging", False, b"AVG_OFF"),
    "A": ("binary", False, b"ASCII_ON"),
    "B": ("binary", True, b"BINARY_ON"),
}
_COMMAND = re.compile(rb"\*(\d\d)(.+)")
_MAX_COMMAND_BYTES = 64


def format_sample_line(counts) -> bytes:
    """28 bytes: per axis a sign byte, the magnitude in 6 bytes with a thousands comma, two spaces; CR."""
    fields = "".join(f"{'-' if c < 0 else ' '}{abs(int(c)):>6,}  " for c in counts)
    return (fields + "\r").encode("ascii")


def format_binary_sample(counts) -> bytes:
    """7 bytes: X, Y, Z signed 16-bit big-endian, CR (layout inferred in the notes, not verified)."""
    return struct.pack(">hhh", *(int(c) for c in counts)) + b"\r"


class SerialMagLine:
    """One pty with one or more simulated devices behind it; bytes from the driver reach every device."""

    def __init__(self, devices: Sequence[SerialMagSim]):
        ids = [d.device_id for d in devices]
        if len(set(ids)) != len(ids) or BROADCAST_ID in ids:
            raise ValueError(f"device ids on one line must be distinct and not 99: {ids}")
        self.devices = list(devices)
        self._link: PtyLink | None = None
        self._tmpdir: str | None = None
        for d in self.devices:
            d.line = self

    def start(self) -> str:
        self._tmpdir = tempfile.mkdtemp(prefix="magrig-serialmag-")
        name = "-".join(f"{d.device_id:02d}" for d in self.devices)
        self._link = PtyLink(self._on_bytes, link_path=os.path.join(self._tmpdir, f"serialmag{name}"))
        for d in self.devices:
            d.closing.clear()
        return self._link.plug()

    def stop(self) -> None:
        for d in self.devices:
            d.closing.set()
            d.stop_stream()
        if self._link is not None:
            self._link.unplug()
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            self._tmpdir = None

    def __enter__(self) -> SerialMagLine:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def path(self) -> str | None:
        return self._link.path if self._link else None

    @property
    def dropped_bytes(self) -> int:
        """Bytes lost because the driver did not read them (pty buffer full)."""
        return self._link.dropped_bytes if self._link else 0

    def port_baudrate(self) -> int | None:
        return self._link.port_baudrate() if self._link else None

    def write(self, data: bytes) -> None:
        if self._link is not None:
            self._link.write(data)

    def unplug(self) -> None:
        for d in self.devices:
            d.stop_stream()
        self._link.unplug()

    def replug(self) -> str:
        """Power comes back: every device restarts at its power-on defaults."""
        for d in self.devices:
            d.power_on()
        return self._link.plug()

    def _on_bytes(self, data: bytes) -> None:
        for d in self.devices:
            d.on_bytes(data)


class SerialMagSim:
    """One device's firmware: parses commands from its line, replies and streams from the world."""

    def __init__(
        self,
        world: World,
        dut: str,
        device_id: int = 0,
        *,
        reply_latency_s: float = 0.002,
        line_time: bool = False,
        world_time: bool = False,
        serial_number: str = "SM2300-0001",
        firmware: str = "SM2300 fw 1.4",
        range_counts: int = 30_000,
        seed: int = 0,
    ):
        self.world = world
        self.dut = dut
        self.device_id = device_id
        self.reply_latency_s = reply_latency_s
        self.line_time = line_time
        self.world_time = world_time
        self.serial_number = serial_number
        self.firmware = firmware
        self.range_counts = range_counts
        self.line: SerialMagLine | None = None
        self._own_line = False
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()  # firmware state and the order of lines on the wire
        self._rx = bytearray()
        self._stream_thread: threading.Thread | None = None
        self._stream_stop = threading.Event()
        self.closing = threading.Event()
        self.received: list[bytes] = []  # every command line this device understood the bytes of
        self._drop = self._wrong = self._garble = 0
        self._garble_mode = "flip"
        self.faults = None
        self.power_on()

    def power_on(self) -> None:
        with self._lock:
            self.rate_hz = 20
            self.auto_set_reset = True
            self.zero_on = False
            self.zero_counts = np.zeros(3, dtype=int)
            self.averaging = False
            self.binary = False
            self.baud = POWER_ON_BAUD
            self.polarity = 1
            self.write_enabled = False
            self._rx.clear()

    # --- life cycle -------------------------------------------------------------------------------
    def start(self) -> str:
        """Serve on a line of its own (for several devices on one line, use SerialMagLine)."""
        if self.line is None:
            SerialMagLine([self])
            self._own_line = True
        if not self._own_line:
            raise ValueError(f"device {self.device_id:02d} is on a shared line: start the SerialMagLine")
        return self.line.start()

    @property
    def path(self) -> str | None:
        return self.line.path if self.line else None

    @property
    def streaming(self) -> bool:
        return self._stream_thread is not None

    @property
    def garbles_pending(self) -> int:
        """Sample lines still to be garbled by garble_next()."""
        return self._garble

    @property
    def dropped_bytes(self) -> int:
        return self.line.dropped_bytes if self.line else 0

    def stop(self) -> None:
        if self.line is not None and self._own_line:
            self.line.stop()
        else:
            self.closing.set()
            self.stop_stream()

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
        """Pull the cable of this device's line (every device on it goes with it)."""
        self.line.unplug()

    def replug(self) -> str:
        return self.line.replug()

    # --- input ------------------------------------------------------------------------------------
    def on_bytes(self, data: bytes) -> None:
        port_baud = self.line.port_baudrate()
        if port_baud is not None and port_baud != self.baud:
            return  # framing errors at the wrong rate: nothing is understood
        for byte in data:
            if byte == ESC:
                self.stop_stream()
                self._rx.clear()
            elif byte == 0x0D:
                line, self._rx = bytes(self._rx), bytearray()
                self._on_command(line)
            elif byte != 0x0A and len(self._rx) < _MAX_COMMAND_BYTES:
                self._rx.append(byte)

    def _on_command(self, line: bytes) -> None:
        if self.line_time:  # the command's own bytes (and its CR) take time on the wire
            self._wait((len(line) + 1) * 10 / self.baud)
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
                if len(self.line.devices) == 1:  # on a shared line nobody knows it was theirs
                    self._reply(b"Re-enter")
                return
            device_id = int(m.group(1))
            if device_id not in (self.device_id, BROADCAST_ID):
                return  # another device on the bus
            if self.faults is not None and self.faults.unplugged():
                self.faults.draw()  # counted as an unplugged operation
                return
            reply = self._execute(m.group(2).decode("ascii", errors="replace"))
            if reply is None or device_id == BROADCAST_ID:
                return
            fault = self.faults.draw() if self.faults is not None else None  # drawn only where it shows
            if fault == "no_reply":
                return
            if fault != "garbled":
                self._reply(reply)
            elif len(reply) + 1 == SAMPLE_LINE_BYTES:
                self._reply(self._garbled(reply + b"\r")[:-1])  # a digit turned into a letter
            else:  # a text reply cut short by noise: its CR never arrives
                self._send(reply[: len(reply) // 2])

    def _execute(self, body: str) -> bytes | None:
        """Firmware state machine; returns the reply line without CR (None: no reply)."""
        write_enabled, self.write_enabled = self.write_enabled, False
        if body.startswith(NEEDS_WRITE_ENABLE) and not write_enabled:
            return b"Re-enter"
        if body == "P":
            return self._sample_bytes()[:-1]
        if body == "C":
            self._start_stream()
            return None
        if body == "WE":
            self.write_enabled = True
            return b"OK"
        if body in ("]S", "]R"):
            self.polarity = 1 if body == "]S" else -1
            return b"SET" if body == "]S" else b"RST"
        if body in TOGGLE_REPLIES:
            attribute, value, reply = TOGGLE_REPLIES[body]
            if body == "ZN":
                self.zero_counts = self._counts(zeroed=False)
            setattr(self, attribute, value)
            return reply
        if body.startswith("R=") and body[2:].isdigit() and int(body[2:]) in RATES_HZ:
            self.rate_hz = int(body[2:])
            return b"OK"
        if body.startswith("!BR=") and body[4:] in BAUD_OF_CODE:
            self.baud = BAUD_OF_CODE[body[4:]]  # the notes give no reply: none is sent
            return None
        if body == "#":
            return self.serial_number.encode()
        if body == "F":
            return self.firmware.encode()
        if body == "Q":
            sr, fmt = "ON" if self.auto_set_reset else "OFF", "BINARY" if self.binary else "ASCII"
            text = f"ID={self.device_id:02d} RATE={self.rate_hz} S/R={sr} FORMAT={fmt} BAUD={self.baud}"
            return text.encode()
        return b"Re-enter"

    # --- output -----------------------------------------------------------------------------------
    def _counts(self, zeroed: bool = True) -> np.ndarray:
        if self.auto_set_reset:
            raw_nt = (self.world.dut_raw_nt(self.dut, 1) - self.world.dut_raw_nt(self.dut, -1)) / 2
        else:
            raw_nt = self.world.dut_raw_nt(self.dut, self.polarity)
        # three numbers: python's round (half to even, as numpy's) and min/max cost less than numpy's calls
        counts = [round(v * COUNTS_PER_GAUSS / NT_PER_GAUSS) for v in raw_nt.tolist()]
        if zeroed and self.zero_on:
            counts = [c - int(z) for c, z in zip(counts, self.zero_counts, strict=True)]
        top = self.range_counts
        return np.array([min(top, max(-top, c)) for c in counts])

    def _sample_bytes(self) -> bytes:
        """One sample in the current output format, CR included."""
        counts = self._counts()
        return format_binary_sample(counts) if self.binary else format_sample_line(counts)

    def _reply(self, line: bytes) -> None:
        self._wait(self.reply_latency_s)
        self._send(line + b"\r")

    def _wait(self, seconds: float, unless: threading.Event | None = None) -> None:
        """Let `seconds` pass before the line goes on, in real time; none with world_time on a simulated
        clock (module docstring)."""
        if seconds > 0 and not (self.world_time and getattr(self.world.clock, "simulated", False)):
            (unless or self.closing).wait(seconds)

    def _send(self, line: bytes, unless: threading.Event | None = None) -> None:
        """Put a line on the wire (after its line time, if emulated); skipped once `unless` is set."""
        if self.line_time:
            self._wait(len(line) * 10 / self.baud, unless)
        with self._lock:
            if unless is not None and unless.is_set():
                return
            if self._garble > 0 and len(line) == SAMPLE_LINE_BYTES:
                self._garble -= 1
                line = self._garbled(line)
            self.line.write(line)

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
                line = self._sample_bytes()
                period_s = 1.0 / self.rate_hz
            self._send(line, unless=self._stream_stop)
            next_t = max(next_t + period_s, time.monotonic() - period_s)

    def stop_stream(self) -> None:
        self._stream_stop.set()
        thread, self._stream_thread = self._stream_thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)


def simulate(req: SimRequest) -> SimSerial:
    device_id = getattr(req.options, "device_id", 0)
    return SimSerial(SerialMagSim(req.world, req.name, device_id, world_time=True), baudrate=9600,
                     timeout_s=0.5)
