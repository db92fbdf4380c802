"""The simulated DUTs' temperatures, every DUT advanced in one array step.

Each DUT's element follows the air at its place in the chamber (the air plus its offset there) through a
first-order lag; its temperature sensors follow the element through a lag of their own (none: they read
the element itself); the thermal hysteresis of its offset is a play of width band_c on the element
temperature (drivers/sim/world/dutmodel.py), whose state p in [-1, 1] moves by 2 / band_c per degC the element
travels. Within a step of constant air each lag is exact.

The world advances every DUT at every reading of any one of them (the time has moved for all), so the
temperatures are arrays: a step costs about the same for 2 DUTs as for 64, where a loop over the DUTs
made a campaign's simulation grow as the square of its DUTs.

    temps = DutTemperatures()
    i = temps.add(start_c=22.0, lag_s=600.0, sensor_lag_s=0.0, air_offset_c=0.3, play_band_c=None)
    temps.step(air_c=25.0, dt=2.0)
    temps.element_c[i], temps.sensor_c[i], temps.play[i]
"""

from __future__ import annotations

import numpy as np


class DutTemperatures:
    def __init__(self) -> None:
        self.element_c = np.zeros(0)
        self.sensor_c = np.zeros(0)  # what the DUT's temperature sensors report
        self.play = np.zeros(0)  # the hysteresis play's state in [-1, 1] (0 where it has none)
        self._air_offset_c = np.zeros(0)
        self._minus_per_lag = np.zeros(0)  # -1 / the element's lag, 1/s
        self._minus_per_sensor_lag = np.zeros(0)  # -1 / the sensors' lag; -inf where they read the element
        self._play_gain = np.zeros(0)  # 2 / band_c per degC; 0 where there is no hysteresis
        self._play_from_c = np.zeros(0)  # the element temperature the play last followed
        # which terms any DUT has: a step is a reading's cost, so terms nobody has are skipped
        self._sensor_lags = self._plays = False

    def add(self, *, start_c: float, lag_s: float, sensor_lag_s: float, air_offset_c: float,
            play_band_c: float | None) -> int:
        """A DUT at `start_c` (element and sensors), its play at 0; returns its index in the arrays."""
        def grown(values: np.ndarray, value: float) -> np.ndarray:
            return np.append(values, float(value))

        self.element_c = grown(self.element_c, start_c)
        self.sensor_c = grown(self.sensor_c, start_c)
        self.play = grown(self.play, 0.0)
        self._air_offset_c = grown(self._air_offset_c, air_offset_c)
        self._minus_per_lag = grown(self._minus_per_lag, -1.0 / lag_s)
        self._minus_per_sensor_lag = grown(self._minus_per_sensor_lag,
                                           -1.0 / sensor_lag_s if sensor_lag_s > 0 else -np.inf)
        self._play_gain = grown(self._play_gain, 2.0 / play_band_c if play_band_c else 0.0)
        self._play_from_c = grown(self._play_from_c, start_c)
        self._sensor_lags = self._sensor_lags or sensor_lag_s > 0
        self._plays = self._plays or bool(play_band_c)
        return len(self.element_c) - 1

    def step(self, air_c: float, dt: float) -> None:
        """`dt` (> 0) seconds at a constant air temperature `air_c`."""
        place_c = self._air_offset_c + air_c
        element_c = (self.element_c - place_c) * np.exp(self._minus_per_lag * dt) + place_c
        if self._sensor_lags:  # exp(-inf) = 0: a sensor without a lag reads the element exactly
            self.sensor_c = (self.sensor_c - element_c) * np.exp(self._minus_per_sensor_lag * dt) + element_c
        else:
            self.sensor_c = element_c
        if self._plays:
            self.play = np.clip(self.play + self._play_gain * (element_c - self._play_from_c), -1.0, 1.0)
            self._play_from_c = element_c
        self.element_c = element_c
