"""calib/stats/distributions.py against mpmath and closed forms."""

from __future__ import annotations

import math

import mpmath
import numpy as np
import pytest

from calib.stats.distributions import chi2_sf, erf, f_sf, gaussian_radius, shifted_interval, shifted_radius


@pytest.mark.parametrize(("x", "d1", "d2"), [(1.0, 3, 100), (5.0, 12, 500), (0.1, 1, 10), (2.5, 36, 3000),
                                              (8.0, 4, 20)])
def test_f_tail(x, d1, d2):
    exact = 1 - mpmath.betainc(d1 / 2, d2 / 2, 0, d1 * x / (d1 * x + d2), regularized=True)
    assert f_sf(x, d1, d2) == pytest.approx(float(exact), rel=1e-10)


@pytest.mark.parametrize(("x", "k"), [(1.0, 3), (26.217, 12), (100.0, 12), (3.0, 1), (0.5, 7)])
def test_chi2_tail(x, k):
    assert chi2_sf(x, k) == pytest.approx(float(mpmath.gammainc(k / 2, x / 2, mpmath.inf, regularized=True)),
                                          rel=1e-10)


def test_erf():
    x = np.linspace(-5, 5, 2001)
    assert np.max(np.abs(erf(x) - np.array([math.erf(v) for v in x]))) < 1.5e-7


def test_gaussian_radius_closed_forms_and_a_general_case():
    assert gaussian_radius(np.eye(3)) == pytest.approx(2.795483482915108, rel=1e-6)  # sqrt(chi2_3 0.95)
    assert gaussian_radius(np.diag([4.0, 0.0, 0.0])) == pytest.approx(2 * 1.959963984540054, rel=1e-6)
    two_d = math.sqrt(-2 * math.log(0.05))  # the Rayleigh quantile
    assert gaussian_radius(np.diag([1.0, 1.0, 0.0])) == pytest.approx(two_d, rel=1e-6)
    assert gaussian_radius(np.zeros((3, 3))) == 0.0
    a = np.array([[2.0, 0.3, -0.4], [0.1, 0.7, 0.2], [0.0, 0.5, 0.3]])
    cov = a @ a.T
    # P(|e| <= r) by 1-D quadrature over the sphere in mpmath (three eigenvalues, chi2_3 along each ray)
    lam = np.linalg.eigvalsh(cov)
    r = gaussian_radius(cov)

    def inside(mu, phi):
        q = lam[0] * (1 - mu * mu) * mpmath.cos(phi) ** 2 + lam[1] * (1 - mu * mu) * mpmath.sin(phi) ** 2 \
            + lam[2] * mu * mu
        x = r * r / q
        return mpmath.erf(mpmath.sqrt(x / 2)) - mpmath.sqrt(2 * x / mpmath.pi) * mpmath.exp(-x / 2)

    prob = mpmath.quad(inside, [0, 1], [0, mpmath.pi / 2]) * 2 / mpmath.pi
    assert float(prob) == pytest.approx(0.95, abs=1e-6)
    stack = gaussian_radius(np.stack([cov, 4 * cov]))
    assert stack.shape == (2,) and stack[1] == pytest.approx(2 * stack[0], rel=1e-6)


SIGNS = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, -1.0], [1.0, -1.0, 1.0], [-1.0, 1.0, 1.0]])


def test_shifted_radius_closed_forms():
    """No shift: the normal radius (to the direction rule's 5e-4); no normal part: the shift's length;
    shifts along one axis against a 1-D normal: P(|x + c| <= r) = Phi((r - c) / s) - Phi((-r - c) / s)."""
    cov = np.diag([4.0, 1.0, 0.25])
    assert shifted_radius(cov[None], np.zeros((1, 3)))[0] == pytest.approx(gaussian_radius(cov), rel=5e-4)
    assert shifted_radius(np.zeros((1, 3, 3)), SIGNS * [3.0, 4.0, 0.0])[0] == pytest.approx(5.0, rel=1e-5)
    c, sd = 3.0, 2.0
    r = shifted_radius(np.diag([sd**2, 0.0, 0.0])[None], [[c, 0.0, 0.0], [-c, 0.0, 0.0]])[0]
    phi = lambda x: 0.5 * (1 + math.erf(x / math.sqrt(2)))  # noqa: E731
    assert phi((r - c) / sd) - phi((-r - c) / sd) == pytest.approx(0.95, abs=2e-5)


@pytest.mark.parametrize("seed", range(4))
def test_shifted_radius_holds_95_percent_of_the_mixture(seed):
    """Against 400 000 draws of x + s d (x normal of a random covariance, s a random sign per axis): the
    radius holds 95 % of them (the draws' own scatter is 0.03 % points), and the normal radius of the
    same covariance (d^2 added) overstates it where the shift dominates."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(3, 3)) * rng.uniform(5.0, 60.0)
    cov, d = a @ a.T, np.abs(rng.normal(size=3)) * 120.0
    r = shifted_radius(np.stack([cov, cov]), SIGNS * d)
    assert r[0] == r[1]
    x = rng.multivariate_normal(np.zeros(3), cov, 400_000) + rng.choice([-1.0, 1.0], (400_000, 3)) * d
    inside = np.mean(np.linalg.norm(x, axis=1) <= r[0])
    assert inside == pytest.approx(0.95, abs=0.0015)
    assert r[0] < gaussian_radius(cov + np.diag(d**2))


def test_the_shifted_interval_holds_its_probability_and_is_each_rows_own():
    """P(|x + c| <= U) = 0.95 for a normal x beside shifts c, each equally likely (a normal's 1.96 sigma
    without them), and a row's U is the same whatever rows are computed beside it (rig apply computes a
    file's every row at once, a check a few); shifted_radius's too."""
    rng = np.random.default_rng(3)
    sigma, shifts = rng.uniform(10.0, 500.0, 300), rng.normal(0.0, 300.0, (300, 4))
    both = shifted_interval(sigma, shifts)
    np.testing.assert_array_equal(both[:5], shifted_interval(sigma[:5], shifts[:5]))
    x = rng.normal(0.0, 1.0, (200_000, 1)) * sigma[:3] + shifts[:3, rng.integers(0, 4, 200_000)].T
    np.testing.assert_allclose(np.mean(np.abs(x) <= both[:3], axis=0), 0.95, atol=0.003)
    assert shifted_interval(np.array([2.0]), np.zeros((1, 1)))[0] == pytest.approx(1.96 * 2.0, rel=1e-4)
    root = rng.normal(0.0, 100.0, (300, 3, 3))  # the 3-D radius likewise each row's own
    cov, state = root @ root.transpose(0, 2, 1), np.array([[100.0, 50.0, 20.0], [100.0, -50.0, 20.0]])
    np.testing.assert_array_equal(shifted_radius(cov, state)[:5], shifted_radius(cov[:5], state))
