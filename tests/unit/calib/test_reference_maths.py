"""The reference chain's maths: coil commissioning, table commissioning, and the Monte Carlo budget."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.commissioning.coilfit import fit_coil_matrix
from calib.commissioning.tablefit import PARAM_NAMES, fit_table_axes, site_from_home, table_field_nt
from calib.errors import FitError
from calib.models.gram import GramAccumulator
from calib.uncertainty.montecarlo import Draw, Source, monte_carlo, raw_for, statistical

TRUE_M = np.array([[50_480.0, 264.0, -12.0], [35.0, 49_510.0, -263.0], [8.0, 20.0, 50_310.0]])
AMBIENT = np.array([16_200.0, -350.0, 43_100.0])


def _design(level: float = 1.2, repeats: int = 2) -> np.ndarray:
    one = [[0.0, 0.0, 0.0]]
    for j in range(3):
        for share in (0.5, 1.0, 0.5, 0.0, -0.5, -1.0, -0.5, 0.0):
            row = [0.0, 0.0, 0.0]
            row[j] = share * level
            one.append(row)
    for signs in np.array(np.meshgrid([1, -1], [1, -1], [1, -1])).T.reshape(-1, 3):
        one.append(list(0.5 * level * signs))
    return np.array(one * repeats, float)


def test_coil_matrix_and_ambient_are_recovered_within_their_stated_errors():
    z_scores = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        currents = _design()
        readings = currents @ TRUE_M.T + AMBIENT + rng.normal(0, 1.0, currents.shape)
        fit = fit_coil_matrix(currents, readings)
        se_m, se_a = fit.std_errors()
        z_scores += list(((fit.matrix_nt_per_a - TRUE_M) / se_m).ravel())
        z_scores += list((fit.ambient_nt - AMBIENT) / se_a)
        assert np.all(fit.nonlinearity < 1e-4)
    z = np.array(z_scores)
    assert 0.8 < z.std() < 1.2  # the covariance states the real scatter
    assert np.mean(np.abs(z) < 2) > 0.9


def test_a_coil_that_does_not_respond_is_named():
    currents = _design()
    dead = TRUE_M.copy()
    dead[:, 2] = 0.0
    readings = currents @ dead.T + AMBIENT + np.random.default_rng(0).normal(0, 1.0, currents.shape)
    with pytest.raises(FitError, match="coil z does not respond"):
        fit_coil_matrix(currents, readings)


def test_a_field_not_linear_in_the_current_shows_in_the_nonlinearity():
    currents = _design()
    bent = currents * (1 + np.array([0.0, 0.01, 0.0]) * np.abs(currents))  # coil y 1 % per ampere
    readings = bent @ TRUE_M.T + AMBIENT + np.random.default_rng(1).normal(0, 1.0, currents.shape)
    fit = fit_coil_matrix(currents, readings)
    assert fit.nonlinearity[1] > 5e-3 and fit.nonlinearity[0] < 1e-4 and fit.nonlinearity[2] < 1e-4


def test_settings_that_cannot_separate_the_coils_are_refused():
    currents = np.array([[1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [0.5, 0.5, 0.5], [-1, -1, -1], [0, 0, 0],
                         [3, 3, 3]], float)
    with pytest.raises(FitError, match="do not separate"):
        fit_coil_matrix(currents, currents @ TRUE_M.T + AMBIENT)


def _ideal_rotation(az, el):
    a, e = np.radians(az), np.radians(el)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    ry = np.array([[np.cos(e), 0, np.sin(e)], [0, 1, 0], [-np.sin(e), 0, np.cos(e)]])
    return rz @ ry


def test_the_ideal_table_is_the_table_model_with_no_errors():
    site = np.array([19_148.0, 894.0, 45_587.0])
    params = np.concatenate([site, np.zeros(4)])
    for az, el in ((0, 0), (30, 20), (200, -60), (90, 90)):
        assert np.allclose(table_field_nt(params, [[az, el]])[0], _ideal_rotation(az, el).T @ site)


def test_a_tilted_table_is_fitted_and_predicts_other_angles():
    site = np.array([19_148.0, 894.0, 45_587.0])
    true = np.array([*site, 0.3, -0.2, 0.4, 0.05])  # v, el tilt, mount x, el zero, mount z
    angles = [(az, el) for az in range(0, 360, 45) for el in (-90, -45, 0, 45, 90)]
    rng = np.random.default_rng(3)
    readings = table_field_nt(true, angles) + rng.normal(0, 1.0, (len(angles), 3))
    fit = fit_table_axes(angles, readings)
    z = (fit.params - true) / fit.std_errors
    assert np.all(np.abs(z) < 4), dict(zip(PARAM_NAMES, z, strict=True))
    other = [(33, 17), (250, -70)]
    assert np.abs(table_field_nt(fit.params, other) - table_field_nt(true, other)).max() < 2.0
    home = table_field_nt(true, [[0, 0]])[0]  # the site field measured at home carries through the axes
    assert np.allclose(site_from_home(true, home), site)


def test_a_table_turned_about_one_axis_only_cannot_be_commissioned():
    site = np.array([19_148.0, 894.0, 45_587.0])
    params = np.concatenate([site, np.zeros(4)])
    angles = [(az, 0) for az in range(0, 360, 30)]
    with pytest.raises(FitError, match="not identifiable"):
        fit_table_axes(angles, table_field_nt(params, angles))


def test_raw_for_inverts_every_model():
    rng = np.random.default_rng(5)
    ds, truth = synthetic.t24_dataset(rng)
    fields = rng.normal(0, 40_000, (10, 3))
    temps = rng.uniform(-30, 70, 10)
    for model in ("t24", "p12", "scalar"):
        cal = calib.fit(ds, model)
        h = raw_for(cal, fields, temps if cal.model != "p12" else None)
        assert np.allclose(cal.apply(h, temps), fields, atol=1e-6)


def test_the_statistical_source_reproduces_the_t24_standard_errors():
    """For a linear fit the parametric bootstrap's spread is sigma^2 G^-1: the fit's own std errors."""
    rng = np.random.default_rng(11)
    ds, _ = synthetic.t24_dataset(rng, noise_nt=20.0, samples_per_point=4)
    cal = calib.fit(ds, "t24")
    sigma = np.array([cal.stats["sigma_nt"][a] for a in "xyz"])
    grid = (rng.normal(0, 40_000, (20, 3)), rng.uniform(-30, 70, 20))

    def refit(d):
        acc = GramAccumulator(cal.temp_ref_c)
        acc.add(d.h_nt, d.temp_c, d.ref_nt)
        return acc.solve()

    budget = monte_carlo(ds, cal, [statistical(ds, sigma)], refit, grid, rng=rng, draws=400,
                         draws_per_source=50)
    ratio = budget.standard["S"] / cal.std_errors["S"]
    assert 0.85 < np.median(ratio) < 1.15
    assert budget.expanded["b_nt"].shape == cal.params["b_nt"].shape
    assert budget.contributions[0]["source"] == "fit (statistical)"


def test_sources_add_up_and_a_larger_input_uncertainty_widens_the_budget():
    rng = np.random.default_rng(2)
    ds, _ = synthetic.t24_dataset(rng, noise_nt=10.0, samples_per_point=3)
    cal = calib.fit(ds, "t24")
    grid = (rng.normal(0, 40_000, (20, 3)), rng.uniform(-30, 70, 20))

    def offset(size_nt):  # a reference offset common to every sample: it goes into b one for one
        return Source(f"offset {size_nt}", lambda r: Draw(ref_nt=np.broadcast_to(r.normal(0, size_nt, 3),
                                                                                 ds.ref_nt.shape)))

    def refit(d):
        return calib.fit(d, "t24", temp_ref_c=cal.temp_ref_c)

    small = monte_carlo(ds, cal, [offset(1.0)], refit, grid, rng=rng, draws=150, draws_per_source=30)
    large = monte_carlo(ds, cal, [offset(1.0), offset(30.0)], refit, grid, rng=rng, draws=150,
                        draws_per_source=30)
    assert np.all(np.abs(small.standard["b_nt"] - 1.0) < 0.25)
    assert np.all(np.abs(large.standard["b_nt"] - np.hypot(1.0, 30.0)) < 6.0)
    assert large.expanded_vector_error_nt > 10 * small.expanded_vector_error_nt
    assert [c["source"] for c in large.contributions] == ["offset 1.0", "offset 30.0"]


def test_the_t24_reference_map_is_the_refit_of_a_changed_reference():
    from calib.models.t24 import reference_map

    rng = np.random.default_rng(8)
    ds, _ = synthetic.t24_dataset(rng, noise_nt=10.0, samples_per_point=3)
    cal = calib.fit(ds, "t24", temp_ref_c=20.0)
    change = rng.normal(0, 50.0, ds.ref_nt.shape)
    refit = calib.fit(dataclasses.replace(ds, ref_nt=ds.ref_nt + change), "t24", temp_ref_c=20.0)
    mapped = reference_map(ds, None, 20.0)(change)
    for key in cal.params:
        assert np.allclose(cal.params[key] + mapped[key], refit.params[key], rtol=1e-7, atol=1e-9), key
