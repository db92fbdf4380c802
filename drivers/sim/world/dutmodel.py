"""A simulated DUT: its T24 truth, and how a real AMR part departs from T24.

The sensor frame's true field B and the offset-cancelled raw reading h are related by

    v = (S + tau K + tau^2 K2) h + b + tau kb + tau^2 kb2 + p offset_hyst + d(t)
    B_i = v_i (1 + c_i |v|^2 / B0^2),   c_i = cubic_ppm_at_50ut_i x 1e-6,  B0 = 50 uT

with tau the element's absolute temperature (degC, the T24 truth's convention). Without deviations it is
T24 itself. The terms beyond it (hardware-notes §9.1 for their sizes):
- K2, kb2: quadratic temperature terms.
- p offset_hyst: a thermal hysteresis of the offset. p in [-1, 1] is a play (backlash) of width band_c on
  the element temperature: it moves by 2 / band_c per degC the element travels and saturates, so after
  band_c of heating it is +1 (the offset is up by offset_nt) and after band_c of cooling -1. A DUT of
  unknown thermal history starts at 0.
- c: a cubic field nonlinearity, each axis off linear by c_i at |B| = 50 uT, growing as |B|^2.
- d(t): slow noise on the offset, each axis independent (OffsetNoise): a random walk and a flicker
  (1/f) noise. All of these sit on the offset that survives SET/RESET (the T24 b), so a pair cancels none.
Reading the DUT inverts the relation for h (raw_from_field): B -> v by fixed-point iteration (the cubic
is small), then the linear part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calib.synthetic import random_t24_params
from drivers.sim.world.dutthermal import DutTemperatures

B0_NT = 50_000.0  # where cubic_ppm_at_50ut is stated
CUBIC_ITERATIONS = 50  # at most; each gains a factor ~2 c (|B| / B0)^2 (~1e-4): two or three suffice
CUBIC_TOLERANCE_NT = 1e-9
FLICKER_TIME_CONSTANTS_S = np.geomspace(1.0, 1e4, 9)  # two per decade, 1 s to ~3 h: 1/f in between

# Typical sizes for DutDeviations.random and DutTruth.random (hardware-notes §9.1; [A] marks assumptions).
K2_TYPICAL_PER_C2 = 1.25e-6  # 15 % of a 500 ppm/degC gain tempco at 60 degC from 25, as a T^2 term [A]
KB2_TYPICAL_NT_PER_C2 = 0.011  # 15 % of a 4.5 nT/degC offset tempco (MMC5983MA, with S/R) at 60 degC [A]
HYSTERESIS_TYPICAL_NT = 100.0  # "0 +- (S/R repeatability)" = 1 mG [A]
HYSTERESIS_BAND_C = 5.0  # no public figure [A]
CUBIC_TYPICAL_PPM = 50.0  # 0.1 %FS linearity (HMC5883L at 2 G, MMC5983MA at 4 G) as a cubic at 50 uT [C]
RANDOM_WALK_TYPICAL_NT_PER_SQRT_H = 2.0  # no AMR figure; fluxgates drift 1.5-3 nT/day [A]
FLICKER_TYPICAL_NT = 15.0  # the 1/f floor averaging does not beat (MMC5603) [R]
AIR_OFFSET_TYPICAL_C = 0.5  # chamber uniformity +-0.5 degC (BS 389) [R]


@dataclass
class DutDeviations:
    """How one DUT departs from T24 (module docstring); all zero is T24 itself."""

    K2_per_c2: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    kb2_nt_per_c2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    hysteresis_offset_nt: np.ndarray = field(default_factory=lambda: np.zeros(3))
    hysteresis_band_c: float = HYSTERESIS_BAND_C
    cubic_ppm_at_50ut: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def is_zero(self) -> bool:
        return not (np.any(self.K2_per_c2) or np.any(self.kb2_nt_per_c2) or
                    np.any(self.hysteresis_offset_nt) or np.any(self.cubic_ppm_at_50ut))

    @classmethod
    def random(cls, rng: np.random.Generator, scale: float = 1.0) -> DutDeviations:
        """Deviations of the typical sizes above times `scale` (K2 mostly on its diagonal)."""
        k2 = rng.normal(0, K2_TYPICAL_PER_C2 / 10, (3, 3))
        k2[np.diag_indices(3)] = rng.normal(0, K2_TYPICAL_PER_C2, 3)
        return cls(K2_per_c2=scale * k2,
                   kb2_nt_per_c2=scale * rng.normal(0, KB2_TYPICAL_NT_PER_C2, 3),
                   hysteresis_offset_nt=scale * rng.uniform(-HYSTERESIS_TYPICAL_NT, HYSTERESIS_TYPICAL_NT, 3),
                   cubic_ppm_at_50ut=scale * rng.normal(0, CUBIC_TYPICAL_PPM, 3))


@dataclass
class DutTruth:
    """The injected calibration errors of one DUT (absolute-tau T24 convention, tau in degC), what bends
    them (deviations) and where and how it sits in the chamber."""

    S: np.ndarray  # 3x3, dimensionless
    K: np.ndarray  # 3x3, per degC
    b_nt: np.ndarray  # 3
    kb_nt_per_c: np.ndarray  # 3
    bridge_offset_nt: np.ndarray = field(default_factory=lambda: np.zeros(3))  # at 25 degC
    bridge_offset_tc_nt_per_c: np.ndarray = field(default_factory=lambda: np.zeros(3))
    noise_nt: float = 0.0  # white noise per axis, RMS
    thermal_lag_s: float = 600.0  # DUT temperature time constant against the chamber air
    mount: np.ndarray = field(default_factory=lambda: np.eye(3))  # lab frame -> sensor frame rotation
    sensor_lag_s: float = 0.0  # the reported temperature lags the element's by this time constant
    position_m: np.ndarray = field(default_factory=lambda: np.zeros(3))  # where it sits in the coil set
    deviations: DutDeviations | None = None  # None: exactly T24
    random_walk_nt_per_sqrt_h: float = 0.0  # on the offset, per axis
    flicker_nt: float = 0.0  # 1/f noise on the offset, RMS per axis
    air_offset_c: float = 0.0  # its place in the chamber is this much warmer than the controller's air

    def _matrix(self, temp_c: float) -> np.ndarray:
        m = self.S + temp_c * self.K
        return m if self.deviations is None else m + temp_c**2 * self.deviations.K2_per_c2

    def _more_offset(self, temp_c: float, extra_nt: np.ndarray | None) -> np.ndarray | None:
        """The offset beyond T24's b + tau kb (None: none), kept apart so that T24 alone stays bit-exact."""
        more = None if self.deviations is None else temp_c**2 * self.deviations.kb2_nt_per_c2
        if extra_nt is not None:
            more = extra_nt if more is None else more + extra_nt
        return more

    def _cubic(self) -> np.ndarray | None:
        c = None if self.deviations is None else self.deviations.cubic_ppm_at_50ut * 1e-6
        return c if c is not None and np.any(c) else None

    def field_from_raw(self, h_nt: np.ndarray, temp_c: float, extra_offset_nt=None) -> np.ndarray:
        """The truth's model: true field from a raw reading (T24 when there are no deviations);
        extra_offset_nt: the offset's state now (hysteresis and slow noise)."""
        v = self._matrix(temp_c) @ h_nt + self.b_nt + temp_c * self.kb_nt_per_c
        more = self._more_offset(temp_c, extra_offset_nt)
        if more is not None:
            v = v + more
        c = self._cubic()
        return v if c is None else v * (1.0 + c * (v @ v) / B0_NT**2)

    def raw_from_field(self, field_nt: np.ndarray, temp_c: float, extra_offset_nt=None) -> np.ndarray:
        """Noise-free raw reading (offset-cancelled) that the truth's model maps to `field_nt`."""
        v = field_nt
        c = self._cubic()
        if c is not None:  # B = v (1 + c |v|^2 / B0^2): a contraction, from v = B
            for _ in range(CUBIC_ITERATIONS):
                v, before = field_nt / (1.0 + c * (v @ v) / B0_NT**2), v
                if np.max(np.abs(v - before)) < CUBIC_TOLERANCE_NT:
                    break
        rhs = v - self.b_nt - temp_c * self.kb_nt_per_c
        more = self._more_offset(temp_c, extra_offset_nt)
        return solve3(self._matrix(temp_c), rhs if more is None else rhs - more)

    def bridge_offset_at(self, temp_c: float) -> np.ndarray:
        return self.bridge_offset_nt + (temp_c - 25.0) * self.bridge_offset_tc_nt_per_c

    @classmethod
    def random(cls, rng: np.random.Generator, *, noise_nt: float = 20.0, thermal_lag_s: float = 600.0,
               deviation_scale: float = 0.0):
        """Errors of the size an AMR datasheet allows (calib.synthetic.random_t24_params), then a bridge
        offset of a few uT drifting some 10 nT/degC. deviation_scale > 0 adds every departure from T24
        (deviations, offset noise, place in the chamber) at that multiple of its typical size, drawn after
        the T24 errors so that those stay as without."""
        p = random_t24_params(rng)
        truth = cls(
            S=p["S"],
            K=p["K"],
            b_nt=p["b_nt"],
            kb_nt_per_c=p["kb_nt_per_c"],
            bridge_offset_nt=rng.normal(0, 2000, 3),
            bridge_offset_tc_nt_per_c=rng.normal(0, 20, 3),
            noise_nt=noise_nt,
            thermal_lag_s=thermal_lag_s,
        )
        if deviation_scale > 0:
            truth.deviations = DutDeviations.random(rng, deviation_scale)
            truth.random_walk_nt_per_sqrt_h = deviation_scale * RANDOM_WALK_TYPICAL_NT_PER_SQRT_H
            truth.flicker_nt = deviation_scale * FLICKER_TYPICAL_NT
            truth.air_offset_c = deviation_scale * rng.normal(0, AIR_OFFSET_TYPICAL_C)
        return truth


def solve3(m: np.ndarray, y: np.ndarray) -> np.ndarray:
    """m^-1 y for a 3x3 m, by its adjugate in floats: every reading of a simulated DUT solves one, and
    numpy's LAPACK call costs several times the arithmetic. A matrix far from well conditioned (the
    determinant below 1e-6 of the product of the rows' norms) goes to numpy's pivoted solve instead."""
    (a, b, c), (d, e, f), (g, h, i) = m.tolist()
    y0, y1, y2 = y.tolist()
    co_a, co_b, co_c = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * co_a + b * co_b + c * co_c
    scale = math.sqrt((a * a + b * b + c * c) * (d * d + e * e + f * f) * (g * g + h * h + i * i))
    if not abs(det) > 1e-6 * scale:
        return np.linalg.solve(m, y)
    return np.array([
        co_a * y0 + (c * h - b * i) * y1 + (b * f - c * e) * y2,
        co_b * y0 + (a * i - c * g) * y1 + (c * d - a * f) * y2,
        co_c * y0 + (b * g - a * h) * y1 + (a * e - b * d) * y2,
    ]) / det


class OffsetNoise:
    """A random walk plus a flicker noise per axis, advanced exactly over any interval (time may jump by
    hours): the walk by a normal step of variance rate^2 dt, the flicker as a sum of Ornstein-Uhlenbeck
    processes with time constants FLICKER_TIME_CONSTANTS_S and equal variances, which sum to a 1/f
    spectrum between them; they start in their stationary state, so the flicker's RMS is flicker_nt."""

    def __init__(self, rng: np.random.Generator, t0: float, *, random_walk_nt_per_sqrt_h: float = 0.0,
                 flicker_nt: float = 0.0, axes: int = 3):
        self.rng = rng
        self.t = t0
        self.walk_nt_per_sqrt_s = random_walk_nt_per_sqrt_h / 60.0
        self.tau_s = FLICKER_TIME_CONSTANTS_S
        self.each_nt = flicker_nt / math.sqrt(len(self.tau_s))
        self.walk = np.zeros(axes)
        self.flicker = rng.normal(0.0, self.each_nt, (axes, len(self.tau_s)))

    def value_nt(self, t: float) -> np.ndarray:
        dt = t - self.t
        if dt > 0:
            self.t = t
            if self.walk_nt_per_sqrt_s > 0:
                self.walk += self.rng.normal(0.0, self.walk_nt_per_sqrt_s * math.sqrt(dt), self.walk.shape)
            if self.each_nt > 0:
                keep = np.exp(-dt / self.tau_s)
                fresh = self.each_nt * np.sqrt(1.0 - keep**2)
                self.flicker = self.flicker * keep + self.rng.normal(0.0, 1.0, self.flicker.shape) * fresh
        return self.walk + self.flicker.sum(axis=1)


class DutState:
    """A DUT's state in the world: its element's and its sensors' temperatures (kept with every other
    DUT's in the world's DutTemperatures), its offset's (hysteresis, slow noise), and the generator of the
    coil current noise it sees."""

    def __init__(self, truth: DutTruth, temps: DutTemperatures, temp_c: float, t: float,
                 offset_rng: np.random.Generator, current_rng: np.random.Generator):
        self.truth = truth
        self._temps = temps
        dev = truth.deviations
        hysteresis = dev is not None and bool(np.any(dev.hysteresis_offset_nt))
        self._index = temps.add(start_c=temp_c, lag_s=truth.thermal_lag_s, sensor_lag_s=truth.sensor_lag_s,
                                air_offset_c=truth.air_offset_c,
                                play_band_c=dev.hysteresis_band_c if hysteresis else None)
        self.has_play = hysteresis
        noisy = truth.random_walk_nt_per_sqrt_h > 0 or truth.flicker_nt > 0
        walk = truth.random_walk_nt_per_sqrt_h
        self.offset_noise = OffsetNoise(offset_rng, t, random_walk_nt_per_sqrt_h=walk,
                                        flicker_nt=truth.flicker_nt) if noisy else None
        self.current_rng = current_rng

    @property
    def temp_c(self) -> float:
        """The element's temperature."""
        return float(self._temps.element_c[self._index])

    @property
    def sensor_c(self) -> float:
        """What its temperature sensors report."""
        return float(self._temps.sensor_c[self._index])

    def extra_offset_nt(self, t: float) -> np.ndarray | None:
        """The offset's state beyond the truth's temperature terms (None: nothing beyond them)."""
        parts = []
        if self.has_play:
            parts.append(self._temps.play[self._index] * self.truth.deviations.hysteresis_offset_nt)
        if self.offset_noise is not None:
            parts.append(self.offset_noise.value_nt(t))
        return sum(parts) if parts else None
