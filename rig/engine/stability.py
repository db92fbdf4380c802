"""Thermal stability detector: a small pure state machine fed (t, temp_c) samples.

The engine judges stability on the DUT's own temperature sensor, not on the chamber air: the DUT lags
the air by many minutes, and it is the DUT's temperature that enters the calibration model. A DUT's place
in the chamber may be warmer or colder than the air the controller holds (hardware-notes §9.5: +-0.5 degC,
up to 2 degC in a worse corner), so each DUT is judged against where it settles itself, not against the
set point.

Stable means all of these at once:
- the temperature drift over the last `dwell_s` seconds (least-squares slope) is below `max_rate_c_per_min`,
- every sample of those `dwell_s` seconds lies within `band_c` of their mean (the DUT holds still at its own
  level: no step, no excursion), and the samples span at least `dwell_s`,
- that level is within `max_offset_c` of the set point.
A DUT that holds still further from the set point than `max_offset_c`, for OFFSET_DWELLS dwells without
moving by more than `band_c`, is a fault ("offset": its place or its sensor is not where the plan needs
it); one that is still approaching is not. A hard `max_wait_s` from the first sample ends the wait as
"timeout" (the engine turns both into a hold). `level_c` is where the DUT settled (the dwell's mean).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

APPROACHING = "approaching"
STABLE = "stable"
TIMEOUT = "timeout"
OFFSET = "offset"  # settled, but too far from the set point

OFFSET_DWELLS = 4  # a level beyond max_offset_c held this many dwells is a fault, not a slow approach


@dataclass(frozen=True)
class StabilityCriteria:
    band_c: float = 0.5
    max_rate_c_per_min: float = 0.1
    dwell_s: float = 300.0
    max_wait_s: float = 4 * 3600.0
    max_offset_c: float = 2.0


def criteria_of(stability) -> StabilityCriteria:
    """The criteria of a plan's `stability:` (rig.config.plan.Stability)."""
    return StabilityCriteria(band_c=stability.band_c, max_rate_c_per_min=stability.rate_c_per_min,
                             dwell_s=stability.dwell_s, max_wait_s=stability.max_wait_s,
                             max_offset_c=stability.max_offset_c)


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


def steady_span_s(samples: list[tuple[float, float]], band_c: float) -> tuple[float, float]:
    """(span, mean) of the longest run of latest samples that all lie within band_c of their own mean."""
    lo = hi = total = 0.0
    span, mean = 0.0, samples[-1][1]
    for k, (t, y) in enumerate(reversed(samples)):
        lo, hi, total = (y, y, y) if k == 0 else (min(lo, y), max(hi, y), total + y)
        m = total / (k + 1)
        if hi - m > band_c or m - lo > band_c:
            break
        span, mean = samples[-1][0] - t, m
    return span, mean


class StabilityDetector:
    """Feed samples with add(); read `state`, `rate_c_per_min`, `in_band_s`, `level_c` for display and
    decisions."""

    def __init__(self, target_c: float, criteria: StabilityCriteria):
        self.target_c = target_c
        self.criteria = criteria
        self.state = APPROACHING
        self.start_t: float | None = None
        self.last_temp_c: float | None = None
        self.rate_c_per_min = 0.0
        self.in_band_s = 0.0  # how long the latest samples have held still within band_c of their mean
        self.level_c: float | None = None  # their mean: where the DUT is settling
        self._window: deque[tuple[float, float]] = deque()
        self._last_t: float | None = None
        self._offset_since: tuple[float, float] | None = None  # (t, level) once settled beyond max_offset_c

    @property
    def elapsed_s(self) -> float:
        if self.start_t is None or self._last_t is None:
            return 0.0
        return self._last_t - self.start_t

    @property
    def offset_c(self) -> float | None:
        """How far from the set point the DUT settles (None before any sample)."""
        return None if self.level_c is None else self.level_c - self.target_c

    def add(self, t: float, temp_c: float) -> str:
        """Take one sample (times must not go backwards) and return the new state."""
        c = self.criteria
        if self.start_t is None:
            self.start_t = t
        self._last_t = t
        self.last_temp_c = temp_c
        self._window.append((t, temp_c))
        while len(self._window) > 1 and self._window[1][0] <= t - c.dwell_s:  # keep one at the boundary
            self._window.popleft()
        window = list(self._window)
        self.rate_c_per_min = slope_per_s(window) * 60.0
        self.in_band_s, self.level_c = steady_span_s(window, c.band_c)
        still = self.in_band_s >= c.dwell_s and abs(self.rate_c_per_min) <= c.max_rate_c_per_min
        near = abs(self.level_c - self.target_c) <= c.max_offset_c
        if still and not near:
            if self._offset_since is None or abs(self.level_c - self._offset_since[1]) > c.band_c:
                self._offset_since = (t, self.level_c)
        else:
            self._offset_since = None
        if still and near:
            self.state = STABLE
        elif self._offset_since is not None and t - self._offset_since[0] >= OFFSET_DWELLS * c.dwell_s:
            self.state = OFFSET
        elif self.elapsed_s >= c.max_wait_s:
            self.state = TIMEOUT
        else:
            self.state = APPROACHING
        return self.state
