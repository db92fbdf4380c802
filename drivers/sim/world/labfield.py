"""The lab's field beyond a uniform, steady ambient: its gradient over the coil set and its steps.

- Gradient G (3x3, nT/m, G[i, j] = dB_i/dx_j): the ambient at a sensor's true position r (m, from the
  coil centre) is ambient + G r (hardware-notes §9.4: a clean site < 5 nT/m, beside a steel chamber
  15-20 uT/m).
- Steps: something moves in the building (a door, a car, a lift; §9.4) at Poisson-distributed times
  (mean interval mean_interval_h), each step an isotropic normal vector of RMS size size_nt, and the
  field stays stepped. The steps come from their own generator in their own order, so where they fall
  depends on the seed alone, never on when the world is asked; they are drawn lazily as the clock
  reaches them (time may jump by hours).
"""

from __future__ import annotations

import math

import numpy as np


class AmbientSteps:
    def __init__(self, rng: np.random.Generator, t0: float, *, mean_interval_h: float, size_nt: float):
        self.rng = rng
        self.mean_interval_s = mean_interval_h * 3600.0
        self.size_nt = size_nt
        self.times_s: list[float] = []  # when each step happened
        self.steps_nt: list[np.ndarray] = []  # and by how much
        self.total_nt = np.zeros(3)  # the sum of the steps up to next_s
        self.next_s = t0 + rng.exponential(self.mean_interval_s)

    def offset_nt(self, t: float) -> np.ndarray:
        """The sum of every step up to time t."""
        while self.next_s <= t:
            self.times_s.append(self.next_s)
            self.steps_nt.append(self.rng.normal(0.0, self.size_nt / math.sqrt(3.0), 3))
            self.total_nt = self.total_nt + self.steps_nt[-1]
            self.next_s += self.rng.exponential(self.mean_interval_s)
        return self.total_nt.copy()


class LabField:
    """Gradient and steps together: the ambient's departure at a position and time (lab frame, nT)."""

    def __init__(self, gradient_nt_per_m=None, steps: AmbientSteps | None = None):
        self.gradient = None if gradient_nt_per_m is None else np.asarray(gradient_nt_per_m, float)
        self.steps = steps

    def field_nt(self, position_m: np.ndarray, t: float) -> np.ndarray:
        out = np.zeros(3)
        if self.gradient is not None:
            out = out + self.gradient @ position_m
        if self.steps is not None:
            out = out + self.steps.offset_nt(t)
        return out
