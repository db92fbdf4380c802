"""The lab field's gradient from the ambients at several places (rig/fieldsources/coils/gradientfit.py)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.dataset import Dataset
from rig.fieldsources.ambientlines import by_position, stated_gradient_source
from rig.fieldsources.coils.gradientfit import NAMES, element_std_errors, fit_gradient

G = np.array([[120.0, 40.0, -60.0], [40.0, -200.0, 90.0], [-60.0, 90.0, 80.0]])  # symmetric, traceless
A0 = np.array([16_000.0, 300.0, 43_000.0])
SIX = [(0, 0, 0), (70, 0, 0), (-70, 0, 0), (0, 70, 0), (0, -70, 0), (0, 0, 70), (0, 0, -70)]


def ambients(places, rng, se=0.3, extra=0.0):
    """The ambient at each place with its own noise `se` and, beyond what its covariance says, `extra`."""
    return [(p, A0 + G @ (np.asarray(p, float) / 1000.0) + rng.normal(0, np.hypot(se, extra), 3),
             np.eye(3) * se**2) for p in places]


def test_the_places_measure_every_component_within_its_standard_error():
    rng = np.random.default_rng(1)
    fit = fit_gradient(ambients(SIX, rng), 300.0)
    assert fit.unidentified == [] and fit.places == 7 and fit.dof == 21 - 8
    sd = element_std_errors(fit.covariance)
    assert np.all(np.abs(fit.nt_per_m - G) <= 5 * sd) and np.all(sd < 5.0)


def test_by_position_is_the_gradient_times_the_offset():
    g = np.array([G[0, 0], G[1, 1], G[0, 1], G[0, 2], G[1, 2]])  # in NAMES' order
    assert NAMES == ("Gxx", "Gyy", "Gxy", "Gxz", "Gyz")
    r = np.array([0.03, -0.05, 0.07])
    np.testing.assert_allclose(by_position(r) @ g, G @ r, atol=1e-12)
    rows = np.array([r, -2 * r, [0.0, 0.0, 0.0]])  # many offsets at once: (N,3,5)
    np.testing.assert_allclose(by_position(rows) @ g, rows @ G.T, atol=1e-12)


def test_the_stated_bound_is_on_the_five_source_free_components():
    """A DUT at (0, 0, z) from the reference misses G r = z (Gxz, Gyz, Gzz), Gzz = -Gxx - Gyy: the lab's
    field has no sources there, so its z axis takes two stated components' share, not one."""
    z, bound = 0.07, 300.0
    source = stated_gradient_source(np.array([[0.0, 0.0, z]]), bound)
    assert np.shape(source.covariance) == (5, 5) and source.distribution == "rectangular"
    a, _ = source.sensitivities(Dataset(h_nt=np.zeros((1, 3)), temp_c=np.zeros(1), ref_nt=np.zeros((1, 3))))
    variance = np.diag(a[0] @ source.covariance @ a[0].T)
    np.testing.assert_allclose(variance, z**2 * bound**2 / 3 * np.array([1.0, 1.0, 2.0]), rtol=1e-12)


def test_places_on_one_axis_leave_the_rest_at_the_stated_bound_or_nothing_without_one():
    rng = np.random.default_rng(2)
    on_x = ambients([(0, 0, 0), (70, 0, 0), (-70, 0, 0)], rng)
    fit = fit_gradient(on_x, 300.0)
    assert fit.unidentified == ["Gyy", "Gyz"]
    sd = np.sqrt(np.diag(fit.covariance))
    assert sd[NAMES.index("Gyy")] == pytest.approx(300.0 / np.sqrt(3), rel=1e-3)
    assert sd[NAMES.index("Gxy")] < 10.0
    assert fit_gradient(on_x, None) is None  # nothing to keep for what they do not show
    assert fit_gradient(on_x[:1], 300.0) is None  # one place shows no gradient


def test_a_lab_field_moving_between_places_widens_the_covariance():
    quiet = fit_gradient(ambients(SIX, np.random.default_rng(3)), 300.0)
    moving = fit_gradient(ambients(SIX, np.random.default_rng(3), extra=3.0), 300.0)
    assert moving.chi2 > 3 * moving.dof  # 3 nT of scatter against 0.3 nT stated
    ratio = element_std_errors(moving.covariance) / element_std_errors(quiet.covariance)
    assert np.all(ratio > 3.0)  # about the scatter's ratio, 10
    sd = element_std_errors(moving.covariance)
    assert np.all(np.abs(moving.nt_per_m - G) <= 5 * sd)  # and still covers the truth


def test_another_reference_read_with_the_first_counts_its_difference_alone():
    """Another reference at r from the first, read together with it, gives the difference G r with its own
    covariance: what it shows of G does not depend on how well the first's ambient is known (that ambient
    is in both readings and cancels), and a stated prior u combines with it as 1 / (1 / u^2 + r^2 / s^2)."""
    r_m, s_nt, bound = 0.075, 2.0, 300.0
    difference = G @ np.array([0.0, 0.0, r_m])
    other = [((0, 0, 75), difference, np.eye(3) * s_nt**2)]
    fits = [fit_gradient([((0, 0, 0), A0, np.eye(3) * own_se**2)], bound, differences=other)
            for own_se in (0.1, 30.0)]
    prior_var = bound**2 / 3
    expected = 1.0 / (1.0 / prior_var + r_m**2 / s_nt**2)
    for fit in fits:
        assert fit.places == 2 and fit.unidentified == ["Gxx", "Gyy", "Gxy"]
        assert fit.covariance[NAMES.index("Gxz"), NAMES.index("Gxz")] == pytest.approx(expected, rel=1e-9)
        assert fit.nt_per_m[0, 2] == pytest.approx(G[0, 2] * r_m**2 / s_nt**2 * expected, rel=1e-9)
