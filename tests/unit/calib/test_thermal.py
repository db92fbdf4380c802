"""A DUT's first-order lag and offset behind the air, and the air's pace and overshoot, measured from
time series (calib/thermal/response.py): recovered within their stated standard errors, refused when the rows
do not show them."""

from __future__ import annotations

import numpy as np
import pytest

from calib.design.planner import element_path
from calib.errors import DataError
from calib.thermal.response import air_motion, first_order_fit


def ramp_and_hold(rate_c_per_min: float, to_c: float, end_s: float, dt_s: float = 10.0):
    t = np.arange(0.0, end_s, dt_s)
    return t, np.minimum(22.0 + rate_c_per_min / 60.0 * t, to_c)


@pytest.mark.parametrize(("lag_s", "offset_c"), [(300.0, 0.0), (600.0, 0.4), (900.0, -1.5)])
def test_a_dut_behind_the_air_gives_its_lag_and_where_it_settles(lag_s, offset_c):
    t, air = ramp_and_hold(2.8, 42.0, 9000.0)
    rng = np.random.default_rng(17)
    dut = element_path(t, air + offset_c, lag_s, 22.0 + offset_c) + rng.normal(0.0, 0.01, t.size)
    fit = first_order_fit(t[::3], air[::3], t, dut)  # the air logged less often than the DUT
    assert fit.identifiable, fit.message
    # 5 standard errors (a chance below 1e-6), plus the air's linear interpolation between its rows
    assert abs(fit.tau_s - lag_s) < 5 * fit.tau_se_s + 0.01 * lag_s
    assert fit.offset_c == pytest.approx(offset_c, abs=0.02)
    assert fit.rms_c == pytest.approx(0.01, rel=0.2)


def test_a_dut_that_started_off_its_place_is_fitted_from_where_it_was():
    t, air = ramp_and_hold(3.0, 40.0, 8000.0)
    dut = element_path(t, air, 500.0, 25.0)  # not settled when the log began
    fit = first_order_fit(t, air, t, dut)
    assert fit.tau_s == pytest.approx(500.0, rel=1e-3) and fit.start_c == pytest.approx(25.0, abs=1e-3)


def test_air_that_does_not_move_shows_no_lag():
    t = np.arange(0.0, 3600.0, 10.0)
    fit = first_order_fit(t, np.full(t.size, 25.0), t, np.full(t.size, 25.2))
    assert not fit.identifiable and fit.tau_s is None and "the air moved 0 degC" in fit.message


def test_a_record_too_short_for_the_lag_is_not_identified():
    t, air = ramp_and_hold(3.0, 40.0, 120.0)  # two minutes of a 20-minute lag
    dut = element_path(t, air, 1200.0, 22.0) + np.random.default_rng(3).normal(0.0, 0.05, t.size)
    fit = first_order_fit(t, air, t, dut)
    assert not fit.identifiable and "not identifiable" in fit.message


def test_the_airs_pace_and_overshoot_after_a_set_point_change():
    t = np.arange(0.0, 3600.0, 5.0)
    air = np.minimum(22.0 + 2.8 / 60.0 * t, 37.0)
    after = t > (15.0 / 2.8 * 60.0)
    air[after] += 0.5 * np.exp(-(t[after] - t[after][0]) / 300.0) * np.sin(np.pi * np.minimum(
        (t[after] - t[after][0]) / 600.0, 1.0))  # a bump past the set point once it arrives
    motion = air_motion(t, np.full(t.size, 37.0), air)
    assert motion.rate_c_per_min == pytest.approx(2.8, rel=1e-6) and motion.changes == 1
    assert 0.1 < motion.overshoot_c < 0.5
    still = air_motion(t, np.full(t.size, 22.5), np.full(t.size, 22.0))
    assert still.rate_c_per_min is None and "no set-point change" in still.message


def test_bad_series_are_refused_naming_what():
    with pytest.raises(DataError, match="air: time goes backwards"):
        first_order_fit([0.0, 2.0, 1.0], [1.0, 2.0, 3.0], [0.0, 1.0], [1.0, 1.0])
    with pytest.raises(DataError, match="DUT temperature: 2 times but 3 values"):
        first_order_fit([0.0, 1.0], [1.0, 2.0], [0.0, 1.0], [1.0, 1.0, 1.0])
