"""One simulated device's fault schedule: which operations fail, and when it is unplugged, stuck or in alarm.

    faults = DeviceFaults("chamber", clock, one_in={"no_reply": 100, "exception": 100}, seed=2026,
                          unplug=Window(600, 120), alarm=Window(1800, 300))
    kind = faults.draw()        # once per operation (request, command, transfer): None or the fault
    faults.stuck()              # the temperature reading is frozen now
    temp_c = faults.shown_temperature(true_c)   # what the chip converts: frozen while stuck
    faults.alarm()              # the chamber's alarm register shows an alarm now

The simulators call these from their fault hooks (modbus_server.py, serialmag.py, i2c_bus.py, tmp117.py,
mmc5983ma.py, chamber.py); rig/devices/simulated/bench.py builds one per device from the station's
`transport: {kind: sim, faults: ...}`. Draws come from a generator seeded by the station's `sim.seed` and
the device's name, so the same station and plan inject the same faults in the same operations. (The
serial firmware answers in real time on a pty, so which of its lines a draw lands on may vary.)

Windows are campaign time (the injected clock), counted from when the schedule is made (the bench start).
`fired` counts what was injected, by kind, and `history` says when, so a test can hold the rig's event
log against it.
"""

from __future__ import annotations

import threading
import zlib
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from drivers.clock import Clock

RATE_KINDS = ("no_reply", "exception", "garbled", "nack")  # drawn in this order, at most one per operation


@dataclass(frozen=True)
class Window:
    """From `after_s` for `for_s` seconds (None: to the end)."""

    after_s: float = 0.0
    for_s: float | None = None

    def contains(self, elapsed_s: float) -> bool:
        return elapsed_s >= self.after_s and (self.for_s is None or elapsed_s < self.after_s + self.for_s)


class DeviceFaults:
    def __init__(
        self,
        device: str,
        clock: Clock,
        *,
        one_in: Mapping[str, int] | None = None,
        unplug: Window | None = None,
        stuck: Window | None = None,
        alarm: Window | None = None,
        seed: int = 0,
    ):
        one_in = dict(one_in or {})
        unknown = set(one_in) - set(RATE_KINDS)
        if unknown or any(n < 2 for n in one_in.values()):
            raise ValueError(f"{device}: fault rates {one_in}: kinds are {RATE_KINDS}, each one in N >= 2")
        self.device = device
        self.clock = clock
        self.one_in = {k: one_in[k] for k in RATE_KINDS if k in one_in}
        self.unplug = unplug
        self.stuck_window = stuck
        self.alarm_window = alarm
        self.start_t = clock.now()
        self.rng = np.random.default_rng([seed, zlib.crc32(device.encode())])
        self.fired: Counter[str] = Counter()
        self.history: list[tuple[float, str]] = []  # (clock time, kind) of every injected operation fault
        self.operations = 0
        self._shown_c: float | None = None
        self._lock = threading.Lock()  # simulators answer from their own threads

    def elapsed_s(self) -> float:
        return self.clock.now() - self.start_t

    def draw(self) -> str | None:
        """The fault this operation suffers: "unplug" inside the unplug window, else one of the rate kinds
        with its probability 1/N, else None."""
        with self._lock:
            self.operations += 1
            if self.unplugged():
                return self._fire("unplug")
            for kind, n in self.one_in.items():
                if self.rng.random() < 1.0 / n:
                    return self._fire(kind)
            return None

    def _fire(self, kind: str) -> str:
        self.fired[kind] += 1
        self.history.append((self.clock.now(), kind))
        return kind

    def unplugged(self) -> bool:
        return self.unplug is not None and self.unplug.contains(self.elapsed_s())

    def stuck(self) -> bool:
        return self.stuck_window is not None and self.stuck_window.contains(self.elapsed_s())

    def alarm(self) -> bool:
        return self.alarm_window is not None and self.alarm_window.contains(self.elapsed_s())

    def shown_temperature(self, true_c: float) -> float:
        """The temperature a chip converts: `true_c`, or while stuck the last one it showed before."""
        with self._lock:
            if self.stuck() and self._shown_c is not None:
                self.fired["stuck_temperature"] += 1
                return self._shown_c
            self._shown_c = true_c
            return true_c
