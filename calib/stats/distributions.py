"""The few distribution functions calib's statistics need, in plain numpy and math (calib has no scipy).

- `f_sf(x, d1, d2)`: the F distribution's upper tail, P(F > x) (the model checks' nested-model tests);
- `chi2_sf(x, k)`: the chi-square upper tail;
- `gaussian_radius(cov, p)`: the radius r with P(|e| <= r) = p for a 3-D Gaussian error e ~ N(0, cov), a
  stack of covariances at once (the expanded vector error of a calibrated field at each grid point).

The incomplete beta and gamma functions are evaluated by their continued fractions (modified Lentz)
and series to ~1e-14; erf by a rational Chebyshev fit good to 1.2e-7; the radius to ~1e-6 relative (a
144-node product rule over one octant of the sphere, Newton steps).
"""

from __future__ import annotations

import math

import numpy as np

_EPS = 1e-15
_TINY = 1e-300
_MAX_TERMS = 10_000


def _beta_cf(a: float, b: float, x: float) -> float:
    """The continued fraction of the incomplete beta function (Numerical Recipes' betacf, Lentz)."""
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > _TINY else _TINY)
    h = d
    for m in range(1, _MAX_TERMS):
        m2 = 2 * m
        even = m * (b - m) * x / ((qam + m2) * (a + m2))
        odd = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        for aa in (even, odd):
            d = 1.0 + aa * d
            d = 1.0 / (d if abs(d) > _TINY else _TINY)
            c = 1.0 + aa / c
            c = c if abs(c) > _TINY else _TINY
            h *= d * c
        if abs(d * c - 1.0) < _EPS:
            break
    return h


def betainc(a: float, b: float, x: float) -> float:
    """The regularised incomplete beta function I_x(a, b)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = (math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x)
                 + b * math.log1p(-x))
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _beta_cf(a, b, x) / a
    return 1.0 - math.exp(log_front) * _beta_cf(b, a, 1.0 - x) / b


def f_sf(x: float, d1: float, d2: float) -> float:
    """P(F > x) for an F(d1, d2) variable."""
    if not x > 0.0:
        return 1.0
    return betainc(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * x))


def _gamma_p_series(a: float, x: float) -> float:
    term = total = 1.0 / a
    ap = a
    for _ in range(_MAX_TERMS):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * math.exp(-x + a * math.log(x) - math.lgamma(a))


def _gamma_q_cf(a: float, x: float) -> float:
    b = x + 1.0 - a
    c, d = 1.0 / _TINY, 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = 1.0 / (d if abs(d) > _TINY else _TINY)
        c = b + an / c
        c = c if abs(c) > _TINY else _TINY
        h *= d * c
        if abs(d * c - 1.0) < _EPS:
            break
    return math.exp(-x + a * math.log(x) - math.lgamma(a)) * h


def chi2_sf(x: float, k: float) -> float:
    """P(chi2_k > x): the regularised upper incomplete gamma Q(k/2, x/2)."""
    if not x > 0.0:
        return 1.0
    a, half = 0.5 * k, 0.5 * x
    if half < a + 1.0:
        return max(0.0, 1.0 - _gamma_p_series(a, half))
    return _gamma_q_cf(a, half)


def erf(x: np.ndarray) -> np.ndarray:
    """erf of an array (Numerical Recipes' erfcc Chebyshev fit, fractional error below 1.2e-7)."""
    z = np.abs(x)
    t = 1.0 / (1.0 + 0.5 * z)
    poly = -z * z - 1.26551223 + t * (1.00002368 + t * (0.37409196 + t * (0.09678418 + t * (
        -0.18628806 + t * (0.27886807 + t * (-1.13520398 + t * (1.48851587 + t * (
            -0.82215223 + t * 0.17087277))))))))
    return np.sign(x) * (1.0 - t * np.exp(poly))


def chi3_cdf(r2: np.ndarray) -> np.ndarray:
    """P(chi2_3 <= r2) in closed form."""
    r2 = np.maximum(r2, 0.0)
    return erf(np.sqrt(0.5 * r2)) - np.sqrt(2.0 * r2 / np.pi) * np.exp(-0.5 * r2)


def _octant_rule(n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (squared direction cosines, (M,3)) and weights (sum 1) averaging a function of u_i^2 over
    the unit sphere: Gauss-Legendre in cos(theta) on [0, 1] and in phi on [0, pi/2] (one octant covers
    the sphere for functions of u_i^2)."""
    x, w = np.polynomial.legendre.leggauss(n)
    mu, w_mu = 0.5 * (x + 1.0), 0.5 * w
    phi, w_phi = 0.25 * np.pi * (x + 1.0), 0.25 * np.pi * w
    m, p = np.meshgrid(mu, phi, indexing="ij")
    s2 = 1.0 - m * m
    u2 = np.stack([s2 * np.cos(p) ** 2, s2 * np.sin(p) ** 2, m * m], axis=-1).reshape(-1, 3)
    weights = np.outer(w_mu, w_phi).ravel() * (2.0 / np.pi)
    return u2, weights


_U2, _W = _octant_rule()
_R2_95_1D, _R2_95_3D = 1.959963984540054**2, 2.795483482915108**2  # the 95 % quantiles of |z| in 1-D, 3-D


def gaussian_radius(cov: np.ndarray, p: float = 0.95, iterations: int = 8) -> np.ndarray:
    """Radius r with P(|e| <= r) = p for e ~ N(0, cov), cov (..., 3, 3): the coverage radius of a 3-D
    error. With lam the eigenvalues, |e|^2 = r_u^2 q(u) along the direction u, q(u) = sum lam_i u_i^2
    and r_u^2 chi-square with 3 dof: P(|e| <= r) = mean over the sphere of chi3_cdf(r^2 / q(u)), taken
    by quadrature. r by Newton steps kept inside the bracket a 1-D and an isotropic error of the largest
    eigenvalue give (for p = 0.95, [1.96, 2.80] sqrt(lam_max); else [0, 6 sqrt(lam_max)])."""
    lam = np.clip(np.linalg.eigvalsh(np.asarray(cov, float)), 0.0, None)
    shape = lam.shape[:-1]
    lam = lam.reshape(-1, 3)
    zero = lam[:, -1] <= 0
    lam[zero] = 1.0  # no error at all: radius 0, set below
    top = lam[:, -1]
    inv_q = 1.0 / np.maximum(lam @ _U2.T, np.finfo(float).tiny)  # (G, M)
    if p == 0.95:  # a little wider than the exact bounds, which the quadrature meets only to ~1e-9
        lo, hi = 0.999 * np.sqrt(_R2_95_1D * top), 1.001 * np.sqrt(_R2_95_3D * top)
        r = np.clip(_moment_matched_95(lam), lo, hi)
    else:
        lo, hi = np.zeros_like(top), 6.0 * np.sqrt(top)
        r = 0.5 * (lo + hi)
    for _ in range(iterations):
        x = (r * r)[:, None] * inv_q
        cdf = chi3_cdf(x) @ _W
        if np.all(np.abs(cdf - p) <= P_SOLVED):  # below what the quadrature resolves: done
            break
        # d cdf / d r = mean of pdf_chi3(x) 2 r / q, pdf_chi3(x) = sqrt(x / (2 pi)) exp(-x / 2)
        slope = (np.sqrt(x / (2.0 * np.pi)) * np.exp(-0.5 * x) * 2.0 * r[:, None] * inv_q) @ _W
        below = cdf < p
        lo, hi = np.where(below, r, lo), np.where(below, hi, r)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = r + (p - cdf) / slope
        r = np.where((step >= lo) & (step <= hi), step, 0.5 * (lo + hi))
    return np.where(zero, 0.0, r).reshape(shape)


P_SOLVED = 1e-12  # |P(r) - p| at which the radius is taken as found (the quadrature is good to ~1e-9)
_Z_95_ONE_SIDED = 1.6448536269514722


def _moment_matched_95(lam: np.ndarray) -> np.ndarray:
    """A start for the 95 % radius (G,) from the eigenvalues (G,3): |e|^2 taken as c chi-square with nu
    dof of its own mean and variance (Satterthwaite), its quantile by Wilson and Hilferty's cube root.
    Within a few per cent, so that Newton's steps meet the quadrature's answer in three or four."""
    s1, s2 = lam.sum(axis=1), (lam * lam).sum(axis=1)
    c, nu = s2 / s1, s1 * s1 / s2
    a = 2.0 / (9.0 * nu)
    return np.sqrt(c * nu * (1.0 - a + _Z_95_ONE_SIDED * np.sqrt(a)) ** 3)


def _sphere_rule(n: int = 10, m: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """(directions (n m, 3), weights) averaging a smooth function over the whole unit sphere:
    Gauss-Legendre in cos(theta) times the trapezoid rule in phi (its weights folded into a repeat)."""
    x, w = np.polynomial.legendre.leggauss(n)
    phi = 2.0 * np.pi * np.arange(m) / m
    mu, p = np.meshgrid(x, phi, indexing="ij")
    s = np.sqrt(1.0 - mu * mu)
    u = np.stack([s * np.cos(p), s * np.sin(p), mu], axis=-1).reshape(-1, 3)
    return u, np.repeat(0.5 * w / m, m)


_SPHERE_U, _SPHERE_W = _sphere_rule()
P_TOLERANCE = 2e-6
_CHI3_PDF = np.sqrt(2.0 / np.pi)  # the chi distribution's (3 dof) density is this x rho^2 exp(-rho^2 / 2)


def shifted_radius(cov: np.ndarray, shifts: np.ndarray, p: float = 0.95, iterations: int = 30) -> np.ndarray:
    """Radius r with P(|e| <= r) = p for e = x + c, x ~ N(0, cov[n]) (N,3,3) and c one of `shifts` (S,3),
    each equally likely: a normal error beside a state that is one way or another. Along a direction u,
    x = rho R u (R R^T = cov, rho^2 chi-square with 3 dof), so |e| <= r holds for rho between the roots
    of rho^2 |Ru|^2 + 2 rho (Ru . c) + |c|^2 - r^2: P is the chi-square's mass between them, averaged over
    the sphere (_sphere_rule) and the shifts. r by Newton steps kept inside a shrinking bracket, until P
    is within P_TOLERANCE of p (r then within about 1e-5 of itself)."""
    cov = np.asarray(cov, float)
    lam, vec = np.linalg.eigh(cov)
    lam = np.clip(lam, 0.0, None)
    root = vec * np.sqrt(lam)[:, None, :]
    ru = np.einsum("nij,dj->ndi", root, _SPHERE_U)  # (N,D,3)
    a = np.maximum(np.einsum("ndi,ndi->nd", ru, ru), np.finfo(float).tiny)[:, None, :]  # (N,1,D)
    shifts = np.atleast_2d(np.asarray(shifts, float))
    b = np.einsum("ndi,si->nsd", ru, shifts)  # (N,S,D)
    cc = np.einsum("si,si->s", shifts, shifts)[None, :, None]  # (1,S,1)

    def coverage(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P(|e| <= r), dP/dr): the roots move by +-r / sqrt(disc) as r grows."""
        disc = b * b - a * (cc - (r * r)[:, None, None])
        real = disc > 0
        width = np.sqrt(np.where(real, disc, 0.0))
        upper = np.where(real, np.maximum((-b + width) / a, 0.0), 0.0)
        lower = np.where(real, np.maximum((-b - width) / a, 0.0), 0.0)
        mass = chi3_cdf(upper * upper) - chi3_cdf(lower * lower)
        density = _CHI3_PDF * (upper * upper * np.exp(-0.5 * upper * upper)
                               + lower * lower * np.exp(-0.5 * lower * lower))
        slope = np.where(real, density * r[:, None, None] / np.where(real, width, 1.0), 0.0)
        return np.mean(mass @ _SPHERE_W, axis=1), np.mean(slope @ _SPHERE_W, axis=1)

    lo, hi = np.zeros(len(cov)), np.sqrt(np.max(cc)) + 3.0 * np.sqrt(lam[:, -1]) + 1e-9  # P(hi) > 0.97
    r = np.minimum(np.sqrt(np.max(cc) + _R2_95_3D * lam.mean(axis=1)), hi)  # an isotropic normal's, shifted
    for _ in range(iterations):
        f, slope = coverage(r)
        f -= p
        going = np.abs(f) > P_TOLERANCE  # a row within the tolerance stays (shifted_interval)
        if not going.any():
            break
        below = f < 0
        lo, hi = np.where(below, r, lo), np.where(below, hi, r)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = r - f / slope
        r = np.where(going, np.where((step > lo) & (step < hi), step, 0.5 * (lo + hi)), r)
    return r


def shifted_interval(sigma: np.ndarray, shifts: np.ndarray, p: float = 0.95, iterations: int = 40
                     ) -> np.ndarray:
    """Half-width U with P(|x + c| <= U) = p for x ~ N(0, sigma[n]^2) and c one of shifts[n] (N,S), each
    equally likely: shifted_radius's 1-D counterpart (the error of a field's size). Newton steps kept inside
    a shrinking bracket [0, max |c| + 4 sigma], until P is within P_TOLERANCE of p."""
    sigma = np.maximum(np.asarray(sigma, float), np.finfo(float).tiny)[:, None]
    shifts = np.atleast_2d(np.asarray(shifts, float))
    lo, hi = np.zeros(len(sigma)), np.max(np.abs(shifts), axis=1) + 4.0 * sigma[:, 0]
    u = np.minimum(np.sqrt(np.mean(shifts**2, axis=1) + (1.96 * sigma[:, 0]) ** 2), hi)
    for _ in range(iterations):
        below, above = (u[:, None] - shifts) / sigma, (u[:, None] + shifts) / sigma
        f = 0.5 * np.mean(erf(below / np.sqrt(2.0)) + erf(above / np.sqrt(2.0)), axis=1) - p
        going = np.abs(f) > P_TOLERANCE  # a row within the tolerance stays: its U is its own, whatever rows
        if not going.any():             # are computed beside it
            break
        density = np.mean(np.exp(-0.5 * below**2) + np.exp(-0.5 * above**2), axis=1) / np.sqrt(2 * np.pi)
        slope = density / sigma[:, 0]
        lo, hi = np.where(f < 0, u, lo), np.where(f < 0, hi, u)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = u - f / slope
        u = np.where(going, np.where((step > lo) & (step < hi), step, 0.5 * (lo + hi)), u)
    return u
