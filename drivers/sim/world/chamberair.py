"""The simulated chamber's air as a real chamber moves it, and the field its heater and compressor add.

Air. Without an overshoot (the default) the air moves straight to its set point at the ramp rate, as an
ideal chamber would. With `overshoot_c` the controller's closed-loop set point moves at the ramp rate and
the air follows it as an under-damped second-order system (damping DAMPING), never faster than the
chamber's `max_rate_c_per_min` (its heater and compressor have a power limit, whatever ramp it is told):
it lags a ramp by rate / omega and overshoots once the ramp ends, by `overshoot_c` after a change made at
the full rate and in proportion after a slower one (hardware-notes §9.5: overshoot grows with ramp speed).

Heater and compressor (hardware-notes §9.5). The compressor runs while the air is below room temperature
or on its way down (its set point more than COOL_BAND_C below it). The heaters trim with a
time-proportioning duty cycle of HEATER_CYCLE_S; their duty is the heat the air needs: its losses to the
room (HOLD_SPAN_C of excess temperature takes full power), its ramp (the full rate takes full power) and,
while the compressor runs, the compressor's cooling (COMPRESSOR_LOAD). So a fast heat-up keeps the
heater on, a fast cool-down keeps it off with the compressor on, a hold above room switches the heater
alone, and a hold or a slow ramp below room runs both. Each adds its field (lab frame, nT, uniform over
the coil set: their sources sit metres away) while on. The switching follows the air's demand; it is
not the cause of the air's motion (the air model above is the controlled result). Room temperature is
the air's at the start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DAMPING = 0.5  # of the air's approach to the closed-loop set point
SECOND_ORDER_STEP_S = 0.5  # integration step: the overshoot comes out within ~1 % of overshoot_c
HEATER_CYCLE_S = 20.0  # time-proportioning period of the heater output ("tens of seconds")
HOLD_SPAN_C = 150.0  # air this far above room needs the heater's full power to hold (losses, [A])
COMPRESSOR_LOAD = 0.6  # the compressor's cooling, as a share of the heater's full power ([A])
ROOM_BAND_C = 1.0  # below room by more than this, the compressor runs
COOL_BAND_C = 1.0  # a set point this far below the air: the compressor runs (an overshoot is the heater's)


@dataclass(frozen=True)
class ChamberTruth:
    """The chamber as it really is (station `sim.chamber`; its rate is the world's ramp_c_per_min);
    all zero: an ideal chamber."""

    overshoot_c: float = 0.0
    heater_field_nt: tuple[float, float, float] = (0.0, 0.0, 0.0)
    compressor_field_nt: tuple[float, float, float] = (0.0, 0.0, 0.0)


def _ramp_stop_overshoot(damping: float) -> float:
    """Peak overshoot, in units of rate / omega, of a second-order system that tracked a ramp when the
    ramp stops: e(s) = exp(-z s) (-2 z cos(w s) + (1 - 2 z^2) / w sin(w s)), w = sqrt(1 - z^2)."""
    w = math.sqrt(1.0 - damping**2)
    s = np.linspace(0.0, 4.0 * math.pi / w, 40_001)
    e = np.exp(-damping * s) * (-2 * damping * np.cos(w * s) + (1 - 2 * damping**2) / w * np.sin(w * s))
    return float(e.max())


class ChamberAir:
    """The air's motion (`step`) and the heater's and compressor's field (`field_nt`)."""

    def __init__(self, truth: ChamberTruth, air_c: float, t0: float, max_rate_c_per_min: float):
        self.truth = truth
        self.room_c = air_c
        self.t0 = t0
        self.air_c = air_c
        self.setpoint_c = air_c
        self.rate_c_per_s = 0.0  # the air's speed over the last step
        self.reference_c = air_c  # the controller's closed-loop set point (second-order model)
        self.max_rate_c_per_s = max_rate_c_per_min / 60.0
        self.omega = (self.max_rate_c_per_s * _ramp_stop_overshoot(DAMPING) / truth.overshoot_c
                      if truth.overshoot_c > 0 else 0.0)
        self.makes_field = any(truth.heater_field_nt) or any(truth.compressor_field_nt)

    def step(self, air_c: float, setpoint_c: float, ramp_c_per_min: float, dt: float) -> float:
        """The air after dt seconds towards `setpoint_c` at `ramp_c_per_min` (the controller's ramp)."""
        if self.omega == 0.0:
            step = ramp_c_per_min / 60.0 * dt
            delta = setpoint_c - air_c
            new_c = air_c + max(-step, min(step, delta))
            self.rate_c_per_s = (new_c - air_c) / dt
        else:
            n = math.ceil(dt / SECOND_ORDER_STEP_S)
            new_c = air_c
            for _ in range(n):
                new_c = self._second_order(new_c, setpoint_c, ramp_c_per_min, dt / n)
        self.air_c, self.setpoint_c = new_c, setpoint_c
        return new_c

    def _second_order(self, air_c: float, setpoint_c: float, ramp_c_per_min: float, dt: float) -> float:
        """One semi-implicit Euler step of the air after the closed-loop set point, its speed clipped."""
        move = ramp_c_per_min / 60.0 * dt
        self.reference_c += max(-move, min(move, setpoint_c - self.reference_c))
        accel = self.omega**2 * (self.reference_c - air_c) - 2 * DAMPING * self.omega * self.rate_c_per_s
        limit = self.max_rate_c_per_s
        self.rate_c_per_s = max(-limit, min(limit, self.rate_c_per_s + accel * dt))
        return air_c + self.rate_c_per_s * dt

    def compressor_on(self) -> bool:
        return self.setpoint_c < self.air_c - COOL_BAND_C or self.air_c < self.room_c - ROOM_BAND_C

    def heater_duty(self) -> float:
        demand = (self.air_c - self.room_c) / HOLD_SPAN_C + self.rate_c_per_s / self.max_rate_c_per_s
        if self.compressor_on():
            demand += COMPRESSOR_LOAD
        return min(1.0, max(0.0, demand))

    def heater_on(self, t: float) -> bool:
        return (t - self.t0) % HEATER_CYCLE_S < self.heater_duty() * HEATER_CYCLE_S

    def field_nt(self, t: float) -> np.ndarray:
        """What the heater and compressor add at the coil centre now (lab frame, nT)."""
        field = np.zeros(3)
        if self.heater_on(t):
            field += self.truth.heater_field_nt
        if self.compressor_on():
            field += self.truth.compressor_field_nt
        return field
