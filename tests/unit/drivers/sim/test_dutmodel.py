"""The simulated DUT beyond T24 (drivers/sim/world/dutmodel.py): each deviation from its station key, the
inversion of the model, and the slow noise on the offset."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.world.dutmodel import FLICKER_TIME_CONSTANTS_S, DutDeviations, DutTruth, OffsetNoise
from rig.config import load_station
from rig.core.errors import ConfigError
from tests.unit.drivers.sim.benches import IDEAL, hold, reading_nt, station_data, world_of, write_station

Z = 5.0  # statistical checks at 5 sigma: a false failure less than once in a million runs


def ideal_with(**truth) -> dict:
    return {"truth": {**IDEAL, **truth}, "noise_nt": 0, "thermal_lag_s": 300}


# --- the inversion -----------------------------------------------------------------------------------
def test_the_raw_reading_inverts_the_whole_model():
    rng = np.random.default_rng(11)
    for _ in range(50):
        truth = DutTruth.random(rng, deviation_scale=1.0)
        truth.deviations.cubic_ppm_at_50ut = rng.normal(0, 5000, 3)  # 100 x typical: still inverted
        field = rng.normal(0, 60_000, 3)
        temp_c = rng.uniform(-40, 85)
        extra = rng.normal(0, 200, 3)
        h = truth.raw_from_field(field, temp_c, extra)
        np.testing.assert_allclose(truth.field_from_raw(h, temp_c, extra), field, rtol=0, atol=1e-6)


def test_without_deviations_the_model_is_t24_itself():
    truth = DutTruth.random(np.random.default_rng(3))
    h = np.array([12_000.0, -30_000.0, 41_000.0])
    t24 = (truth.S + 31.0 * truth.K) @ h + truth.b_nt + 31.0 * truth.kb_nt_per_c
    assert np.array_equal(truth.field_from_raw(h, 31.0), t24)


# --- quadratic temperature terms -----------------------------------------------------------------------
def test_quadratic_terms_bend_the_reading_over_temperature(tmp_path):
    k2 = [[2e-6, 0, 0], [0, 0, 0], [0, 0, 0]]
    spec = ideal_with(K2_per_c2=k2, kb2_nt_per_c2=[0.05, -0.02, 0.0])
    world, clock = world_of(tmp_path, sim={"ambient_nt": [40_000, 0, 10_000]}, duts={"dut1": {"sim": spec}})
    h = {}
    for temp_c in (-20.0, 20.0, 60.0):
        hold(world, clock, temp_c)
        h[temp_c] = reading_nt(world, "dut1")
    # B = (1 + K2 tau^2) h + kb2 tau^2 on each axis, so h = (B - kb2 tau^2) / (1 + K2 tau^2)
    for temp_c, got in h.items():
        tau2 = temp_c**2
        want = [(40_000 - 0.05 * tau2) / (1 + 2e-6 * tau2), 0.02 * tau2, 10_000.0]
        np.testing.assert_allclose(got, want, atol=1e-6)
    curvature = h[-20.0] - 2 * h[20.0] + h[60.0]  # zero for any T24 DUT
    assert curvature[1] == pytest.approx(0.02 * (400 - 800 + 3600))
    assert abs(curvature[0]) > 200.0


# --- thermal hysteresis --------------------------------------------------------------------------------
def test_hysteresis_shifts_the_offset_by_twice_offset_nt_between_heating_and_cooling(tmp_path):
    offset = np.array([120.0, -60.0, 25.0])
    spec = ideal_with(hysteresis={"offset_nt": offset.tolist(), "band_c": 3.0})
    world, clock = world_of(tmp_path, sim={"ambient_nt": [20_000, 0, 40_000]}, duts={"dut1": {"sim": spec}})
    field = np.array([20_000.0, 0.0, 40_000.0])
    hold(world, clock, 40.0)
    hold(world, clock, 30.0)  # cooled by 10 degC, beyond the band
    after_cooling = field - reading_nt(world, "dut1")
    hold(world, clock, 20.0)
    hold(world, clock, 30.0)  # heated by 10 degC
    after_heating = field - reading_nt(world, "dut1")
    np.testing.assert_allclose(after_cooling, -offset, atol=1e-6)
    np.testing.assert_allclose(after_heating, offset, atol=1e-6)
    hold(world, clock, 29.0)  # back by 1 degC of a 3 degC band: two thirds of the way up
    np.testing.assert_allclose(field - reading_nt(world, "dut1"), offset / 3, atol=1e-6)


# --- cubic nonlinearity --------------------------------------------------------------------------------
def test_each_axis_is_off_linear_by_its_ppm_at_50_ut_growing_as_the_square(tmp_path):
    ppm = np.array([300.0, -150.0, 0.0])
    world, clock = world_of(tmp_path, duts={"dut1": {"sim": ideal_with(cubic_ppm_at_50ut=ppm.tolist())}})
    off = {}
    for magnitude_nt in (50_000.0, 25_000.0):
        field = magnitude_nt * np.ones(3) / math.sqrt(3)
        world.set_coil_currents(field / 50_000.0)
        off[magnitude_nt] = field / reading_nt(world, "dut1") - 1  # B = h (1 + c |B|^2 / B0^2), nearly
    np.testing.assert_allclose(off[50_000.0], ppm * 1e-6, rtol=1e-3, atol=1e-12)
    np.testing.assert_allclose(off[25_000.0], ppm * 1e-6 / 4, rtol=1e-3, atol=1e-12)


# --- its place in the chamber --------------------------------------------------------------------------
def test_a_place_warmer_than_the_air_is_what_the_element_and_its_sensors_follow(tmp_path):
    spec = ideal_with(air_offset_c=1.5) | {"air_offset_c": 1.5, "sensor_lag_s": 60}
    spec["truth"].pop("air_offset_c")
    world, clock = world_of(tmp_path, duts={"dut1": {"sim": spec}})
    hold(world, clock, 40.0)
    assert world.chamber_air_c() == pytest.approx(40.0)
    assert world.element_temp_c("dut1") == pytest.approx(41.5, abs=1e-6)
    assert world.dut_temp_c("dut1") == pytest.approx(41.5, abs=1e-6)


# --- slow noise on the offset --------------------------------------------------------------------------
def test_the_random_walk_variance_grows_linearly_with_time():
    n, rate = 20_000, 3.0  # axes; nT per sqrt(h)
    noise = OffsetNoise(np.random.default_rng(5), 0.0, random_walk_nt_per_sqrt_h=rate, axes=n)
    tolerance = Z * math.sqrt(2.0 / n)  # the sample variance's relative standard deviation
    previous = noise.value_nt(0.0).copy()
    for hours in (1.0, 4.0, 9.0):  # a jump of hours at once
        value = noise.value_nt(hours * 3600.0).copy()
        assert np.mean(value**2) / (rate**2 * hours) == pytest.approx(1.0, abs=tolerance)
        previous = value
    step = noise.value_nt(9.5 * 3600.0) - previous  # the next half hour, in 1800 steps of one second
    fine = OffsetNoise(np.random.default_rng(6), 0.0, random_walk_nt_per_sqrt_h=rate, axes=n)
    for second in range(1, 1801):
        walked = fine.value_nt(float(second))
    for increments in (step, walked):
        assert np.mean(increments**2) / (rate**2 * 0.5) == pytest.approx(1.0, abs=tolerance)


def test_flicker_has_its_rms_and_equal_power_per_decade():
    n, rms = 50_000, 15.0
    noise = OffsetNoise(np.random.default_rng(8), 0.0, flicker_nt=rms, axes=n)
    tolerance = Z * math.sqrt(2.0 / n)
    start = noise.value_nt(0.0).copy()
    assert math.sqrt(np.mean(start**2)) / rms == pytest.approx(1.0, abs=tolerance)
    t, spread = 0.0, {}
    for lag_s in (10.0, 100.0, 1000.0):  # the structure function D(lag) = <(x(t + lag) - x(t))^2>
        before = noise.value_nt(t).copy()
        t += lag_s
        spread[lag_s] = np.mean((noise.value_nt(t) - before) ** 2)
        t += 1e5  # a fresh, independent start
        taus = FLICKER_TIME_CONSTANTS_S  # equal variances: D = 2 rms^2 / n sum(1 - exp(-lag / tau))
        want = 2 * rms**2 / len(taus) * np.sum(1 - np.exp(-lag_s / taus))
        assert spread[lag_s] / want == pytest.approx(1.0, abs=tolerance)
    per_decade = [spread[100.0] - spread[10.0], spread[1000.0] - spread[100.0]]
    # 1/f: each decade alike (0.98 exactly; the ratio's standard deviation here is 0.033)
    assert per_decade[1] / per_decade[0] == pytest.approx(1.0, abs=0.2)


def test_the_offset_noise_keys_reach_every_dut_reading(tmp_path):
    duts = {f"d{i:02d}": {"sim": {"truth": IDEAL, "noise_nt": 0, "random_walk_nt_per_sqrt_h": 4.0,
                                  "flicker_nt": 0.0}} for i in range(40)}
    world, clock = world_of(tmp_path, sim={"ambient_nt": [20_000, 0, 40_000]}, duts=duts)
    start = {name: reading_nt(world, name) for name in duts}
    clock.sleep(4 * 3600.0)
    moved = np.concatenate([reading_nt(world, name) - start[name] for name in duts])
    # 120 axes: the variance's relative standard deviation is 13 %; 5 sigma of it
    assert np.mean(moved**2) / (4.0**2 * 4) == pytest.approx(1.0, abs=Z * math.sqrt(2 / moved.size))
    again, clock2 = world_of(tmp_path, sim={"ambient_nt": [20_000, 0, 40_000]}, duts=duts)
    for name in duts:  # the same seed and the same calls: the same walks
        reading_nt(again, name)
    clock2.sleep(4 * 3600.0)
    assert all(np.array_equal(reading_nt(again, n) - start[n], reading_nt(world, n) - start[n]) for n in duts)


# --- random deviations for benches of many DUTs -----------------------------------------------------
def test_random_deviations_have_the_typical_sizes_and_leave_the_t24_draws_alone():
    plain = DutTruth.random(np.random.default_rng(4))
    bent = DutTruth.random(np.random.default_rng(4), deviation_scale=1.0)
    assert np.array_equal(plain.S, bent.S) and np.array_equal(plain.b_nt, bent.b_nt)
    assert plain.deviations is None and bent.deviations is not None and bent.flicker_nt > 0
    rng = np.random.default_rng(9)
    many = [DutDeviations.random(rng) for _ in range(2000)]
    cubic = np.array([d.cubic_ppm_at_50ut for d in many])
    assert 45 < np.std(cubic) < 55  # 50 ppm typical (0.1 %FS as a cubic), 6000 draws
    k2 = np.array([np.diag(d.K2_per_c2) for d in many])
    assert 1.1e-6 < np.std(k2) < 1.4e-6
    assert np.all(np.abs([d.hysteresis_offset_nt for d in many]) <= 100.0)
    assert DutDeviations().is_zero()


# --- the station keys' mistakes ------------------------------------------------------------------------
@pytest.mark.parametrize(("spec", "message"), [
    ({"truth": {**IDEAL, "hysteresis": {"offset_nt": [1, 2, 3]}}},
     r"sim\.duts\.dut1\.truth\.hysteresis\.band_c: required key is missing \(line \d+\)$"),
    ({"truth": {**IDEAL, "cubic_ppm": [1, 2, 3]}},
     r"sim\.duts\.dut1\.truth\.cubic_ppm: unknown key \(line \d+\)$"),
    ({"truth": {**IDEAL, "K2_per_c2": [[1, 0, 0], [0, 0, 0], [0, 0, 0]]}},
     r"sim\.duts\.dut1\.truth\.K2_per_c2\[0\]: each component must be within \+-0\.01 \(line \d+\)$"),
    ({"truth": IDEAL, "flicker_nt": -1}, r"sim\.duts\.dut1\.flicker_nt: must be >= 0 \(line \d+\)$"),
])
def test_a_mistake_in_a_dut_key_is_one_line_naming_it(tmp_path, spec, message):
    with pytest.raises(ConfigError, match=message):
        load_station(write_station(tmp_path, station_data(duts={"dut1": {"sim": spec}})))
