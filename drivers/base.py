"""The vocabulary every driver shares: readings with units and timestamps, and the Device base class.

Every device: connect(), close(), describe(), read(), safe_state().
Movers (coils, turntable, chamber) add set(target) and wait_settled(timeout_s).
Limits are checked before anything is written (raise drivers.errors.LimitError).
"""

from __future__ import annotations

import logging
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


def make_all_safe(devices: Iterable[Device]) -> list[str]:
    """safe_state() on every device, each on its own: one failure must not leave the others unsafe.
    Returns the names of the devices that failed to go safe (each failure is logged)."""
    log = logging.getLogger("magrig.safety")
    failed = []
    for dev in devices:
        name = getattr(dev, "name", type(dev).__name__)
        try:
            dev.safe_state()
        except Exception as exc:
            failed.append(name)
            log.error("%s: safe_state failed: %s", name, exc, extra={"device": name})
    return failed
