"""Residual statistics per group: temperature steps found from gaps, group columns of numbers or text,
each group's RMS as a direct computation over its rows gives it."""

import numpy as np
import pytest

from calib.dataset import Dataset
from calib.stats.residuals import residual_stats, temperature_steps


def test_steps_split_at_gaps_wider_than_one_degree_and_count_from_the_coldest():
    rng = np.random.default_rng(0)
    temps = np.concatenate([rng.uniform(40.0, 40.9, 50), rng.uniform(-10.0, -9.2, 30), [15.0, 15.9, 16.8]])
    order = rng.permutation(temps.size)
    steps, mean_c = temperature_steps(temps[order])
    expected = np.concatenate([np.full(50, 2), np.zeros(30, int), np.ones(3, int)])[order]
    np.testing.assert_array_equal(steps, expected)
    np.testing.assert_allclose(mean_c, [temps[50:80].mean(), temps[80:].mean(), temps[:50].mean()])


def _brute_force(labels, before, after, used, temps):
    out = {}
    for label in dict.fromkeys(labels.tolist()):
        rows = (labels == label) & used
        out[label] = (rows.sum(), np.sqrt(np.mean(before[rows] ** 2)), np.sqrt(np.mean(after[rows] ** 2)),
                      temps[rows].mean())
    return out


@pytest.mark.parametrize("kind", ["text", "numbers"])
def test_each_group_gets_the_rms_of_its_own_used_rows_in_order_of_appearance(kind):
    rng = np.random.default_rng(2)
    n = 600
    ids = rng.integers(0, 5, n)
    labels = np.array([f"T{i}-P{i * 3}" for i in ids], dtype=object) if kind == "text" else ids * 1.0
    h = rng.normal(0, 3e4, (n, 3))
    ref = h + rng.normal(0, 50, (n, 3)) * (1 + ids[:, None])
    field = ref + rng.normal(0, 5, (n, 3)) * (1 + ids[:, None])
    temps = 20.0 + ids + rng.normal(0, 0.1, n)
    used = rng.random(n) > 0.1
    ds = Dataset(h_nt=h, temp_c=temps, ref_nt=ref, group=labels)
    stats = residual_stats(ds, field, vector=True, used=used)["per_group"]
    expected = _brute_force(labels, h - ref, field - ref, used, temps)
    keys = [str(k) if kind == "text" else str(int(k)) for k in expected]
    assert list(stats) == keys
    for key, (count, rms_before, rms_after, temp) in zip(keys, expected.values(), strict=True):
        assert stats[key]["n"] == count
        assert stats[key]["rms_before_nt"] == pytest.approx(rms_before, rel=1e-12)
        assert stats[key]["rms_after_nt"] == pytest.approx(rms_after, rel=1e-12)
        assert stats[key]["temp_c"] == pytest.approx(temp, rel=1e-12)
