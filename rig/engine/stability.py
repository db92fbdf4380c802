"""Thermal stability detector: a small pure state machine fed (t, temp_c) samples.

The engine judges stability on the DUT's own temperature sensor, not on the chamber air: the DUT lags
the air by many minutes, and it is the DUT's temperature that enters the calibration model. A DUT's place
in the chamber may be warmer or colder than the air the controller holds (hardware-notes §9.5: +-0.5 degC,
up to 2 degC in a worse corner), so each DUT is judged against where it settles itself, not only against
the set point.

A DUT is still when, over the last `dwell_s` seconds, its temperature drifts slower than
`max_rate_c_per_min` (least-squares slope) and every sample lies within `band_c` of their mean (no step,
no excursion), the samples spanning at least `dwell_s`. It is stable when it is still and
- once three dwells of it are known: it has settled at its own asymptote. A first-order approach moves by a
  constant factor q from one dwell to the next, so the means m1, m2, m3 of the last three dwells give the
  level it tends to, m3 + (m3 - m2) q / (1 - q) with q = (m3 - m2) / (m2 - m1) (Aitken's extrapolation;
  without a steady approach, m3 and the last move); what is left of its approach must be within `band_c`
  and that level within `max_offset_c` of the set point;
- before that (a DUT found settled at once, a retake): every sample of the dwell lies within `band_c` of
  the set point.
A slow DUT still on its way is therefore not taken for a settled one, however slowly it moves. One settled
further than `max_offset_c` from the set point, for another dwell (and the stuck-sensor watch's ten
minutes), is a fault ("offset": its place or its
sensor is not where the plan needs it). A hard `max_wait_s` from the first sample ends the wait as
"timeout" (the engine turns both into a hold). `level_c` is where the DUT settles (the asymptote once three
dwells show it, else the last dwell's mean).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from rig.engine.frozen import MIN_FROZEN_S

APPROACHING = "approaching"
STABLE = "stable"
TIMEOUT = "timeout"
OFFSET = "offset"  # settled, but too far from the set point

# a level beyond max_offset_c held this many dwells more, and no shorter than the stuck-sensor watch needs
# (rig/engine/frozen.py: a reading that never moves is a stuck sensor, not a place), is a fault
OFFSET_DWELLS = 1
NOISE_SHARE = 0.02  # dwell means closer than this share of band_c are one level (noise, quantisation)


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


def asymptote(samples: list[tuple[float, float]], dwell_s: float, noise_c: float
              ) -> tuple[float, float] | None:
    """(the level a first-order approach tends to, what is left of the approach) from the means of the
    last three dwells (module docstring); None before three dwells."""
    t_end = samples[-1][0]
    if t_end - samples[0][0] < 3 * dwell_s:
        return None
    means = []
    for k in (3, 2, 1):
        window = [y for t, y in samples if t_end - k * dwell_s < t <= t_end - (k - 1) * dwell_s]
        if not window:
            return None
        means.append(sum(window) / len(window))
    m1, m2, m3 = means
    d1, d2 = m2 - m1, m3 - m2
    if d1 * d2 <= 0 or abs(d2) >= abs(d1) or max(abs(d1), abs(d2)) <= noise_c:
        return m3, abs(d2)  # no steady approach (settled, noise): what is left is no more than its last move
    q = d2 / d1
    left = d2 * q / (1.0 - q)
    return m3 + left, abs(left)


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
        self.level_c: float | None = None  # where the DUT is settling
        self._history: deque[tuple[float, float]] = deque()  # the last three dwells and one sample
        self._last_t: float | None = None
        self._offset_since: float | None = None  # when it was first found settled beyond max_offset_c

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
        self._history.append((t, temp_c))
        while len(self._history) > 1 and self._history[1][0] <= t - 3 * c.dwell_s:
            self._history.popleft()
        history = list(self._history)
        first = max((i for i, (ti, _) in enumerate(history) if ti <= t - c.dwell_s), default=0)
        window = history[first:]  # the last dwell, from the sample at its boundary
        self.rate_c_per_min = slope_per_s(window) * 60.0
        self.in_band_s, self.level_c = steady_span_s(window, c.band_c)
        still = self.in_band_s >= c.dwell_s and abs(self.rate_c_per_min) <= c.max_rate_c_per_min
        known = asymptote(history, c.dwell_s, NOISE_SHARE * c.band_c)
        settled = known is not None and known[1] <= c.band_c
        if settled:
            self.level_c = known[0]
        near = abs(self.level_c - self.target_c) <= c.max_offset_c
        far = still and settled and not near
        if not far:
            self._offset_since = None
        elif self._offset_since is None:
            self._offset_since = t
        at_target = known is None and all(abs(y - self.target_c) <= c.band_c for _, y in window)
        if still and (at_target or (settled and near)):
            self.state = STABLE
        elif far and t - self._offset_since >= max(OFFSET_DWELLS * c.dwell_s, MIN_FROZEN_S):
            self.state = OFFSET
        elif self.elapsed_s >= c.max_wait_s:
            self.state = TIMEOUT
        else:
            self.state = APPROACHING
        return self.state
