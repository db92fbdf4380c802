"""The simulated coil current source as a real one is: the current it delivers and the current it reports.

    delivered = set x (1 + gain_error) + offset + noise      (per channel, while its output is on)
    reported  = delivered x (1 + readback_error)             (the controller's read-back registers)

`set` is what the controller regulates to (its setpoint, clamped to its compliance). The noise is white,
drawn anew for every evaluation of the field (a DUT conversion is far longer than the source's
bandwidth) and for every read-back. A rig that takes the read-back as the truth is wrong by the
read-back error; one that takes the commanded currents, by the gain and offset errors.
Magnitudes: hardware-notes §9.3 (Kepco BOP calibration tolerances, read-back accuracy [A]).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CurrentSourceErrors:
    gain_error_ppm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset_ma: tuple[float, float, float] = (0.0, 0.0, 0.0)
    noise_ma: tuple[float, float, float] = (0.0, 0.0, 0.0)
    readback_error_ppm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def is_zero(self) -> bool:
        return not any(np.any(v) for v in (self.gain_error_ppm, self.offset_ma, self.noise_ma,
                                            self.readback_error_ppm))


class CurrentSource:
    def __init__(self, errors: CurrentSourceErrors, rng: np.random.Generator):
        self.gain = 1.0 + np.asarray(errors.gain_error_ppm, float) * 1e-6
        self.offset_a = np.asarray(errors.offset_ma, float) * 1e-3
        self.noise_a = np.asarray(errors.noise_ma, float) * 1e-3
        self.readback_gain = 1.0 + np.asarray(errors.readback_error_ppm, float) * 1e-6
        self.rng = rng  # for the read-backs (the field's draws come from the caller's stream)

    def delivered_a(self, set_a: np.ndarray, on: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """What flows in each coil now, for a controller regulating to `set_a` (outputs `on`)."""
        noise = rng.normal(0.0, 1.0, 3) * self.noise_a if np.any(self.noise_a) else 0.0
        return np.where(on, set_a * self.gain + self.offset_a + noise, 0.0)

    def reported_a(self, set_a: np.ndarray, on: np.ndarray) -> np.ndarray:
        """What the read-back registers show for a controller regulating to `set_a`."""
        return self.delivered_a(set_a, on, self.rng) * self.readback_gain
