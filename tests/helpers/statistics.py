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
