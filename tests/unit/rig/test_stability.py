"""The thermal stability detector: band, rate, dwell and the hard maximum wait."""

from __future__ import annotations

import math

import pytest

from rig.engine.stability import (
    APPROACHING,
    STABLE,
    TIMEOUT,
    StabilityCriteria,
    StabilityDetector,
    slope_per_s,
)

CRIT = StabilityCriteria(band_c=0.5, max_rate_c_per_min=0.1, dwell_s=300.0, max_wait_s=7200.0)


def feed(det: StabilityDetector, temps, dt_s: float = 10.0, t0: float = 0.0) -> list[str]:
    return [det.add(t0 + i * dt_s, temp) for i, temp in enumerate(temps)]


def test_slope_of_a_line_and_degenerate_inputs():
    assert slope_per_s([(0.0, 1.0), (10.0, 2.0), (20.0, 3.0)]) == pytest.approx(0.1)
    assert slope_per_s([(5.0, 1.0)]) == 0.0
    assert slope_per_s([(5.0, 1.0), (5.0, 2.0)]) == 0.0


def test_first_order_approach_becomes_stable_only_after_dwell_in_band():
    target = 40.0
    det = StabilityDetector(target, CRIT)
    # DUT lagging the air with a 600 s time constant from 22 degC
    temps = [target + (22.0 - target) * math.exp(-i * 10.0 / 600.0) for i in range(600)]
    states = feed(det, temps)
    first_stable = states.index(STABLE)
    entered_band = next(i for i, x in enumerate(temps) if abs(x - target) <= 0.5)
    assert first_stable * 10.0 >= entered_band * 10.0 + CRIT.dwell_s
    assert all(s == APPROACHING for s in states[:first_stable])
    assert abs(det.rate_c_per_min) <= CRIT.max_rate_c_per_min


def test_leaving_the_band_restarts_the_dwell():
    det = StabilityDetector(25.0, CRIT)
    feed(det, [25.0] * 20)  # 190 s in band
    assert det.state == APPROACHING
    det.add(200.0, 26.0)  # a bump out of band
    assert det.in_band_s == 0.0
    states = feed(det, [25.0] * 31, t0=210.0)
    assert states[-1] == STABLE
    assert states[29] == APPROACHING  # 290 s after the bump: dwell not yet complete


def test_in_band_but_drifting_is_not_stable():
    crit = StabilityCriteria(band_c=2.0, max_rate_c_per_min=0.1, dwell_s=300.0, max_wait_s=7200.0)
    det = StabilityDetector(25.0, crit)
    # 0.3 degC/min drift that stays within +-2 degC for the whole 10 min
    states = feed(det, [24.0 + 0.005 * i * 10.0 for i in range(40)])
    assert STABLE not in states
    assert det.rate_c_per_min == pytest.approx(0.3, rel=1e-6)


def test_never_settling_times_out_at_the_hard_maximum():
    crit = StabilityCriteria(band_c=0.5, max_rate_c_per_min=0.1, dwell_s=300.0, max_wait_s=600.0)
    det = StabilityDetector(60.0, crit)
    states = feed(det, [30.0] * 100)
    assert states[59] == APPROACHING
    assert states[60] == TIMEOUT
