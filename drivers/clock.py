"""Injected clocks: everything that waits goes through one, so campaigns can run on simulated time."""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float:
        """Seconds since the epoch (simulated or real)."""

    def sleep(self, seconds: float) -> None:
        """Wait; a simulated clock just advances."""


class RealClock:
    """Wall time."""

    simulated = False

    def now(self) -> float:
        return time.time()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class SimClock:
    """Simulated time: `sleep` advances it at once. Thread-safe, shared by the world and all simulators."""

    simulated = True

    def __init__(self, start: float = 1_767_225_600.0):  # 2026-01-01T00:00:00Z
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        # No lock: reading one attribute is atomic, and only the read-modify-writes below need it (every
        # simulated transfer asks the time, some 2000 times a sample on a 64-DUT station).
        return self._t

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            with self._lock:
                self._t += seconds

    def advance_to(self, t: float) -> None:
        with self._lock:
            self._t = max(self._t, t)
