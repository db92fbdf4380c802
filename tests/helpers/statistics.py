"""Bounds for statistical assertions that fail by chance less than once in FALSE_ALARM**-1 runs."""

from __future__ import annotations

from statistics import NormalDist

import numpy as np

FALSE_ALARM = 1e-4  # the chance that an assertion fails on correct code, over all the values it checks


def z_bound(n: int, false_alarm: float = FALSE_ALARM) -> float:
    """|z| that any of n standard-normal values exceeds with probability below `false_alarm`
    (Bonferroni: each gets false_alarm / n, two-sided)."""
    return NormalDist().inv_cdf(1.0 - false_alarm / (2.0 * n))


def assert_within_std_errors(found: dict[str, np.ndarray]) -> None:
    """Every z = (estimate - truth) / standard error in `found` ({label: z array}) within the bound for
    all of them together."""
    total = sum(np.size(z) for z in found.values())
    bound = z_bound(total)
    worst = {label: float(np.max(np.abs(z))) for label, z in found.items()}
    assert max(worst.values()) < bound, f"|z| above {bound:.2f} (n = {total}): {worst}"


def chi2_quantile(q: float, dof: int) -> float:
    """The q-quantile of chi-square with `dof` degrees of freedom (Wilson-Hilferty: within a fraction of
    a percent for dof above 30, ample for a test's bound)."""
    z = NormalDist().inv_cdf(q)
    return dof * (1.0 - 2.0 / (9.0 * dof) + z * (2.0 / (9.0 * dof)) ** 0.5) ** 3


def sigma_bounds(true_sigma: float, dof: int, n: int = 1,
                 false_alarm: float = FALSE_ALARM) -> tuple[float, float]:
    """(low, high) that a residual sigma estimated with `dof` degrees of freedom leaves, any of `n` such
    estimates, with probability below `false_alarm`."""
    tail = false_alarm / (2.0 * n)
    return (true_sigma * (chi2_quantile(tail, dof) / dof) ** 0.5,
            true_sigma * (chi2_quantile(1.0 - tail, dof) / dof) ** 0.5)
