"""The vocabulary every driver shares: readings with units and timestamps, and the Device base class.

Every device: connect(), close(), describe(), read(), safe_state().
Movers (coils, turntable, chamber) add set(target) and wait_settled(timeout_s).
Limits are checked before anything is written (raise drivers.errors.LimitError).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TypeVar

from drivers.clock import Clock, RealClock


@dataclass(frozen=True)
class FieldSample:
    """One magnetometer reading, in the sensor's own (uncalibrated) axes.

    field_nt: raw reading converted to nT with the datasheet's nominal scale (this is `h` of the models).
    counts:   the raw integer codes as read from the device (after any register decoding).
    offset_nt: bridge offset measured by a SET/RESET pair, when the driver did one.
    flags: e.g. {"overflow"}, {"saturated"}; a flagged sample is recorded but not fitted.
    """

    t: float
    field_nt: tuple[float, float, float]
    counts: tuple[int, int, int] | None = None
    temp_c: float | None = None
    offset_nt: tuple[float, float, float] | None = None
    flags: frozenset[str] = field(default_factory=frozenset)


def reading_description(mode: str, mode_text: str, conversion: str | None, raw_unit: str = "nT") -> dict:
    """What a magnetometer's describe() states of how one read() makes h (recorded in the session, and
    from there in every calibration's `reading:`): `mode` set_reset_pair | set_only | single, what that
    does in words, the unit of h and the conversion from the device's output codes to it."""
    return {"mode": mode, "mode_text": mode_text, "raw_unit": raw_unit, "conversion": conversion}


@dataclass(frozen=True)
class TempSample:
    t: float
    temp_c: float
    flags: frozenset[str] = field(default_factory=frozenset)


class Device:
    """Base class. `name` is the station's name for the device; it appears in every error message."""

    kind = "device"

    def __init__(self, name: str, clock: Clock | None = None):
        self.name = name
        self.clock = clock or RealClock()

    def connect(self) -> None:
        """Open the link and check the device's identity."""

    def close(self) -> None:
        """Release the link; never raises."""

    def describe(self) -> dict:
        """Model, id, firmware, ranges: recorded in the session as a device snapshot."""
        return {"name": self.name, "kind": self.kind}

    def read(self):
        raise NotImplementedError

    def safe_state(self) -> None:
        """Put the hardware in a safe state. Must be safe to call at any time, repeatedly."""

    def __enter__(self):
        self.connect()
        return self

    def __exit__(self, *exc):
        try:
            self.safe_state()
        finally:
            self.close()


R = TypeVar("R")


def wait_until(clock: Clock, read: Callable[[], R], settled: Callable[[R], bool], *, timeout_s: float,
               poll_s: float, timed_out: Callable[[R], Exception]) -> R:
    """The movers' wait_settled loop: read(), return the reading once settled(reading) holds, else sleep
    poll_s on the injected clock; after timeout_s raise timed_out(last reading). `settled` may raise
    (a fault will not settle)."""
    deadline = clock.now() + timeout_s
    while True:
        reading = read()
        if settled(reading):
            return reading
        left = deadline - clock.now()
        if left <= 0:
            raise timed_out(reading)
        clock.sleep(min(poll_s, left))  # the last look at the deadline itself, not a poll past it


def serial_line(dev: object) -> object | None:
    """The serial line (drivers/transports/serial.py SerialLine) a device talks over, None for the rest."""
    return getattr(getattr(dev, "transport", None), "line", None)


def each_by_line(devices: list[Device], act: Callable[[Device], object], *,
                 stop_at_error: bool = False) -> dict[int, Exception]:
    """act(dev) for every device, the devices of each serial line in a thread of that line while the
    others go in this one: a line's waits (the quiet after an Esc) are real time, and lines are separate
    cables. Within a line, and among the others, the devices keep their order. {index in `devices`: the
    Exception its act raised}; with `stop_at_error` a line (or the rest) stops at its first. Every thread
    has ended when this returns, or when it raises (Ctrl-C here)."""
    groups: dict[int, list[int]] = {}
    for k, dev in enumerate(devices):
        line = serial_line(dev)
        groups.setdefault(0 if line is None else id(line), []).append(k)
    errors: dict[int, Exception] = {}

    def run(group: list[int]) -> None:
        for k in group:
            try:
                act(devices[k])
            except Exception as exc:
                errors[k] = exc
                if stop_at_error:
                    return

    threads = [threading.Thread(target=run, args=(group,), name="serial line", daemon=True)
               for key, group in groups.items() if key != 0]
    for thread in threads:
        thread.start()
    try:
        run(groups.get(0, []))
    finally:
        for thread in threads:
            thread.join()
    return errors


def make_all_safe(devices: Iterable[Device]) -> list[str]:
    """safe_state() on every device, each on its own: one failure must not leave the others unsafe (the
    serial lines each in a thread of their own, each_by_line). Returns the names of the devices that failed
    to go safe, in the devices' order (each failure is logged)."""
    devices = list(devices)
    errors = each_by_line(devices, lambda dev: dev.safe_state())
    log = logging.getLogger("magrig.safety")
    failed = []
    for k in sorted(errors):
        name = getattr(devices[k], "name", type(devices[k]).__name__)
        failed.append(name)
        log.error("%s: safe_state failed: %s", name, errors[k], extra={"device": name})
    return failed
