"""Coverage factors from degrees of freedom: Student's t and the Welch-Satterthwaite formula (GUM, JCGM
100 §G.3, G.4).

    nu = effective_dof(u2, [(part_variance, part_dof), ...])   # G.4.1
    k = coverage_factor(nu)                                     # t_p(nu), p = 95.45 %: 2 when nu is large
    t = t_quantile(0.975, nu)                                   # one-sided quantile
    widening(nu)                                                # t_97.5(nu) / 1.96

An input whose standard uncertainty is estimated from a few readings (Type A: the ambient's scatter from
its five or six measurements in a run) is itself uncertain; a combined uncertainty that it dominates
then needs a larger k for the same coverage. The probability 95.45 % is the one for which k = 2 with
infinite degrees of freedom (GUM Table G.2), so a budget of well-known inputs keeps k = 2.

No scipy: the t distribution's CDF is the regularized incomplete beta function, by its continued
fraction (modified Lentz), and its quantile is found by Newton's method from the Cornish-Fisher
expansion (bisection where that fails). Degrees of freedom are truncated to an integer (G.4.1 note 1),
so each is worked out once.
"""

from __future__ import annotations

import math
from functools import lru_cache

from calib.stats.distributions import betainc

P_K2 = math.erf(math.sqrt(2.0))  # 95.45 %, GUM Table G.2: the probability for which t_p(inf) = 2 exactly
NORMAL_DOF = 10_000  # beyond, t differs from the normal by less than 2e-4 relative: taken as infinite


def effective_dof(total_variance: float, parts) -> float:
    """Welch-Satterthwaite (G.2b): u_c^4 / sum(u_i^4 / nu_i) over the parts (variance, dof) with a finite
    dof; infinite when there is none, the total is zero, or it exceeds NORMAL_DOF."""
    denominator = sum(v * v / dof for v, dof in parts if math.isfinite(dof) and dof > 0 and v > 0)
    if denominator <= 0 or total_variance <= 0:
        return math.inf
    dof = total_variance * total_variance / denominator
    return math.inf if dof > NORMAL_DOF else dof


def coverage_factor(dof: float, probability: float = P_K2) -> float:
    """k = t_p(nu): the half-width of the central interval of probability p, in standard deviations (2
    for infinite nu at the default p)."""
    if probability == P_K2 and (not math.isfinite(dof) or dof > NORMAL_DOF):
        return 2.0  # exactly: the convention the probability was chosen for
    return t_quantile(0.5 + probability / 2.0, dof)


def widening(dof: float) -> float:
    """How much a 95 % interval made for known inputs (+-1.96 u) widens with `dof`: t_97.5(nu) / 1.96."""
    return t_quantile(0.975, dof) / t_quantile(0.975, math.inf)


def t_quantile(p: float, dof: float) -> float:
    """The p quantile (p > 0.5) of Student's t with `dof` degrees of freedom (truncated to an integer, at
    least 1; infinite or beyond NORMAL_DOF: the normal's)."""
    if not 0.5 < p < 1.0:
        raise ValueError(f"t_quantile: p {p!r} must be in (0.5, 1)")
    nu = NORMAL_DOF + 1 if not math.isfinite(dof) or dof > NORMAL_DOF else max(int(dof), 1)
    return _quantile(round(p, 12), nu)


@lru_cache(maxsize=512)
def _quantile(p: float, nu: int) -> float:
    if nu > NORMAL_DOF:
        return _normal_quantile(p)
    if nu == 1:
        return math.tan(math.pi * (p - 0.5))
    central = 2.0 * p - 1.0  # P(|T| <= t)
    t = _cornish_fisher(_normal_quantile(p), nu)
    for _ in range(20):  # Newton from the expansion: two or three steps; each costs one incomplete beta
        step = (_central(t, nu) - central) / (2.0 * _density(t, nu))
        if not math.isfinite(step) or t - step <= 0.0:
            break
        t -= step
        if abs(step) <= 1e-13 * t:
            return t
    return _bisect(central, nu)


def _cornish_fisher(z: float, nu: int) -> float:
    """t_p(nu) from the normal quantile z by its expansion in 1/nu (Abramowitz & Stegun 26.7.5): within
    1e-6 relative from nu = 10, a start for Newton below."""
    z2 = z * z
    g1 = z * (z2 + 1.0) / 4.0
    g2 = z * ((5.0 * z2 + 16.0) * z2 + 3.0) / 96.0
    g3 = z * (((3.0 * z2 + 19.0) * z2 + 17.0) * z2 - 15.0) / 384.0
    g4 = z * ((((79.0 * z2 + 776.0) * z2 + 1482.0) * z2 - 1920.0) * z2 - 945.0) / 92160.0
    return z + (g1 + (g2 + (g3 + g4 / nu) / nu) / nu) / nu


def _density(t: float, nu: int) -> float:
    """Student's t probability density."""
    log_norm = math.lgamma(0.5 * (nu + 1)) - math.lgamma(0.5 * nu) - 0.5 * math.log(nu * math.pi)
    return math.exp(log_norm - 0.5 * (nu + 1) * math.log1p(t * t / nu))


def _bisect(central: float, nu: int) -> float:
    """The quantile by bisection: slow but sure, where Newton did not converge."""
    lo, hi = 0.0, 1.0
    while _central(hi, nu) < central:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _central(mid, nu) < central:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hi:
            break
    return 0.5 * (lo + hi)


def _central(t: float, nu: int) -> float:
    """P(|T| <= t) = 1 - I_x(nu/2, 1/2), x = nu / (nu + t^2)."""
    return 1.0 - betainc(0.5 * nu, 0.5, nu / (nu + t * t))



def _normal_quantile(p: float) -> float:
    """The standard normal's p quantile, by bisection on erf (p in (0.5, 1))."""
    lo, hi = 0.0, 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if 0.5 * (1.0 + math.erf(mid / math.sqrt(2.0))) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
