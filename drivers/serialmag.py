"""Honeywell HMR2300 serial AMR magnetometer (ASCII protocol, RS-232 or RS-485).

Constructors (what the station YAML maps onto)::

    SerialMagnetometer(transport, *, name, clock=None, device_id=0, rate_hz=20, set_reset="pulse")
    SerialMagnetometer.from_port(port, *, name, clock=None, baudrate=9600, timeout_s=0.5, tries=3,
                                 device_id=0, rate_hz=20, set_reset="pulse")
    SerialMagnetometer.on_line(line, *, name, device_id, clock=None, timeout_s=0.5, tries=3,
                               rate_hz=20, set_reset="pulse")     # several devices on one RS-485 line

- transport: a drivers.transports.serial.SerialTransport (it owns timeouts, retries and reconnects);
  `line`: a drivers.transports.serial.SerialLine shared by every HMR2300 on the cable.
- baudrate: the rate the device is at when it powers up, 9600 or 19200 (the only two it has).
- device_id: the `dd` of the commands, 0..98 (99 addresses every device on the line).
- rate_hz: continuous-mode rate, one of RATES_HZ that an ASCII stream can carry (see BAUD below).
- set_reset: "pulse": auto S/R off; every read() does a RESET and a SET pulse with a poll after each and
  reports H = (H_set - H_reset)/2 and the bridge offset (H_set + H_reset)/2 in FieldSample.offset_nt.
  "auto": the device's own auto S/R (`TN`), plain polls, offset not reported. "off": no pulses at all
  (`TF`, one SET at connect so the polarity is known).

The wire protocol (commands, replies, the sample line, the baud arithmetic): drivers/serialmag_protocol.py.
"""

from __future__ import annotations

import logging

from pydantic import Field, field_validator

from drivers import registry
from drivers.base import Device, FieldSample, reading_description
from drivers.clock import Clock
from drivers.errors import DeviceError, DeviceTimeout, OptionError, ProtocolError
from drivers.serialmag_protocol import (
    ASCII_ON,
    AUTO_SET_RESET_REPLY,
    BAUD_CODE,
    BAUD_RATES,
    BAUD_SWITCH_S,
    BITS_PER_LINE,
    BROADCAST_ID,
    COUNTS_PER_GAUSS,
    CR,
    ESC,
    LINE_BYTES,
    NT_PER_COUNT,
    NT_PER_GAUSS,
    OK,
    PULSE_COMMAND,
    PULSE_REPLY,
    RANGE_COUNTS,
    RATES_HZ,
    SET_RESET_MODES,
    WRONG_ENTRY,
    baud_needed,
    command,
    counts_to_nt,
    half_sum_nt,
    parse_sample_line,
    saturated,
)
from drivers.transports.serial import SerialLine, SerialTransport, line_time_s

log = logging.getLogger("magrig.drivers.serialmag")

class SerialMagnetometer(Device):
    kind = "magnetometer"
    model = "Honeywell HMR2300 serial AMR magnetometer"

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
        if not 0 <= device_id < BROADCAST_ID:
            raise OptionError(f"{name}: device_id {device_id} is not in 0..98 (99 addresses every device)")
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
        """Build the transport and the driver from a port path or pyserial URL (a port of its own)."""
        _check_baud(name, baudrate)
        transport = SerialTransport(
            port, name=name, clock=clock, baudrate=baudrate, timeout_s=timeout_s, tries=tries
        )
        return cls(transport, name=name, clock=clock, **kwargs)

    @classmethod
    def on_line(
        cls,
        line: SerialLine,
        *,
        name: str,
        device_id: int,
        clock: Clock | None = None,
        timeout_s: float = 0.5,
        tries: int = 3,
        **kwargs,
    ) -> SerialMagnetometer:
        """One of several HMR2300s on a shared RS-485 line, addressed by `device_id`."""
        _check_baud(name, line.baudrate)
        transport = line.transport(device_id, name=name, clock=clock, timeout_s=timeout_s, tries=tries)
        return cls(transport, name=name, clock=clock, device_id=device_id, **kwargs)

    # --- link and setup ---------------------------------------------------------------------------
    def connect(self) -> None:
        with self.transport.session():
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
        unplugged may have power-cycled to its defaults (baud rate included)."""
        with self.transport.session():
            self.transport.open()
            if self.transport.open_count == self._configured_open_count:
                return
            self._stop_stream()
            self._find_device()
            self._raise_baud_for(self.rate_hz)
            auto = self.set_reset == "auto"
            self._setting("TN" if auto else "TF", AUTO_SET_RESET_REPLY[auto], "set auto set/reset")
            self._setting(f"R={self.rate_hz}", OK, "set rate")
            if self.set_reset != "auto":
                self.pulse(1)
            self._configured_open_count = self.transport.open_count

    def _find_device(self) -> None:
        """`*ddA` -> ASCII_ON: ASCII output, and proof that we talk at the device's baud rate. A device
        that does not answer at the line's rate is tried once at the other one (it may have kept 19200
        from an earlier run, or power-cycled back to its start-up rate)."""
        first = self.transport.baudrate
        try:
            self._reply_to("A", ASCII_ON, "set ASCII output")
            return
        except (DeviceTimeout, ProtocolError) as exc:
            other = next(b for b in BAUD_RATES if b != first)
            self._warn(f"no answer at {first} baud ({exc.detail}); trying {other}")
        self.transport.set_baudrate(other)
        try:
            self._reply_to("A", ASCII_ON, "set ASCII output")
        except DeviceError:
            self.transport.set_baudrate(first)
            raise

    def _raise_baud_for(self, rate_hz: int) -> None:
        """Switch every device on the line to 19200 baud if `rate_hz` needs it (never down: another
        device on a shared line may need the faster rate)."""
        needed = baud_needed(rate_hz)
        if needed is None or needed <= self.transport.baudrate:
            return
        operation = f"switch line to {needed} baud"
        self.transport.write(command(BROADCAST_ID, "WE"), operation=operation)
        switch = command(BROADCAST_ID, f"!BR={BAUD_CODE[needed]}")
        self.transport.write(switch, operation=operation)
        # Let the command leave at the old rate and the devices act on it before the port changes (the
        # notes give ~2 ms per reply, not how long the switch takes); anything sent back is dropped.
        self.transport.discard_input(line_time_s(len(switch), self.transport.baudrate) + BAUD_SWITCH_S)
        self.transport.set_baudrate(needed, operation=operation)
        self._reply_to("A", ASCII_ON, f"{operation} (check)")  # the device answers at the new rate

    def _expect(self, line: bytes, wanted: bytes, sent: bytes, operation: str) -> bytes:
        if line == wanted:
            return line
        if line.endswith(WRONG_ENTRY):
            raise ProtocolError(
                self.name, operation, f"device answered Re-enter (command refused) to {sent!r}"
            )
        raise ProtocolError(self.name, operation, f"expected {wanted!r} after {sent!r}, got {line!r}")

    def _reply_to(self, body: str, wanted: bytes, operation: str) -> None:
        """One command whose datasheet reply is `wanted`, retried."""
        cmd = self._cmd(body)
        self.transport.query(
            cmd, operation=operation, parse=lambda line: self._expect(line, wanted, cmd, operation)
        )

    def _setting(self, body: str, wanted: bytes, operation: str) -> None:
        """Write-enable, then one setting command; the pair is retried together."""
        we, cmd = self._cmd("WE"), self._cmd(body)

        def once() -> None:
            self._expect(self.transport.exchange(we, operation=operation), OK, we, operation)
            self._expect(self.transport.exchange(cmd, operation=operation), wanted, cmd, operation)

        with self.transport.session():
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
        with self.transport.session():
            self._ensure_configured()
            self._raise_baud_for(rate_hz)
            self._setting(f"R={rate_hz}", OK, "set rate")
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
        with self.transport.session():
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
        with self.transport.session():  # the RESET/SET pair must not interleave with another device
            return self._read()

    def _read(self) -> FieldSample:
        for _ in range(self.transport.tries):
            self._ensure_configured()
            opened = self.transport.open_count
            try:
                if self.set_reset != "pulse":
                    return self._sample(self.poll_counts(), None)
                reset, set_ = self._pulsed_pair()
            except DeviceError as exc:
                if self.transport.open_count == opened:
                    raise
                # The port was reopened under us: the device may be at other settings (baud rate
                # included), so the commands failed for that; reconfigure and repeat.
                self._warn(f"port reopened during a read ({exc.detail}); reconfiguring")
                continue
            if self.transport.open_count != opened:  # reconnected mid-sequence: polarity unknown
                self._warn("reconnected during a SET/RESET read; repeating it")
                continue
            return FieldSample(
                t=self.clock.now(), field_nt=half_sum_nt(reset, set_, -1), counts=set_,
                offset_nt=half_sum_nt(reset, set_),
                flags=saturated(set_) | saturated(reset),
            )
        raise DeviceError(self.name, "read", "the port kept reconnecting during the read")

    def _sample(self, counts, offset_nt) -> FieldSample:
        """A sample from one reading; a known bridge offset is subtracted."""
        field = counts_to_nt(counts)
        if offset_nt is not None:
            field = tuple(f - o for f, o in zip(field, offset_nt, strict=True))
        return FieldSample(
            t=self.clock.now(), field_nt=field, counts=counts, offset_nt=offset_nt, flags=saturated(counts)
        )

    def read_stream(self, n: int) -> list[FieldSample]:
        """`n` samples from continuous mode, then the stream is stopped. In "pulse" mode the bridge
        offset is measured once with a RESET/SET pair first and subtracted from every sample. The line
        is this device's until the stream has stopped."""
        with self.transport.session():
            return self._read_stream(n)

    def _read_stream(self, n: int) -> list[FieldSample]:
        operation = "stream samples"
        self._ensure_configured()
        offset_nt = half_sum_nt(*self._pulsed_pair()) if self.set_reset == "pulse" else None
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
            "baudrate": self.transport.baudrate,
            "shared_line": self.transport.shared,
            "device_id": self.device_id,
            "serial_number": self.serial_number,
            "firmware": self.firmware,
            "rate_hz": self.rate_hz,
            "set_reset": self.set_reset,
            "counts_per_gauss": COUNTS_PER_GAUSS,
            "range_nt": RANGE_COUNTS * NT_PER_COUNT,
            "temperature": None,
            "reading": self.reading(),
        }

    def reading(self) -> dict:
        """How read() makes h (drivers/base.py reading_description)."""
        conversion = (f"H_nT = counts / {COUNTS_PER_GAUSS} * {NT_PER_GAUSS:.0f} per axis (the signed counts "
                      "of the ASCII sample line X, Y, Z)")
        if self.set_reset == "pulse":
            return reading_description(
                "set_reset_pair", "h = (H_SET - H_RESET) / 2: a poll after a RESET pulse and one after a SET "
                "pulse; the bridge offset cancels", conversion)
        if self.set_reset == "off":
            return reading_description(
                "set_only", "h = H of one poll; one SET pulse at connect and none after: the bridge offset "
                "stays in h (the calibration's offset holds it)", conversion)
        return reading_description(
            "single", "h = H of one poll, with the device's own automatic SET/RESET on (`TN`)", conversion)


def _check_rate(name: str, rate_hz: int) -> None:
    if rate_hz not in RATES_HZ:
        raise OptionError(f"{name}: rate_hz {rate_hz} is not one of {', '.join(map(str, RATES_HZ))}")
    if baud_needed(rate_hz) is None:
        streamable = [r for r in RATES_HZ if baud_needed(r)]
        raise OptionError(
            f"{name}: rate_hz {rate_hz}: a {LINE_BYTES}-byte ASCII sample stream at {rate_hz} Hz needs "
            f"{rate_hz * BITS_PER_LINE} baud, above the device's fastest 19200; "
            f"use one of {', '.join(map(str, streamable))}"
        )


def _check_baud(name: str, baudrate: int) -> None:
    if baudrate not in BAUD_RATES:
        raise OptionError(f"{name}: baudrate {baudrate}: the HMR2300 runs at 9600 or 19200 only")


# --- registration -----------------------------------------------------------------------------------
class SerialMagOptions(registry.Options):
    rate_hz: float = 20
    set_reset: bool = True
    device_id: int = Field(0, ge=0, le=98, description="the `dd` of its commands on a shared RS-485 line")

    @field_validator("rate_hz")
    @classmethod
    def _a_rate_of_the_device(cls, value: float) -> float:
        if value not in RATES_HZ:
            raise ValueError(f"serialmag runs at one of {', '.join(f'{r:g}' for r in RATES_HZ)} Hz")
        return value


def _build(link: registry.SerialLink, options: SerialMagOptions, *, name: str, clock: Clock,
           set_reset: bool = True) -> SerialMagnetometer:
    pulse = set_reset and options.set_reset
    if link.line is not None:  # a line the station shares between several devices (by device id)
        return SerialMagnetometer.on_line(link.line, name=name, device_id=options.device_id, clock=clock,
                                          timeout_s=link.timeout_s, rate_hz=int(options.rate_hz),
                                          set_reset="pulse" if pulse else "off")
    return SerialMagnetometer.from_port(link.port, name=name, clock=clock, baudrate=link.baudrate,
                                        timeout_s=link.timeout_s, rate_hz=int(options.rate_hz),
                                        device_id=options.device_id, set_reset="pulse" if pulse else "off")


def _sample_time_s(options: SerialMagOptions, set_reset_pair: bool) -> float:
    return 1.0 / options.rate_hz


SCAN_NAME = "port scan"  # the name a scan's transports go by (one name for every id it asks)


def quiet(line: SerialLine) -> None:
    """For port scans, before asking each id: Esc, so a stream some device was left in stops."""
    SerialMagnetometer.on_line(line, name=SCAN_NAME, device_id=0, tries=1)._stop_stream()


def identify(line: SerialLine, device_id: int, timeout_s: float) -> dict | None:
    """For port scans: is an HMR2300-style device at `device_id` on this line? `*ddA` (ASCII output; its
    ASCII_ON reply also proves the baud rate), then `*dd#` and `*ddF`. Nothing else is changed. None
    when nothing answers; ProtocolError when something else does."""
    dev = SerialMagnetometer.on_line(line, name=SCAN_NAME, device_id=device_id, timeout_s=timeout_s, tries=1)
    with dev.transport.session():
        try:
            dev._reply_to("A", ASCII_ON, "identify (*ddA)")
        except DeviceTimeout:
            return None
        found = {"model": dev.model, "serial_number": None, "firmware": None}
        for key, body in (("serial_number", "#"), ("firmware", "F")):
            try:
                found[key] = dev._text_query(body, f"identify (*dd{body})")
            except DeviceError:
                pass  # answers the handshake but not this query: still the device, say what is known
        return found


registry.register(registry.DeviceSpec(
    role="magnetometer", type="serialmag", options=SerialMagOptions, transports=("serial",), build=_build,
    simulator="drivers.sim.devices.serialmag:simulate", has_temperature=False, sample_time=_sample_time_s,
    rates_hz=RATES_HZ, probe=registry.SerialProbe(identify, tuple(range(BROADCAST_ID)), BAUD_RATES, quiet),
    manufacturer="Honeywell"))
