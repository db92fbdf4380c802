"""Serial streaming AMR magnetometer in the style of the Honeywell HMR2300 (ASCII protocol).

Constructors (what the station YAML maps onto)::

    SerialMagnetometer(transport, *, name, clock=None, device_id=0, rate_hz=20, set_reset="pulse")
    SerialMagnetometer.from_port(port, *, name, clock=None, baudrate=9600, timeout_s=0.5, tries=3,
                                 device_id=0, rate_hz=20, set_reset="pulse")

- transport: a drivers.transports.serial.SerialTransport (it owns timeouts, retries and reconnects).
- device_id: the `dd` of the commands, 0..98 (99 addresses every device on the bus).
- rate_hz: continuous-mode rate, one of RATES_HZ.
- set_reset: "pulse": auto S/R off; every read() does a RESET and a SET pulse with a poll after each and
  reports H = (H_set - H_reset)/2 and the bridge offset (H_set + H_reset)/2 in FieldSample.offset_nt.
  "auto": the device's own auto S/R (`TN`), plain polls, offset not reported. "off": no pulses at all
  (`TF`, one SET at connect so the polarity is known).

Commands (ASCII, `dd` = two-digit id, each ends with CR)::

    *ddP       poll one sample          -> one sample line
    *ddC       continuous stream        -> sample lines at the set rate until Esc (0x1B)
    *ddWE      write enable             -> "OK"     (needed before each setting command below)
    *ddR=nnn   rate in Hz               -> "OK"
    *ddTN/TF   auto S/R on/off          -> "OK"
    *dd]S/]R   one SET / RESET pulse    -> "SET" / "RST"
    *dd#       serial number            -> one text line
    *ddF       firmware version         -> one text line
    *ddQ       query setup              -> one text line
    anything the device does not accept -> "Re-enter"

The command set is the HMR2300's. The short acknowledgements (OK, SET, RST) are the ones our simulator
gives; check them against a real unit before relying on them. The HMR2300 has no temperature output:
temp_c is None (the rig places a temperature probe next to the DUT).

Sample line, 28 bytes: three 7-byte fields, each followed by two spaces, then CR::

    column  0-6    7-8   9-15   16-17  18-24  25-26  27
            X      "  "  Y      "  "   Z      "  "   CR

A field is a sign byte (space or "-") then the magnitude right-aligned in 6 bytes, thousands separated
by a comma: " 12,345", "- 1,234", "    567", "      0". 15000 counts = 1 gauss = 100000 nT; the range
is +-2 gauss (+-30,000 counts, a reading at the rail is flagged "saturated").

Line noise: a reply longer than 28 bytes whose last 28 bytes are a valid sample is accepted (the noise
before it is logged); any other malformed line is logged and discarded, and the poll is repeated within
the transport's bounded retries. Streams tolerate as many bad lines in a row as the transport's tries.
"""

from __future__ import annotations

import logging
import re

from pydantic import field_validator

from drivers import registry
from drivers.base import Device, FieldSample
from drivers.clock import Clock
from drivers.errors import DeviceError, OptionError, ProtocolError
from drivers.transports.serial import SerialTransport, line_time_s

log = logging.getLogger("magrig.drivers.serialmag")

COUNTS_PER_GAUSS = 15_000
NT_PER_GAUSS = 100_000.0
NT_PER_COUNT = NT_PER_GAUSS / COUNTS_PER_GAUSS
RANGE_COUNTS = 30_000  # +-2 gauss
RATES_HZ = (10, 20, 25, 30, 40, 50, 60, 100, 123, 154)
SET_RESET_MODES = ("pulse", "auto", "off")
LINE_BYTES = 28
FIELD_COLUMNS = ((0, 7), (9, 16), (18, 25))
SEPARATOR_COLUMNS = ((7, 9), (16, 18), (25, 27))
CR = b"\r"
ESC = b"\x1b"
OK = b"OK\r"
WRONG_ENTRY = b"Re-enter\r"
PULSE_REPLY = {1: b"SET\r", -1: b"RST\r"}
PULSE_COMMAND = {1: "]S", -1: "]R"}

_FIELD = re.compile(rb"([ -]) *(\d{1,2},\d{3}|\d{1,3})")


def command(device_id: int, body: str) -> bytes:
    """`*dd<body><CR>`."""
    return b"*%02d%s\r" % (device_id, body.encode("ascii"))


def decode_field(field: bytes) -> int | None:
    """One 7-byte signed count field, or None if it is not one."""
    m = _FIELD.fullmatch(field)
    if m is None:
        return None
    value = int(m.group(2).replace(b",", b""))
    return -value if m.group(1) == b"-" else value


def parse_sample_line(line: bytes) -> tuple[int, int, int] | None:
    """Counts from exactly one 28-byte sample line, or None if the line is malformed."""
    if len(line) != LINE_BYTES or not line.endswith(CR):
        return None
    if any(line[a:b] != b"  " for a, b in SEPARATOR_COLUMNS):
        return None
    counts = [decode_field(line[a:b]) for a, b in FIELD_COLUMNS]
    if None in counts:
        return None
    return counts[0], counts[1], counts[2]


def counts_to_nt(counts) -> tuple[float, float, float]:
    return tuple(c * NT_PER_COUNT for c in counts)


class SerialMagnetometer(Device):
    kind = "magnetometer"
    model = "HMR2300-style serial AMR magnetometer"

    def __init__(
        self,
        transport: SerialTransport,
        *,
        name: str,
        clock: Clock | None = None,
        device_id: int = 0,
        rate_hz: int = 20,
        set_reset: str = "pulse",
    ):
        super().__init__(name, clock or transport.clock)
        if not 0 <= device_id <= 99:
            raise OptionError(f"{name}: device_id {device_id} is not in 0..99")
        if set_reset not in SET_RESET_MODES:
            raise OptionError(f"{name}: set_reset {set_reset!r} is not one of {', '.join(SET_RESET_MODES)}")
        _check_rate(name, rate_hz)
        self.transport = transport
        self.device_id = device_id
        self.rate_hz = rate_hz
        self.set_reset = set_reset
        self.serial_number: str | None = None
        self.firmware: str | None = None
        self._configured_open_count = -1
        self._streaming_on: int | None = None  # open_count of the port the stream was started on

    @classmethod
    def from_port(
        cls,
        port: str,
        *,
        name: str,
        clock: Clock | None = None,
        baudrate: int = 9600,
        timeout_s: float = 0.5,
        tries: int = 3,
        **kwargs,
    ) -> SerialMagnetometer:
        """Build the transport and the driver from a port path or pyserial URL."""
        transport = SerialTransport(
            port, name=name, clock=clock, baudrate=baudrate, timeout_s=timeout_s, tries=tries
        )
        return cls(transport, name=name, clock=clock, **kwargs)

    # --- link and setup ---------------------------------------------------------------------------
    def connect(self) -> None:
        self._ensure_configured()
        self.serial_number = self._text_query("#", "read serial number")
        self.firmware = self._text_query("F", "read firmware")

    def close(self) -> None:
        self.transport.close()

    def _warn(self, message: str) -> None:
        log.warning("%s: %s", self.name, message, extra={"device": self.name})

    def _cmd(self, body: str) -> bytes:
        return command(self.device_id, body)

    def _ensure_configured(self) -> None:
        """(Re)apply our settings after the first open and after every reopen: a device that was
        unplugged may have power-cycled to its defaults."""
        self.transport.open()
        if self.transport.open_count == self._configured_open_count:
            return
        self._stop_stream()
        self._setting("TN" if self.set_reset == "auto" else "TF", "set auto set/reset")
        self._setting(f"R={self.rate_hz}", "set rate")
        if self.set_reset != "auto":
            self.pulse(1)
        self._configured_open_count = self.transport.open_count

    def _expect(self, line: bytes, wanted: bytes, sent: bytes, operation: str) -> bytes:
        if line == wanted:
            return line
        if line.endswith(WRONG_ENTRY):
            raise ProtocolError(self.name, operation, f"device answered Re-enter to {sent!r}")
        raise ProtocolError(self.name, operation, f"expected {wanted!r} after {sent!r}, got {line!r}")

    def _setting(self, body: str, operation: str) -> None:
        """Write-enable, then one setting command; the pair is retried together."""
        we, cmd = self._cmd("WE"), self._cmd(body)

        def once() -> None:
            self._expect(self.transport.exchange(we, operation=operation), OK, we, operation)
            self._expect(self.transport.exchange(cmd, operation=operation), OK, cmd, operation)

        self.transport.retry(once, operation=operation)

    def _text_query(self, body: str, operation: str) -> str:
        cmd = self._cmd(body)

        def parse(line: bytes) -> str:
            text = line.rstrip(b"\r\n").decode("ascii", errors="replace").strip()
            if not text or line.endswith(WRONG_ENTRY):
                raise ProtocolError(self.name, operation, f"unusable reply {line!r} to {cmd!r}")
            return text

        return self.transport.query(cmd, operation=operation, parse=parse)

    def set_rate(self, rate_hz: int) -> None:
        """Continuous-mode output rate, one of RATES_HZ."""
        _check_rate(self.name, rate_hz)
        self._ensure_configured()
        self._setting(f"R={rate_hz}", "set rate")
        self.rate_hz = rate_hz

    def pulse(self, polarity: int) -> None:
        """One SET (+1) or RESET (-1) pulse: flips the sign of the bridge's field response."""
        cmd = self._cmd(PULSE_COMMAND[polarity])
        operation = "set pulse" if polarity > 0 else "reset pulse"
        self.transport.query(
            cmd, operation=operation,
            parse=lambda line: self._expect(line, PULSE_REPLY[polarity], cmd, operation),
        )

    def query_setup(self) -> str:
        """The device's own one-line setup summary (`*ddQ`)."""
        self._ensure_configured()
        return self._text_query("Q", "query setup")

    # --- samples ----------------------------------------------------------------------------------
    def _decode(self, line: bytes, operation: str) -> tuple[int, int, int]:
        """Counts from a reply line; noise before a valid sample is dropped, anything else raises."""
        counts = parse_sample_line(line[-LINE_BYTES:])
        if counts is not None and len(line) > LINE_BYTES:
            self._warn(f"{operation}: dropped {len(line) - LINE_BYTES} noise bytes before a sample: "
                       f"{line[:-LINE_BYTES]!r}")
        if counts is not None:
            return counts
        detail = "device answered Re-enter" if line.endswith(WRONG_ENTRY) else f"malformed line {line!r}"
        self._warn(f"{operation}: discarded {detail}")
        raise ProtocolError(self.name, operation, detail)

    def poll_counts(self) -> tuple[int, int, int]:
        """One `*ddP` sample in the current bridge polarity, retried."""
        cmd = self._cmd("P")
        return self.transport.query(
            cmd, operation="poll sample", parse=lambda line: self._decode(line, "poll sample")
        )

    def _pulsed_pair(self) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
        """(counts after RESET, counts after SET); ends in the SET state."""
        self.pulse(-1)
        reset = self.poll_counts()
        self.pulse(1)
        return reset, self.poll_counts()

    def read(self) -> FieldSample:
        """One sample. In "pulse" mode H = (H_set - H_reset)/2, counts are the SET reading's."""
        for _ in range(self.transport.tries):
            self._ensure_configured()
            opened = self.transport.open_count
            if self.set_reset != "pulse":
                return self._sample(self.poll_counts(), None)
            reset, set_ = self._pulsed_pair()
            if self.transport.open_count != opened:  # reconnected mid-sequence: polarity unknown
                self._warn("reconnected during a SET/RESET read; repeating it")
                continue
            return FieldSample(
                t=self.clock.now(), field_nt=_half_sum_nt(reset, set_, -1), counts=set_,
                offset_nt=_half_sum_nt(reset, set_),
                flags=_saturated(set_) | _saturated(reset),
            )
        raise DeviceError(self.name, "read", "the port kept reconnecting during the SET/RESET sequence")

    def _sample(self, counts, offset_nt) -> FieldSample:
        """A sample from one reading; a known bridge offset is subtracted."""
        field = counts_to_nt(counts)
        if offset_nt is not None:
            field = tuple(f - o for f, o in zip(field, offset_nt, strict=True))
        return FieldSample(
            t=self.clock.now(), field_nt=field, counts=counts, offset_nt=offset_nt, flags=_saturated(counts)
        )

    def read_stream(self, n: int) -> list[FieldSample]:
        """`n` samples from continuous mode, then the stream is stopped. In "pulse" mode the bridge
        offset is measured once with a RESET/SET pair first and subtracted from every sample."""
        operation = "stream samples"
        self._ensure_configured()
        offset_nt = _half_sum_nt(*self._pulsed_pair()) if self.set_reset == "pulse" else None
        timeout_s = max(self.transport.timeout_s, 3.0 / self.rate_hz)
        samples: list[FieldSample] = []
        failures = 0
        self._streaming_on = None
        try:
            while len(samples) < n:
                try:
                    counts = self._next_stream_counts(operation, timeout_s)
                except DeviceError as exc:
                    failures += 1
                    if failures >= self.transport.tries:
                        detail = f"{exc.detail} ({failures} failures in a row)"
                        raise type(exc)(self.name, operation, detail) from exc
                    if not isinstance(exc, ProtocolError):  # _decode has logged malformed lines
                        self._warn(f"{operation}: {exc.detail}")
                    self.clock.sleep(self.transport.backoff_s)
                    continue
                failures = 0
                samples.append(self._sample(counts, offset_nt))
        finally:
            self._stop_stream_quietly()
        return samples

    def _next_stream_counts(self, operation: str, timeout_s: float) -> tuple[int, int, int]:
        """The next streamed sample; (re)starts the stream on a fresh or reopened port."""
        if self._streaming_on != self.transport.open_count or not self.transport.is_open:
            self._ensure_configured()
            self.transport.flush_input()
            self.transport.write(self._cmd("C"), operation=operation)
            self._streaming_on = self.transport.open_count
        return self._decode(self.transport.read_line(CR, timeout_s, operation=operation), operation)

    # --- stopping ---------------------------------------------------------------------------------
    def _stop_stream(self) -> None:
        """Esc, then drop the tail of a stream that was in flight."""
        self.transport.write(ESC, operation="stop stream")
        quiet_s = 2 * line_time_s(LINE_BYTES, self.transport.baudrate) + 0.05  # + scheduling slack
        self.transport.discard_input(quiet_s)

    def _stop_stream_quietly(self) -> None:
        try:
            self._stop_stream()
        except Exception as exc:  # noqa: BLE001 - stopping must never mask the real error
            self._warn(f"could not stop the stream: {exc}")

    def safe_state(self) -> None:
        """Stop any stream. Never raises, not even on a dead port."""
        self._stop_stream_quietly()

    def describe(self) -> dict:
        if self.serial_number is None:
            self.connect()
        return {
            **super().describe(),
            "model": self.model,
            "port": self.transport.port,
            "device_id": self.device_id,
            "serial_number": self.serial_number,
            "firmware": self.firmware,
            "rate_hz": self.rate_hz,
            "set_reset": self.set_reset,
            "counts_per_gauss": COUNTS_PER_GAUSS,
            "range_nt": RANGE_COUNTS * NT_PER_COUNT,
            "temperature": None,
        }


def _check_rate(name: str, rate_hz: int) -> None:
    if rate_hz not in RATES_HZ:
        raise OptionError(f"{name}: rate_hz {rate_hz} is not one of {', '.join(map(str, RATES_HZ))}")


def _half_sum_nt(reset, set_, reset_sign: int = 1) -> tuple[float, float, float]:
    """(set + reset_sign * reset) / 2 in nT: the bridge offset (+1) or the offset-free field (-1)."""
    return tuple((s + reset_sign * r) / 2 * NT_PER_COUNT for s, r in zip(set_, reset, strict=True))


def _saturated(counts) -> frozenset[str]:
    return frozenset({"saturated"}) if any(abs(c) >= RANGE_COUNTS for c in counts) else frozenset()


# --- registration -----------------------------------------------------------------------------------
class SerialMagOptions(registry.Options):
    rate_hz: float = 20
    set_reset: bool = True

    @field_validator("rate_hz")
    @classmethod
    def _a_rate_of_the_device(cls, value: float) -> float:
        if value not in RATES_HZ:
            raise ValueError(f"serialmag runs at one of {', '.join(f'{r:g}' for r in RATES_HZ)} Hz")
        return value


def _build(link: registry.SerialLink, options: SerialMagOptions, *, name: str, clock: Clock,
           set_reset: bool = True) -> SerialMagnetometer:
    pulse = set_reset and options.set_reset
    return SerialMagnetometer.from_port(link.port, name=name, clock=clock, baudrate=link.baudrate,
                                        timeout_s=link.timeout_s, rate_hz=int(options.rate_hz),
                                        set_reset="pulse" if pulse else "off")


def _sample_time_s(options: SerialMagOptions, set_reset_pair: bool) -> float:
    return 1.0 / options.rate_hz


registry.register(registry.DeviceSpec(
    role="magnetometer", type="serialmag", options=SerialMagOptions, transports=("serial",), build=_build,
    simulator="drivers.sim.serialmag:simulate", has_temperature=False, sample_time=_sample_time_s,
    rates_hz=RATES_HZ))
