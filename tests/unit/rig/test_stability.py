"""The thermal stability detector: rate, dwell and band around each DUT's own level, the bound on how far
from the set point a DUT may settle, and the hard maximum wait."""

from __future__ import annotations

import math

import pytest

from rig.engine.stability import (
    APPROACHING,
    OFFSET,
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


def approach(target: float, start: float, tau_s: float, n: int, dt_s: float = 10.0) -> list[float]:
    return [target + (start - target) * math.exp(-i * dt_s / tau_s) for i in range(n)]


def test_first_order_approach_becomes_stable_once_what_is_left_is_within_the_band():
    target = 40.0
    det = StabilityDetector(target, CRIT)
    temps = approach(target, 22.0, 600.0, 600)  # a DUT lagging the air by 600 s, from 22 degC
    states = feed(det, temps)
    first_stable = states.index(STABLE)
    assert abs(temps[first_stable] - target) <= CRIT.band_c
    assert abs(temps[first_stable - int(CRIT.dwell_s // 10)] - target) > CRIT.band_c / 2  # not a dwell later
    assert all(s == APPROACHING for s in states[:first_stable])
    assert abs(det.rate_c_per_min) <= CRIT.max_rate_c_per_min


def test_a_dut_found_settled_at_once_is_stable_after_one_dwell_in_band():
    det = StabilityDetector(25.0, CRIT)
    states = feed(det, [25.1] * 40)
    assert states.index(STABLE) * 10.0 == CRIT.dwell_s


@pytest.mark.parametrize("offset_c", [1.5, -0.8])
def test_a_dut_whose_place_is_off_the_air_is_stable_where_it_settles(offset_c):
    det = StabilityDetector(40.0, CRIT)
    temps = approach(40.0 + offset_c, 22.0, 600.0, 900)  # its place warmer or colder than the air
    states = feed(det, temps)
    first = states.index(STABLE)
    assert OFFSET not in states
    # stable only once what is left of its approach is within the band of its own level
    assert abs(temps[first] - (40.0 + offset_c)) <= CRIT.band_c
    assert det.level_c == pytest.approx(40.0 + offset_c, abs=0.02)
    assert det.offset_c == pytest.approx(offset_c, abs=0.02)


def test_a_slow_dut_moving_slower_than_the_rate_limit_is_not_taken_for_a_settled_one():
    crit = StabilityCriteria(band_c=0.3, max_rate_c_per_min=0.2, dwell_s=60.0, max_wait_s=20_000.0)
    det = StabilityDetector(20.0, crit)
    temps = approach(19.6, 30.0, 316.0, 600)  # 0.4 degC colder than the air, a 316 s lag
    states = feed(det, temps)
    first = states.index(STABLE)
    # its rate falls below 0.2 degC/min a full degree before it gets there: not stable then
    slow = next(i for i in range(1, len(temps)) if abs(temps[i] - temps[i - 1]) / 10.0 * 60.0 <= 0.2)
    assert abs(temps[slow] - 19.6) > 1.0 and first > slow
    assert abs(temps[first] - 19.6) <= crit.band_c


def test_a_dut_settled_beyond_max_offset_is_a_fault_not_a_wait():
    det = StabilityDetector(40.0, CRIT)
    states = feed(det, approach(43.0, 22.0, 300.0, 700))  # 3 degC off, more than max_offset_c 2
    assert STABLE not in states
    first = states.index(OFFSET)
    assert first * 10.0 < 4000.0 < CRIT.max_wait_s  # a fault once it has shown where it settles


def test_a_slow_approach_is_not_taken_for_an_offset():
    det = StabilityDetector(40.0, CRIT)
    states = feed(det, approach(40.0, 22.0, 1800.0, 1500))  # 1800 s lag: slow while still degrees away
    assert OFFSET not in states and STABLE in states
    assert abs(det.offset_c) <= CRIT.band_c


def test_leaving_the_band_restarts_the_dwell():
    det = StabilityDetector(25.0, CRIT)
    feed(det, [25.0] * 20)  # 190 s in band
    assert det.state == APPROACHING
    det.add(200.0, 27.0)  # a bump: 2 degC does not fit within +-0.5 of any level
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
