"""Thermal stability detector: a small pure state machine fed (t, temp_c) samples.

The engine judges stability on the DUT's own temperature sensor, not on the chamber air: the DUT lags
the air by many minutes, and it is the DUT's temperature that enters the calibration model.

Stable means all three at once:
- every sample of the last `dwell_s` seconds lies within `band_c` of the target,
- those in-band samples span at least `dwell_s` (the DUT stayed there, it did not just pass through),
- the temperature drift over that window (least-squares slope) is below `max_rate_c_per_min`.
A hard `max_wait_s` from the first sample ends the wait as "timeout" (the engine turns it into a hold).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

APPROACHING = "approaching"
STABLE = "stable"
TIMEOUT = "timeout"


@dataclass(frozen=True)
class StabilityCriteria:
    band_c: float = 0.5
    max_rate_c_per_min: float = 0.1
    dwell_s: float = 300.0
    max_wait_s: float = 4 * 3600.0


def criteria_of(stability) -> StabilityCriteria:
    """The criteria of a plan's `stability:` (rig.config.plan.Stability)."""
    return StabilityCriteria(band_c=stability.band_c, max_rate_c_per_min=stability.rate_c_per_min,
                          dwell_s=stability.dwell_s, max_wait_s=stability.max_wait_s)


def slope_per_s(samples: list[tuple[float, float]]) -> float:
    """Least-squares slope of temp against time; 0 for fewer than two distinct times."""
    n = len(samples)
    if n < 2:
        return 0.0
    t_mean = sum(t for t, _ in samples) / n
    y_mean = sum(y for _, y in samples) / n
    sxx = sum((t - t_mean) ** 2 for t, _ in samples)
    if sxx == 0:
        return 0.0
    return sum((t - t_mean) * (y - y_mean) for t, y in samples) / sxx


class StabilityDetector:
    """Feed samples with add(); read `state`, `rate_c_per_min`, `in_band_s` for display and decisions."""

    def __init__(self, target_c: float, criteria: StabilityCriteria):
        self.target_c = target_c
        self.criteria = criteria
        self.state = APPROACHING
        self.start_t: float | None = None
        self.last_temp_c: float | None = None
        self.rate_c_per_min = 0.0
        self._window: deque[tuple[float, float]] = deque()
        self._in_band_since: float | None = None
        self._last_t: float | None = None

    @property
    def in_band_s(self) -> float:
        """How long the temperature has stayed in band so far (0 when out of band)."""
        if self._in_band_since is None or self._last_t is None:
            return 0.0
        return self._last_t - self._in_band_since

    @property
    def elapsed_s(self) -> float:
        if self.start_t is None or self._last_t is None:
            return 0.0
        return self._last_t - self.start_t

    def add(self, t: float, temp_c: float) -> str:
        """Take one sample (times must not go backwards) and return the new state."""
        c = self.criteria
        if self.start_t is None:
            self.start_t = t
        self._last_t = t
        self.last_temp_c = temp_c
        self._window.append((t, temp_c))
        while self._window and self._window[0][0] < t - c.dwell_s:
            self._window.popleft()
        self.rate_c_per_min = slope_per_s(list(self._window)) * 60.0

        if abs(temp_c - self.target_c) <= c.band_c:
            if self._in_band_since is None:
                self._in_band_since = t
        else:
            self._in_band_since = None

        if self.in_band_s >= c.dwell_s and abs(self.rate_c_per_min) <= c.max_rate_c_per_min:
            self.state = STABLE
        elif self.elapsed_s >= c.max_wait_s:
            self.state = TIMEOUT
        else:
            self.state = APPROACHING
        return self.state
