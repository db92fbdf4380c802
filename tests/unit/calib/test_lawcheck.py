"""When the law of propagation is the whole answer (calib/uncertainty/lawcheck.py), a source's direct effect
on the true field (InputSource.field_nt) against draws of it, and a Monte Carlo whose refits all fail."""

from __future__ import annotations

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.stats.distributions import gaussian_radius
from calib.uncertainty.adaptive import adaptive_monte_carlo
from calib.uncertainty.budgeting import budget
from calib.uncertainty.lawcheck import normal_interval_holds, validate_temperature
from calib.uncertainty.linearise import ParamLayout, linearised
from calib.uncertainty.propagation import (
    InputSource,
    matrix_source,
    offset_source,
    propagate_linear,
    temperature_source,
)

COIL_NT_PER_A = 10_000.0


def case(seed: int, temps_c=(-20.0, 20.0, 60.0)):
    ds, _ = synthetic.t24_dataset(np.random.default_rng(seed), temps_c=temps_c, samples_per_point=2)
    return ds, ds.ref_nt / COIL_NT_PER_A, calib.fit(ds, "t24")


def grid():
    fields = 50_000.0 * synthetic.coil_directions()
    return np.repeat(fields, 2, axis=0), np.tile([-20.0, 60.0], len(fields))


def test_a_dominant_rectangular_input_needs_monte_carlo_and_small_ones_do_not():
    ds, currents, cal = case(1)
    big = offset_source("offset", len(ds), np.eye(3) * 30.0**2, distribution="rectangular")
    holds, found = normal_interval_holds(propagate_linear(ds, cal, [big], grid(), statistical=False), ndig=1)
    assert not holds and "Monte Carlo" in found  # a uniform alone: its 95 % interval is 1.645 u, not 1.96 u
    matrix = matrix_source("coil matrix", currents, np.eye(9).reshape(9, 3, 3), np.eye(9))  # 100 ppm, normal
    small = offset_source("offset", len(ds), np.eye(3) * 0.2**2, distribution="rectangular")
    holds, found = normal_interval_holds(propagate_linear(ds, cal, [matrix, small], grid()), ndig=1)
    assert holds and "+-1.96 u holds" in found
    b = budget(ds, cal, [matrix, small], grid(), rng=np.random.default_rng(2))
    assert b.monte_carlo is None and "the checks above held" in b.method
    drawn = budget(ds, cal, [matrix, small], grid(), rng=np.random.default_rng(3), monte_carlo="always",
                   ndig=2)
    # the drawn intervals agree with +-1.96 u to within the numerical tolerance the check allowed
    for key in ("S", "b_nt"):
        half = (drawn.interval[key][1] - drawn.interval[key][0]) / 2
        np.testing.assert_allclose(half, 1.959964 * b.standard[key], rtol=0.05)


def test_a_small_temperature_source_on_t24_is_taken_through_its_first_order_map():
    ds, currents, cal = case(4)
    columns = np.column_stack([np.ones(len(ds)), ds.temp_c - 25.0])
    small = temperature_source("temperature", columns, np.diag([0.1**2, 0.002**2]))
    lin, linear = linearised(ds, cal), propagate_linear(ds, cal, [small], grid())
    holds, found, failed = validate_temperature(lin, linear, [small], np.random.default_rng(5), ndig=1)
    assert holds and failed == 0 and "it holds" in found
    b = budget(ds, cal, [small], grid(), rng=np.random.default_rng(6))
    assert b.monte_carlo is None
    huge = temperature_source("temperature", columns, np.diag([15.0**2, 0.3**2]))  # far beyond first order
    lin, linear = linearised(ds, cal), propagate_linear(ds, cal, [huge], grid())
    holds, found, _ = validate_temperature(lin, linear, [huge], np.random.default_rng(7), ndig=1)
    assert not holds and "refitting every draw" in found
    b = budget(ds, cal, [huge], grid(), rng=np.random.default_rng(8))
    assert b.monte_carlo["refits"] == "every draw" and "beyond first order" in b.method


def test_a_direct_effect_on_the_true_field_agrees_with_1e5_draws_within_2_percent():
    """A model error: a term z(h) = h_i^2 / B0 per axis the model lacks, moving the data by z c and the
    true field at the grid by z_grid c; the calibrated field's error (F J - a_grid) c. Law of propagation
    against 10^5 draws of c: u of every parameter and the 95 % radius at every grid point within 2 % (the
    draws' own scatter: ~0.22 % on u, ~0.5 % on a 95 % quantile)."""
    ds, currents, cal = case(9)
    h = ds.h_nt
    z = h * h / 5e4  # (N,3): even in h, which T24 cannot follow
    a_ref = np.zeros((len(ds), 3, 3))
    for i in range(3):
        a_ref[:, i, i] = z[:, i]

    def at_grid(grid_h, grid_t):
        zg = grid_h * grid_h / 5e4
        out = np.zeros((len(grid_h), 3, 3))
        for i in range(3):
            out[:, i, i] = zg[:, i]
        return out

    sigma = np.diag([1.0e-3, 0.6e-3, 1.5e-3]) ** 2
    term = InputSource("quadratic term", sigma, ref_nt=a_ref, field_nt=at_grid)
    linear = budget(ds, cal, [term], grid(), rng=np.random.default_rng(10), statistical=False,
                    monte_carlo="never")
    drawn = budget(ds, cal, [term], grid(), rng=np.random.default_rng(11), statistical=False,
                   monte_carlo="always", batch_draws=50_000, max_draws=100_000, ndig=3)
    assert drawn.draws >= 100_000
    lay = ParamLayout.of(cal.params)
    u_lin, u_mc = lay.flatten(linear.standard), lay.flatten(drawn.standard)
    big = u_lin > 1e-6 * u_lin.max()
    np.testing.assert_allclose(u_mc[big], u_lin[big], rtol=0.02)
    r_lin = np.asarray(linear.vector_error_nt["per_point"])
    r_mc = np.asarray(drawn.vector_error_nt["per_point"])
    np.testing.assert_allclose(r_mc, r_lin, rtol=0.02)
    # the direct effect is in the radius: the fit follows an even term with its offset only, so the error
    # left where the term is small (along a coordinate axis) or large differs from F J c alone by tens of nT
    without = propagate_linear(ds, cal, [InputSource("quadratic term", term.covariance, ref_nt=a_ref)],
                               grid(), statistical=False)
    assert np.max(np.abs(r_lin - gaussian_radius(without.field_covariance))) > 20.0


def test_a_monte_carlo_whose_refits_all_fail_cannot_be_stated_and_says_so():
    def failing(rng, m):
        return np.zeros((m, 4)), np.zeros((m, 2)), np.ones(m, bool)

    result = adaptive_monte_carlo(failing, np.random.default_rng(12), batch_size=100)
    assert not result.stated and result.failed == result.draws == 100
    assert "cannot be stated" in result.message


@pytest.mark.parametrize("distribution", ["normal", "rectangular"])
def test_a_source_without_data_effect_changes_only_the_field(distribution):
    ds, currents, cal = case(13)
    only = InputSource("misfit", np.eye(3) * 20.0**2, field_nt=lambda gh, gt: np.broadcast_to(
        np.eye(3), (len(gh), 3, 3)), distribution=distribution)
    b = budget(ds, cal, [only], grid(), rng=np.random.default_rng(14), statistical=False, monte_carlo="never")
    assert np.all(ParamLayout.of(cal.params).flatten(b.standard) == 0)
    np.testing.assert_allclose(b.combined_standard_nt, np.sqrt(3) * 20.0, rtol=1e-9)


def test_a_two_point_state_has_its_own_coverage():
    """A field error of +-20 nT, one way or the other (a thermal hysteresis's state at a point of use):
    its 95 % radius is 20 nT, not the 1.96 x 20 of a normal error of the same variance."""
    ds, currents, cal = case(15)
    state = InputSource("state", np.diag([20.0**2, 1e-6, 1e-6]), distribution="two-point",
                        field_nt=lambda gh, gt: np.broadcast_to(np.eye(3), (len(gh), 3, 3)))
    holds, _ = normal_interval_holds(propagate_linear(ds, cal, [state], grid(), statistical=False), ndig=1)
    assert not holds
    b = budget(ds, cal, [state], grid(), rng=np.random.default_rng(16), statistical=False)
    assert b.monte_carlo is not None
    np.testing.assert_allclose(b.vector_error_nt["per_point"], 20.0, rtol=0.01)
