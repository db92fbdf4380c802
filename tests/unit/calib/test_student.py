"""Coverage factors from degrees of freedom: Student's t against GUM Table G.2, Welch-Satterthwaite, and a
budget whose dominant input is estimated from three readings covering its truth as often as it states."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.stats import student
from calib.stats.student import NORMAL_DOF, P_K2, coverage_factor, effective_dof, t_quantile
from calib.uncertainty.budgeting import budget
from calib.uncertainty.propagation import Estimated, offset_source

# GUM (JCGM 100:2008) Table G.2, p = 95.45 %
TABLE_G2 = {1: 13.97, 2: 4.53, 3: 3.31, 4: 2.87, 5: 2.65, 6: 2.52, 7: 2.43, 8: 2.37, 10: 2.28, 20: 2.13,
            50: 2.05, 100: 2.025, math.inf: 2.000}


@pytest.mark.parametrize("dof, k", TABLE_G2.items())
def test_the_coverage_factor_is_gums_table(dof, k):
    assert coverage_factor(dof) == pytest.approx(k, abs=0.006)


def test_t_quantiles_and_their_limits():
    assert t_quantile(0.975, 1) == pytest.approx(12.7062, abs=1e-4)
    assert t_quantile(0.975, 4) == pytest.approx(2.7764, abs=1e-4)
    assert t_quantile(0.975, 30) == pytest.approx(2.0423, abs=1e-4)
    assert t_quantile(0.975, math.inf) == pytest.approx(1.959964, abs=1e-6)
    assert t_quantile(0.975, 4.9) == t_quantile(0.975, 4)  # truncated to an integer (G.4.1 note 1)
    with pytest.raises(ValueError, match="p 0.3"):
        t_quantile(0.3, 4)


@pytest.mark.parametrize("nu", [2, 3, 5, 9, 10, 31, 250, 4000, NORMAL_DOF])
@pytest.mark.parametrize("p", [0.6, 0.975, 0.5 + P_K2 / 2, 0.9995])
def test_the_newton_quantile_is_the_one_bisection_finds(nu, p):
    """Each quantile solves P(|T| <= t) = 2p - 1 to 1e-10, whichever way it is found."""
    t = t_quantile(p, nu)
    assert student._central(t, nu) == pytest.approx(2 * p - 1, abs=1e-10)
    assert t == pytest.approx(student._bisect(2 * p - 1, nu), rel=1e-9)


def test_welch_satterthwaite():
    # two equal parts, one with 4 degrees of freedom, one known: 4 (1 + 1)^2 / 1 = 16
    assert effective_dof(2.0, [(1.0, 4), (1.0, math.inf)]) == pytest.approx(16.0)
    assert effective_dof(1.0, [(1.0, math.inf)]) == math.inf
    assert effective_dof(1.0, [(1e-4, 4)]) == math.inf  # 4e8: as good as known
    assert coverage_factor(math.inf) == 2.0 and coverage_factor(1e6) == 2.0
    assert effective_dof(3.0, [(1.0, 2), (2.0, 8)]) == pytest.approx(9.0 / (1 / 2 + 4 / 8))


def test_a_budget_dominated_by_a_three_reading_estimate_covers_its_truth():
    """An offset the references miss, whose size is known only from three readings of it (2 degrees of
    freedom): b absorbs it. Its estimate s being itself off, b's error / u is t-distributed; k = 2 covers
    it about 82 % of the time, the k the effective degrees of freedom give about 95 %."""
    rng = np.random.default_rng(7)
    ds, _ = synthetic.t24_dataset(rng, temps_c=(-20.0, 60.0))
    truth = calib.fit(ds, "t24")  # the calibration of references without the offset
    fields = 50_000.0 * synthetic.coil_directions()
    grid = (fields, np.full(len(fields), 25.0))
    sigma_nt, covered, covered_k2, ks = 300.0, 0, 0, []
    trials = 300
    for _ in range(trials):
        offset = rng.normal(0.0, sigma_nt, 3)  # the field the references missed
        readings = rng.normal(0.0, sigma_nt, (3, 3))  # how the lab saw it scatter
        s2 = np.var(readings, axis=0, ddof=1)
        source = offset_source("ambient", len(ds), np.diag(s2),
                               estimated=tuple(Estimated(np.array([i]), s2[i:i + 1], 2) for i in range(3)))
        moved = dataclasses.replace(ds, ref_nt=ds.ref_nt - offset)  # the references miss it
        cal = calib.fit(moved, "t24")
        b = budget(moved, cal, [source], grid, rng=rng, monte_carlo="never")
        error = np.abs(cal.params["b_nt"] - truth.params["b_nt"])
        covered += int(error[0] <= b.expanded["b_nt"][0])
        covered_k2 += int(error[0] <= 2.0 * b.standard["b_nt"][0])
        ks.append(float(np.ravel(b.coverage_factors["b_nt"])[0]))
    assert 4.0 < np.median(ks) < 4.6  # about t_95.45(2) = 4.53: the estimate dominates
    assert covered / trials >= 0.92
    assert covered_k2 / trials <= 0.88  # the test can tell the two apart
