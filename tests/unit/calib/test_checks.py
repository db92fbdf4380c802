"""The model checks (calib/checks/model_checks.py): each fires on data with its deviation, stays quiet on
exact T24 data with noise (p uniform, verdict "holds"), says when it cannot test, and follows the stated
verdict rule."""

from __future__ import annotations

import numpy as np
import pytest

from calib.checks.model_checks import (
    FIELD,
    HYSTERESIS,
    TEMPERATURE,
    field_linearity,
    field_magnitudes_nt,
    hysteresis,
    model_checks,
    verdict,
)
from calib.dataset import Dataset
from calib.errors import DataError
from calib.synthetic import coil_directions, random_t24_params

# the Kolmogorov-Smirnov distance of 200 uniform p-values exceeds this with probability 1e-4
KS_LIMIT_200 = float(np.sqrt(-np.log(0.5e-4) / (2 * 200)))


def sensor_data(rng, *, temps_c=(-30.0, 20.0, 70.0), magnitudes_nt=(50_000.0,), samples=10, noise_nt=10.0,
                curvature_nt_per_c2=0.0, hysteresis_nt=0.0, cubic_ppm=0.0):
    """A T24 sensor at every temperature x magnitude x 26 directions x `samples`, each sample labelled
    heating or cooling at random, with the deviations T24 cannot follow added to the field it measured:
    curvature (tau - 20)^2 on x, +-hysteresis on every axis, and a cubic c |h|^2 h / (50 uT)^2."""
    p = random_t24_params(rng)
    dirs = np.repeat(coil_directions(26), samples, axis=0)
    ref = np.concatenate([m * dirs for m in magnitudes_nt])
    ref = np.tile(ref, (len(temps_c), 1))
    temp = np.repeat(np.asarray(temps_c, float), len(dirs) * len(magnitudes_nt))
    m = p["S"][None] + temp[:, None, None] * p["K"][None]
    h = np.linalg.solve(m, (ref - p["b_nt"] - temp[:, None] * p["kb_nt_per_c"])[..., None])[..., 0]
    h += rng.normal(0, noise_nt, h.shape)
    direction = rng.choice([-1.0, 1.0], len(h))
    field = ref + np.outer(curvature_nt_per_c2 * (temp - 20.0) ** 2, [1.0, 0.0, 0.0])
    field += hysteresis_nt * direction[:, None]
    field += 1e-6 * cubic_ppm * np.sum(h**2, axis=1, keepdims=True) * h / 50_000.0**2
    return Dataset(h_nt=h, temp_c=temp, ref_nt=field), direction


def test_every_check_stays_quiet_on_exact_t24_data_with_noise():
    """200 noise draws of a small campaign (156 samples): every check's p-values are uniform (KS distance
    within its 1e-4 limit). On data this small a chance p < 1e-3 comes with a noise-sized effect, so about
    one check in a thousand says "fails": 0.6 expected of 600, 6 or more has probability 4e-5."""
    rng = np.random.default_rng(10)
    p_values = {TEMPERATURE: [], HYSTERESIS: [], FIELD: []}
    fails = 0
    for _ in range(200):
        ds, direction = sensor_data(rng, magnitudes_nt=(25_000.0, 50_000.0), samples=1)
        for check in model_checks(ds, direction):
            assert check.testable, check.message
            fails += check.verdict == "fails"
            p_values[check.name].append(check.p)
    assert fails <= 5
    for name, p in p_values.items():
        p = np.sort(p)
        ks = np.max(np.maximum(np.arange(1, 201) / 200 - p, p - np.arange(200) / 200))
        assert ks < KS_LIMIT_200, name


def test_every_check_holds_on_a_campaign_sized_t24_data_set():
    """5 temperatures x 2 magnitudes x 26 directions x 10 samples: a false "fails" needs p < 1e-3 (one in a
    thousand) and, at the same time, a noise-driven effect beyond half the noise, which on 2600 samples
    (the effects' standard errors ~1 nT against the 5 nT threshold) is far rarer still."""
    ds, direction = sensor_data(np.random.default_rng(18), temps_c=(-30.0, -5.0, 20.0, 45.0, 70.0),
                                magnitudes_nt=(25_000.0, 50_000.0))
    for check in model_checks(ds, direction):
        assert check.testable and check.verdict == "holds", check.message
        assert check.magnitude_nt < 0.5 * check.noise_nt


def test_a_curve_in_temperature_fails_the_temperature_check_with_its_size():
    ds, direction = sensor_data(np.random.default_rng(11), temps_c=(-30.0, -5.0, 20.0, 45.0, 70.0),
                                curvature_nt_per_c2=0.008)
    checks = {c.name: c for c in model_checks(ds, direction)}
    curve = checks[TEMPERATURE]
    assert curve.verdict == "fails" and curve.p < 1e-10
    assert 0.008 * 50**2 * 0.7 < curve.magnitude_nt < 0.008 * 50**2 * 1.5  # 20 nT at the ends of the range
    assert checks[HYSTERESIS].verdict == "holds"


def test_hysteresis_fails_with_twice_the_offset_as_its_magnitude():
    ds, direction = sensor_data(np.random.default_rng(12), hysteresis_nt=6.0)
    check = hysteresis(ds, direction)
    assert check.verdict == "fails" and check.p < 1e-10
    assert 12.0 * 0.8 < check.magnitude_nt < 12.0 * 1.2 and "heating and cooling differ" in check.message
    np.testing.assert_allclose(check.details["offset_nt"], 6.0, atol=1.5)
    scaled = hysteresis(ds, direction, scale=True)
    assert scaled.verdict == "fails" and scaled.dof == 12


def test_a_cubic_response_fails_the_field_check_in_ppm_and_nt():
    ds, _ = sensor_data(np.random.default_rng(13), magnitudes_nt=(20_000.0, 50_000.0), cubic_ppm=400.0)
    check = field_linearity(ds)
    assert check.verdict == "fails" and check.p < 1e-10
    np.testing.assert_allclose(check.details["cubic_ppm_at_50ut"], 400.0, atol=120.0)
    largest = check.details["largest_field_nt"]
    assert check.magnitude_nt == pytest.approx(max(abs(c) for c in check.details["cubic_ppm_at_50ut"]) * 1e-6
                                               * largest**3 / 50_000.0**2)


def test_what_the_data_cannot_show_is_not_testable():
    rng = np.random.default_rng(14)
    ds, direction = sensor_data(rng, temps_c=(-30.0, 70.0))
    temperature, hyst, field = model_checks(ds, direction)
    assert temperature.verdict == "not testable" and "interior" in temperature.message
    assert hyst.testable  # two temperatures suffice for an offset
    assert field.verdict == "not testable" and "one, 50000 nT" in field.message
    assert model_checks(ds)[1].verdict == "not testable"  # no thermal direction given
    heating_only = hysteresis(ds, np.ones(len(ds)))
    assert not heating_only.testable and "0 cooling" in heating_only.message
    assert field_magnitudes_nt(ds.ref_nt) == [pytest.approx(50_000.0)]


def test_a_tiny_significant_effect_on_many_samples_is_reported_but_holds():
    """2d = 3 nT against 10 nT noise on 23 400 samples: significant, but within half the noise."""
    ds, direction = sensor_data(np.random.default_rng(15), samples=300, hysteresis_nt=1.5)
    check = hysteresis(ds, direction)
    assert check.p < 1e-6 and check.verdict == "holds"
    assert "significant, within 0.5 x the noise" in check.message
    strict = hysteresis(ds, direction, practical_ratio=0.1)
    assert strict.verdict == "fails"


def test_the_verdict_rule():
    assert verdict(1e-4, 6.0, 10.0) == "fails"
    assert verdict(1e-4, 4.0, 10.0) == "holds"  # significant, smaller than half the noise
    assert verdict(0.01, 60.0, 10.0) == "holds"  # large but not significant
    assert verdict(1e-4, 4.0, 10.0, practical_ratio=0.3) == "fails"


def test_a_bad_direction_label_is_one_line_naming_it():
    ds, _ = sensor_data(np.random.default_rng(16), samples=1)
    with pytest.raises(DataError, match="thermal direction: expected 78 values"):
        hysteresis(ds, np.ones(5))
    with pytest.raises(DataError, match="with others among them"):
        hysteresis(ds, np.full(len(ds), 2.0))


def test_checks_are_plain_data_for_the_calibration_stats():
    ds, direction = sensor_data(np.random.default_rng(17), samples=2)
    for check in model_checks(ds, direction):
        d = check.as_dict()
        assert set(d) >= {"name", "testable", "statistic", "dof", "p", "magnitude_nt", "verdict", "message"}
        assert d["verdict"] in ("holds", "fails", "not testable")
