"""The design maths (calib/design/optimal.py): known optima on small cases, and predictions the fit
confirms."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from calib.design.optimal import (
    criterion_value,
    exact_design,
    exchange,
    gain_for,
    information,
    optimal_weights,
    std_errors,
    target_ratios,
    worst_parameter,
)
from calib.design.targets import check_targets
from calib.equations import t24_regressors
from calib.errors import DataError, FitError
from calib.models.gram import GramAccumulator
from calib.synthetic import coil_directions, random_t24_params


def fibonacci(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    polar, azimuth = np.arccos(1 - 2 * i / n), np.pi * (1 + 5**0.5) * i
    return np.column_stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)])


@pytest.mark.parametrize("criterion", ["D", "I"])
def test_a_model_linear_in_temperature_puts_half_the_weight_at_each_end(criterion):
    temps = np.linspace(-30.0, 70.0, 21)
    x = np.column_stack([np.ones_like(temps), temps - 20.0])
    w, efficiency = optimal_weights(x, criterion, tol=1e-6)
    assert efficiency >= 1 - 1e-6
    assert w[0] == pytest.approx(0.5, abs=2e-3) and w[-1] == pytest.approx(0.5, abs=2e-3)
    assert w[1:-1].sum() < 5e-3


def test_d_optimal_directions_for_a_linear_map_have_an_isotropic_second_moment():
    h = fibonacci(150)  # model B = S h: x = h, three parameters per axis
    w, efficiency = optimal_weights(h, "D", tol=1e-5)
    moment = (h * w[:, None]).T @ h
    assert efficiency >= 1 - 1e-5
    np.testing.assert_allclose(moment, np.eye(3) / 3, atol=2e-3)
    axes = np.vstack([np.eye(3), -np.eye(3), coil_directions(26)])  # +-x, +-y, +-z among other candidates
    w, _ = optimal_weights(axes, "D", tol=1e-6)
    np.testing.assert_allclose((axes * w[:, None]).T @ axes, np.eye(3) / 3, atol=1e-4)


def test_t24_d_optimum_is_the_largest_field_balanced_at_the_two_ends_of_the_range():
    temps = np.linspace(-30.0, 70.0, 11)
    dirs = coil_directions(26)
    fields = np.vstack([30_000 * dirs, 60_000 * dirs])
    f, t = (np.array(a) for a in zip(*itertools.product(fields, temps), strict=True))
    x = t24_regressors(f, t, 20.0)
    w, efficiency = optimal_weights(x, "D", tol=1e-4)
    assert efficiency >= 1 - 1e-4
    big = np.linalg.norm(f, axis=1) > 45_000
    ends = (t == -30.0) | (t == 70.0)
    assert w[big & ends].sum() > 0.995
    assert w[(t == -30.0)].sum() == pytest.approx(0.5, abs=5e-3)
    # the optimum beats the plain full factorial, and the I-optimum (over the same grid) does too
    uniform = np.full(len(x), 1 / len(x))
    assert criterion_value(x, w, "D") > criterion_value(x, uniform, "D") + 1.0
    wi, eff_i = optimal_weights(x, "I", tol=1e-3)
    assert eff_i >= 1 - 1e-3
    assert criterion_value(x, wi, "I") < 0.8 * criterion_value(x, uniform, "I")


def test_predicted_standard_errors_are_the_fits_own_for_the_same_samples():
    rng = np.random.default_rng(4)
    p = random_t24_params(rng)
    fields = 50_000 * np.repeat(coil_directions(26), 20, axis=0)
    temps = np.tile(np.repeat([-20.0, 25.0, 60.0], 1), len(fields) // 3 + 1)[: len(fields)]
    h = np.array([np.linalg.solve(p["S"] + t * p["K"], b - p["b_nt"] - t * p["kb_nt_per_c"])
                  for b, t in zip(fields, temps, strict=True)]) + rng.normal(0, 25, fields.shape)
    acc = GramAccumulator(22.0)
    acc.add(h, temps, fields)
    cal = acc.solve()
    sigma = np.array([cal.stats["sigma_nt"][a] for a in "xyz"])
    predicted = std_errors(acc.gram[:8, :8], sigma, 22.0)
    for key, value in cal.std_errors.items():
        np.testing.assert_allclose(predicted[key], value, rtol=1e-9)
    targets = {"S": 1e-4, "K": 2e-6, "b": 3.0, "kb": 0.05}
    ratios = target_ratios(acc.gram[:8, :8], sigma, 22.0, targets)
    status = check_targets(acc, targets)
    np.testing.assert_allclose(ratios, [status.ratios[g] for g in targets], rtol=1e-9)


def test_predicted_standard_errors_match_the_scatter_of_repeated_fits():
    rng = np.random.default_rng(11)
    p = random_t24_params(rng)
    fields = 45_000 * np.tile(coil_directions(26), (6, 1))
    temps = np.repeat(np.linspace(-30, 70, 6), 26)
    clean = np.array([np.linalg.solve(p["S"] + t * p["K"], b - p["b_nt"] - t * p["kb_nt_per_c"])
                      for b, t in zip(fields, temps, strict=True)])
    fits = []
    for _ in range(300):
        acc = GramAccumulator(20.0)
        acc.add(clean + rng.normal(0, 30, clean.shape), temps, fields)
        fits.append(acc.solve().params)
    predicted = std_errors(information(clean, temps, temp_ref_c=20.0), 30.0, 20.0)
    for key in ("S", "K", "b_nt", "kb_nt_per_c"):
        scatter = np.std([f[key] for f in fits], axis=0)
        ratio = scatter / predicted[key]
        assert 0.85 < ratio.mean() < 1.15, key


def test_gain_is_the_drop_in_variance_of_the_parameter():
    temps = np.repeat([-30.0, 70.0], 26)
    fields = 50_000 * np.tile(coil_directions(26), (2, 1))
    g = information(fields, temps, 5, temp_ref_c=20.0)
    group, row = worst_parameter(g, 20.0, {"K": 1e-6, "S": 1e-3})
    assert group == "K" and row in (5, 6, 7)
    cands = t24_regressors(50_000 * coil_directions(26), np.full(26, 70.0), 20.0)
    gains = gain_for(g, 20.0, row, cands, 10)
    before = std_errors(g, 1.0, 20.0)["K"].max() ** 2
    for k in (0, int(np.argmax(gains))):
        after_g = g + 10 * np.outer(cands[k], cands[k])
        from calib.design.optimal import covariance

        drop = covariance(g, 20.0)[row, row] - covariance(after_g, 20.0)[row, row]
        assert drop == pytest.approx(gains[k], rel=1e-6)
    assert before > 0


def test_exact_design_rounds_to_the_count_keeping_proportions():
    w = np.array([0.5, 0.25, 0.25, 1e-9])
    counts = exact_design(w, 8)
    assert counts.tolist() == [4, 2, 2, 0]
    assert exact_design(np.full(24, 1 / 24), 12).sum() == 12
    assert exact_design(w, 3).sum() == 3


def test_an_unidentifiable_design_gives_infinite_errors_and_bad_input_is_refused():
    fields = 50_000 * coil_directions(26)
    g = information(fields, np.full(26, 25.0), temp_ref_c=20.0)  # one temperature: K, kb unknown
    se = std_errors(g, 20.0, 20.0)
    assert np.all(np.isinf(se["K"]))
    with pytest.raises(DataError, match="criterion"):
        optimal_weights(t24_regressors(fields, np.zeros(26), 0.0), "A")
    with pytest.raises(DataError, match="candidates"):
        optimal_weights(np.ones((3, 8)))
    with pytest.raises(FitError, match="zero on every candidate"):
        optimal_weights(np.column_stack([np.ones(10), np.zeros(10)]))
    with pytest.raises(DataError, match="sigma"):
        std_errors(g, -1.0, 20.0)


@pytest.mark.parametrize("criterion", ["D", "I"])
def test_exchange_finds_a_balanced_isotropic_sweep_among_many_directions(criterion):
    dirs = fibonacci(200)
    x = np.column_stack([np.ones(200), 50_000 * dirs])  # [1, h]: offset and scale of one axis
    rng = np.random.default_rng(2)
    start = rng.choice(200, 12, replace=False)
    design = exchange(x, 12, criterion, start=start)
    assert len(set(design.tolist())) == 12
    chosen = dirs[design]
    np.testing.assert_allclose(chosen.mean(axis=0), 0, atol=0.03)  # balanced: offsets separate from S
    np.testing.assert_allclose(chosen.T @ chosen / 12, np.eye(3) / 3, atol=0.03)
    m_start, m_end = (x[i].T @ x[i] for i in (start, design))
    assert np.linalg.slogdet(m_end)[1] > np.linalg.slogdet(m_start)[1]


@pytest.mark.parametrize("criterion", ["D", "I"])
def test_exchange_asked_for_every_candidate_takes_them_all(criterion):
    """A plan whose fields were designed already is designed again: its sweep is every one of them."""
    x = np.column_stack([np.ones(12), 50_000 * fibonacci(12)])
    assert exchange(x, 12, criterion).tolist() == list(range(12))
