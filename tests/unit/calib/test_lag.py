"""Thermal-lag estimation: the lag filter against the closed-form ramp response, and the estimate on
synthetic ramp series with a known lag, without lag, with the other lag direction and on step data."""

from __future__ import annotations

import numpy as np
import pytest

from calib.errors import DataError
from calib.synthetic import t24_dataset, t24_ramp_dataset
from calib.thermal.lag import element_temperature, estimate_lag


def estimate(ds, **kw):
    return estimate_lag(ds.columns["t_s"], ds.h_nt, ds.temp_c, ds.ref_nt, **kw)


def ramp_response(t, rate, tau):
    """x = rate t from equilibrium at 0: T_e = rate (t - tau (1 - exp(-t/tau)))."""
    return rate * (t - tau * (1 - np.exp(-t / tau)))


@pytest.mark.parametrize("tau", [30.0, 300.0])
def test_lag_filter_is_exact_on_a_ramp_even_over_many_time_constants(tau):
    t = np.sort(np.random.default_rng(0).uniform(0, 200 * 3600, 5000))  # uneven, up to 2400 tau
    t[0] = 0.0
    te = element_temperature(t, 0.01 * t, tau, max_gap_s=1e9)
    np.testing.assert_allclose(te, ramp_response(t, 0.01, tau), rtol=0, atol=1e-9 * 0.01 * t[-1])


def test_sensor_lag_adds_tau_times_the_slope():
    t = np.arange(0.0, 3600.0, 10.0)
    te = element_temperature(t, 20 + t / 60.0, 600.0, "sensor_lags")
    np.testing.assert_allclose(te, 20 + t / 60.0 + 10.0, atol=1e-9)  # 1 degC/min x 600 s


def test_a_gap_restarts_at_equilibrium():
    t = np.concatenate([np.arange(0.0, 600.0, 10.0), 10_000 + np.arange(0.0, 600.0, 10.0)])
    x = np.where(t < 5000, 0.0, 50.0)
    te = element_temperature(t, x, 300.0)  # default gap: 20 sample intervals
    assert np.array_equal(te, x)  # a dwell after a gap is taken as settled


@pytest.mark.parametrize("lag_s", [300.0, 600.0, 900.0])
def test_recovers_a_known_element_lag(lag_s):
    ds, _ = t24_ramp_dataset(np.random.default_rng(int(lag_s)), lag_s=lag_s)
    r = estimate(ds)
    assert r.identifiable and r.direction == "element_lags"
    assert r.tau_s == pytest.approx(lag_s, rel=0.02)
    assert abs(r.tau_s - lag_s) < 5 * r.tau_se_s + 1.0  # the stated uncertainty is of the right size
    assert r.tau_se_s < 0.02 * lag_s
    assert np.abs(r.temp_element_c - ds.columns["temp_element_c"]).max() < 0.1
    assert r.updown_after_nt < 0.1 * r.updown_before_nt and not r.warnings


def test_no_lag_gives_about_zero():
    ds, _ = t24_ramp_dataset(np.random.default_rng(3), lag_s=0.0)
    r = estimate(ds)
    assert r.identifiable
    assert r.tau_s < 3 * r.tau_se_s + 1.0
    assert r.tau_se_s < 5.0


def test_auto_finds_a_lagging_sensor_and_the_wrong_direction_warns():
    ds, _ = t24_ramp_dataset(np.random.default_rng(4), lag_s=600.0, lagging="sensor")
    r = estimate(ds, direction="auto")
    assert r.direction == "sensor_lags" and r.tau_s == pytest.approx(600.0, rel=0.03)
    wrong = estimate(ds, direction="element_lags")  # no positive element lag can explain it
    assert wrong.tau_s < 60.0
    assert any("still disagree" in w for w in wrong.warnings)


def test_step_and_dwell_data_is_not_identifiable_and_unchanged():
    ds, _ = t24_dataset(np.random.default_rng(5), samples_per_point=5)
    rows_per_step = ds.n // 6
    t = np.arange(ds.n) % rows_per_step * 1.0 + np.arange(ds.n) // rows_per_step * 3600.0
    r = estimate_lag(t, ds.h_nt, ds.temp_c, ds.ref_nt)
    assert not r.identifiable and r.tau_s is None
    assert "not identifiable" in r.message and "step-and-dwell" in r.message
    assert np.array_equal(r.temp_element_c, ds.temp_c)


def test_temperature_independent_dut_is_not_identifiable():
    params = {"S": np.eye(3), "K": np.zeros((3, 3)), "b_nt": np.zeros(3), "kb_nt_per_c": np.zeros(3)}
    ds, _ = t24_ramp_dataset(np.random.default_rng(6), params=params, lag_s=600.0)
    r = estimate(ds)
    assert not r.identifiable and "hardly changes" in r.message
    assert np.array_equal(r.temp_element_c, ds.temp_c)


def test_bad_time_column_is_one_clear_line():
    t = np.array([0.0, 10.0, 5.0, 20.0])
    with pytest.raises(DataError, match="backwards at row 2"):
        element_temperature(t, np.zeros(4), 100.0)
    with pytest.raises(DataError, match="direction 'sideways'"):
        element_temperature(np.arange(4.0), np.zeros(4), 100.0, "sideways")


def test_same_lag_definition_as_the_world_simulator():
    """drivers.sim.world: each DUT's temperature (what its die sensor and TMP117 report) follows the
    chamber air with thermal_lag_s: the element_lags model with the air as the recorded column."""
    from drivers.clock import SimClock
    from drivers.sim.world import DutTruth, World

    clock = SimClock()
    world = World(clock, air_c=20.0, ramp_c_per_min=2.0)
    world.add_dut("dut1", DutTruth.random(np.random.default_rng(0), thermal_lag_s=450.0))
    world.set_chamber_setpoint(60.0)
    t, air, dut = [], [], []
    for k in range(720):  # 2 h every 10 s: ramp up 20 min, hold, then back down
        if k == 360:
            world.set_chamber_setpoint(20.0)
        t.append(clock.now())
        air.append(world.chamber_air_c())
        dut.append(world.dut_temp_c("dut1"))
        clock.sleep(10.0)
    te = element_temperature(np.array(t), np.array(air), 450.0)
    # the world holds the air at each 2 s sub-step's end value: half a step (1 s) of extra lead
    np.testing.assert_allclose(te, dut, atol=2.0 / 60 * 1.0 + 1e-3)
