"""Whether the law of propagation is the whole answer, so that no Monte Carlo is needed (GUM S1 5.8: its
conditions; 7.9.2: the numerical tolerance delta the answer is stated to).

    holds, found = normal_interval_holds(linear, ndig)             # non-normal inputs, linear map
    holds, found, failed = validate_temperature(lin, linear, sources, rng, ndig=ndig)   # T24 / T36

1. Non-normal inputs through a linear map. Every output (a parameter, a field component at a grid point)
   is y = sum_k c_k v_k over the inputs' independent unit parts v_k (q = L v per source), so its
   cumulants add: var y = sum c_k^2, kappa_4(y) = sum c_k^4 kappa_4(v_k) (a rectangular v has -1.2, a
   two-point one -2, a normal 0; every input is symmetric, so y is too). The Cornish-Fisher expansion
   moves the 97.5 % quantile from 1.96 u by (z^3 - 3 z) g2 / 24 u, g2 = kappa_4 / var^2 the excess
   kurtosis. When that is below half the numerical tolerance of u for every output, +-1.96 u is the
   coverage interval to the digits stated, and the field's 95 % radius that of its Gaussian covariance.
2. Temperature changes on T24 / T36 move the regressors: first order only. VALIDATION_DRAWS draws of the
   temperature sources are refitted exactly (calib/uncertainty/mcrefit.py) and compared draw by draw with the
   first-order map; when no parameter strays from it by more than half its tolerance, the map is used
   (the same rule as the scalar fit's, calib.uncertainty.budgeting.validate_scalar).
"""

from __future__ import annotations

import numpy as np

from calib.uncertainty.adaptive import numerical_tolerance
from calib.uncertainty.mcrefit import refit_for

Z_975 = 1.959963984540054
KURTOSIS = {"normal": 0.0, "rectangular": -1.2, "two-point": -2.0}  # excess kurtosis of a unit input
CF_SLOPE = (Z_975**3 - 3 * Z_975) / 24.0  # the quantile's shift per unit excess kurtosis
SHARE = 0.5  # of the numerical tolerance: how far the law of propagation's interval may be off
VALIDATION_DRAWS = 100  # exact refits that check a first-order map (scalar fit, temperature changes)


def unit_draws(rng: np.random.Generator, distribution: str, shape) -> np.ndarray:
    """Independent draws of mean 0 and variance 1 from a source's distribution."""
    if distribution == "rectangular":
        return rng.uniform(-np.sqrt(3.0), np.sqrt(3.0), shape)
    if distribution == "two-point":
        return rng.choice(np.array([-1.0, 1.0]), size=shape)
    return rng.standard_normal(shape)


def covariance_root(cov: np.ndarray) -> np.ndarray:
    """L with L L^T = cov (positive semi-definite), taken on the correlation matrix: the parameters'
    variances span twenty decades (K2 against b), which an eigen-solve of cov itself would not resolve."""
    cov = np.atleast_2d(cov)
    d = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    safe = np.where(d > 0, d, 1.0)
    w, v = np.linalg.eigh(cov / np.outer(safe, safe))
    return d[:, None] * (v * np.sqrt(np.clip(w, 0.0, None)))


def normal_interval_holds(linear, ndig: int, share: float = SHARE) -> tuple[bool, str]:
    """(whether +-1.96 u is every output's 95 % interval to within share x its tolerance, what was found)
    for a LinearBudget whose non-normal sources reach the outputs through its linear maps."""
    rect = [c for c in linear.contributions if c.source is not None
            and KURTOSIS.get(c.source.distribution, 0.0) != 0.0]
    if not rect:
        return True, "every input normal"
    var_p = np.diag(linear.covariance)
    var_f = np.einsum("gii->gi", linear.field_covariance).ravel()
    k4_p, k4_f = np.zeros_like(var_p), np.zeros_like(var_f)
    f_jac = linear.field_jacobian
    for c in rect:
        root = covariance_root(c.source.covariance)
        coef_p = c.jacobian @ root  # (P,K)
        coef_f = np.einsum("gip,pk->gik", f_jac, coef_p)
        if c.grid_effect is not None:
            coef_f = coef_f - np.einsum("giq,qk->gik", c.grid_effect, root)
        kappa = KURTOSIS[c.source.distribution]
        k4_p += kappa * np.sum(coef_p**4, axis=1)
        k4_f += kappa * np.sum(coef_f.reshape(-1, coef_f.shape[2]) ** 4, axis=1)
    worst = 0.0
    for var, k4 in ((var_p, k4_p), (var_f, k4_f)):
        u = np.sqrt(np.clip(var, 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            shift = np.where(u > 0, np.abs(CF_SLOPE * k4 / np.where(u > 0, var, 1.0) ** 2) * u, 0.0)
        delta = numerical_tolerance(u, ndig)
        ratio = np.where(delta > 0, shift / np.where(delta > 0, delta, 1.0), 0.0)
        worst = max(worst, float(np.max(ratio, initial=0.0)))
    holds = worst <= share
    names = ", ".join(c.name for c in rect)
    return holds, (f"{names}: not normal; their kurtosis moves the 95 % intervals by up to {worst:.2g} of "
                   f"the numerical tolerance ({'within' if holds else 'beyond'} {share:g}: "
                   f"{'+-1.96 u holds' if holds else 'Monte Carlo'})")


def validate_temperature(lin, linear, sources, rng: np.random.Generator, *, ndig: int,
                         draws: int = VALIDATION_DRAWS) -> tuple[bool, str, int]:
    """(the first-order map of the temperature sources holds, what was found, refits failed) for T24 /
    T36: `draws` exact refits against J_temp q."""
    parts = [(s, s.sensitivities(lin.ds)[1]) for s in sources]
    parts = [(s, a) for s, a in parts if a is not None]
    if not parts:
        return True, "no temperature source", 0
    qs, mapped = [], np.zeros((draws, linear.layout.size))
    for source, a_temp in parts:
        root = covariance_root(source.covariance)
        q = unit_draws(rng, source.distribution, (draws, root.shape[1])) @ root.T
        qs.append(q)
        mapped += q @ lin.temp_jacobian(a_temp).T
    refit = refit_for(lin, np.column_stack([a for _, a in parts]))
    refitted, failed = refit(np.column_stack(qs))
    off = np.max(np.abs(refitted[~failed] - mapped[~failed]), axis=0, initial=0.0)
    delta = numerical_tolerance(np.sqrt(np.diag(linear.covariance)), ndig)
    ratio = float(np.max(np.where(delta > 0, off / np.where(delta > 0, delta, 1.0), 0.0)))
    holds = ratio <= SHARE and not failed.any()
    return holds, (f"temperature changes: {draws} exact refits stay within {ratio:.2g} of the numerical "
                   f"tolerance of the first-order map ({'it holds' if holds else 'refitting every draw'})"), \
        int(failed.sum())
