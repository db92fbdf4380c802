"""The adaptive Monte Carlo procedure of GUM S1 7.9 (calib/uncertainty/adaptive.py): its tolerance, its
stopping rule, its coverage intervals and how it counts failed draws."""

from __future__ import annotations

import numpy as np
import pytest

from calib.uncertainty.adaptive import adaptive_monte_carlo, numerical_tolerance, shortest_interval


def normal_batch(rng, m):
    """Values: N(0, 1) and N(0, 3^2); lengths: |N(0, I3)|; nothing fails."""
    values = rng.standard_normal((m, 2)) * [1.0, 3.0]
    return values, np.linalg.norm(rng.standard_normal((m, 4, 3)), axis=2), np.zeros(m, bool)


def test_numerical_tolerance_is_half_a_unit_in_the_last_asked_digit():
    np.testing.assert_allclose(numerical_tolerance([0.0234, 3.4, 99.0, 1.0e-7, 0.0], 2),
                               [0.0005, 0.05, 0.5, 0.5e-8, 0.0])
    np.testing.assert_allclose(numerical_tolerance([0.0234, 3.4, 9.9], 1), [0.005, 0.5, 0.5])


def test_it_stops_at_the_first_batch_where_twice_every_spread_is_within_the_tolerance():
    """The rule recomputed here from the same draws with numpy's quantiles: per batch the mean, u, the 2.5
    and 97.5 % quantiles of each value and the 95 % quantile of each length; the standard deviation of
    their average over h batches, doubled, against delta from the average u (and average length
    quantile) with ndig digits."""
    result = adaptive_monte_carlo(normal_batch, np.random.default_rng(1), ndig=2, batch_size=1000,
                                  interval="symmetric")
    rng = np.random.default_rng(1)
    rows, stop = [], None
    for h in range(1, result.batches + 1):
        values, lengths, _ = normal_batch(rng, 1000)
        ends = np.quantile(values, [0.025, 0.975], axis=0)
        top = np.quantile(lengths, 0.95, axis=0)
        rows.append(np.concatenate([values.mean(0), values.std(0, ddof=1), *ends, top]))
        if h >= 2:
            est = np.array(rows)
            avg = est.mean(axis=0)
            delta = np.concatenate([np.tile(numerical_tolerance(avg[2:4], 2), 4),
                                    numerical_tolerance(avg[8:], 2)])
            if np.all(2 * est.std(axis=0, ddof=1) / np.sqrt(h) <= delta):
                stop = h
                break
    assert result.converged and stop == result.batches and result.draws == 1000 * stop
    assert result.u == pytest.approx([1.0, 3.0], rel=0.03)
    np.testing.assert_allclose(result.low, [-1.96, -5.88], rtol=0.05)
    assert result.length_quantile == pytest.approx(np.full(4, 2.7955), rel=0.03)


def test_the_draws_it_may_not_exceed_are_stated():
    result = adaptive_monte_carlo(normal_batch, np.random.default_rng(2), ndig=3, batch_size=1000,
                                  max_draws=5000)
    assert not result.converged and result.draws == 5000 and "not met within 5000 draws" in result.message


def test_failed_draws_are_counted_and_too_many_stop_the_statement():
    def failing(share):
        def batch(rng, m):
            values, lengths, _ = normal_batch(rng, m)
            failed = np.zeros(m, bool)
            failed[: int(share * m)] = True
            values[failed] = 1e9  # what a failed refit would give: it must not reach the figures
            return values, lengths, failed
        return batch

    few = adaptive_monte_carlo(failing(0.005), np.random.default_rng(3), ndig=1, batch_size=2000)
    assert few.stated and few.failed == 10 * few.batches
    assert "refits failed (0.5 % of the draws)" in few.message
    assert np.all(np.abs(few.high) < 10)
    many = adaptive_monte_carlo(failing(0.05), np.random.default_rng(3), ndig=1, batch_size=2000)
    assert not many.stated and many.failed == 100 * many.batches
    assert "the uncertainty cannot be stated" in many.message


def test_a_skewed_output_gets_the_shortest_interval():
    def skewed(rng, m):
        values = np.column_stack([rng.exponential(1.0, m), rng.standard_normal(m)])
        return values, np.ones((m, 1)), np.zeros(m, bool)

    result = adaptive_monte_carlo(skewed, np.random.default_rng(4), ndig=1, batch_size=10_000)
    assert list(result.shortest) == [True, False]
    assert result.low[0] == pytest.approx(0.0, abs=0.01)
    assert result.high[0] == pytest.approx(-np.log(0.05), rel=0.03)  # shortest 95 % of Exp(1): [0, 3.0]
    low, high = shortest_interval(np.sort(np.array([[0.0], [1.0], [1.1], [1.2], [5.0]]), axis=0), 0.6)
    assert (low[0], high[0]) == (1.0, 1.2)
