"""Uncertainty propagation (calib/uncertainty/propagation.py, calib/uncertainty/linearise.py,
calib/uncertainty/mcrefit.py, calib/uncertainty/budgeting.py) against refits made independently here: plain
least squares in the absolute-tau regressors, calib.fit."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.errors import DataError, FitError
from calib.stats.student import coverage_factor, t_quantile
from calib.uncertainty import mcrefit
from calib.uncertainty.budgeting import budget, cross_covariance_of
from calib.uncertainty.linearise import ParamLayout, linearised
from calib.uncertainty.mcrefit import ScalarRefit, TemperatureRefit
from calib.uncertainty.montecarlo import Draw, Source, monte_carlo
from calib.uncertainty.propagation import (
    STATISTICAL,
    cross_covariance,
    matrix_source,
    offset_source,
    propagate_linear,
    temperature_source,
)

COIL_NT_PER_A = 10_000.0


def small_case(seed: int, temps_c=(-20.0, 60.0), samples=1):
    ds, _ = synthetic.t24_dataset(np.random.default_rng(seed), temps_c=temps_c, samples_per_point=samples)
    return ds, ds.ref_nt / COIL_NT_PER_A  # the coil currents that made each reference


def scalar_case(seed: int, temps_c=None, n: int = 400):
    """A sensor turned through random orientations in a 50 uT field (the scalar model's own data), with the
    field vectors known as references; with temps_c, n samples at each temperature and temperature terms."""
    rng = np.random.default_rng(seed)
    p = synthetic.random_scalar_params(rng, temps_c is not None)
    temps = np.repeat(np.asarray(temps_c if temps_c is not None else [25.0], float), n)
    ref = rng.normal(size=(len(temps), 3))
    ref *= 50_000.0 / np.linalg.norm(ref, axis=1, keepdims=True)
    dt = temps - 25.0
    h = np.empty_like(ref)
    for i in range(len(ref)):
        a = p["A"] + (dt[i] * p["KA_per_c"] if temps_c is not None else 0)
        c = p["c_nt"] + (dt[i] * p["kc_nt_per_c"] if temps_c is not None else 0)
        h[i] = np.linalg.solve(a, ref[i]) + c
    h += rng.normal(0, 10.0, h.shape)
    ds = Dataset(h, temps if temps_c is not None else None, ref)
    return ds, ref / COIL_NT_PER_A


def grid():
    fields = 50_000.0 * synthetic.coil_directions()
    return np.repeat(fields, 2, axis=0), np.tile([-20.0, 60.0], len(fields))


def coil_sources(ds, currents, *, shared=None):
    ppm = 100e-6 * COIL_NT_PER_A
    unit_entries = np.eye(9).reshape(9, 3, 3)
    return [matrix_source("coil matrix", currents, unit_entries, np.eye(9) * ppm**2, shared=shared),
            offset_source("ambient", len(ds), np.diag([4.0, 9.0, 1.0]), distribution="rectangular")]


def absolute_refits(ds, ref_draws: np.ndarray) -> np.ndarray:
    """T24 refits of every drawn reference set (D,N,3) by least squares on [1, T, h, T h] (absolute T), all
    draws as right-hand sides of one solve: (D, 24) in calib's layout (S, K, b, kb)."""
    t, h = ds.temp_c, ds.h_nt
    x = np.column_stack([np.ones(len(t)), t, h, t[:, None] * h])
    scale = np.linalg.norm(x, axis=0)
    d = ref_draws.shape[0]
    rhs = ref_draws.transpose(1, 2, 0).reshape(len(t), 3 * d)
    beta = (np.linalg.lstsq(x / scale, rhs, rcond=None)[0] / scale[:, None]).reshape(8, 3, d)
    s, k = (beta[rows].transpose(2, 1, 0).reshape(d, 9) for rows in (slice(2, 5), slice(5, 8)))
    return np.concatenate([s, k, beta[0].T, beta[1].T], axis=1)


def drawn_references(ds, currents, sigma_nt, rng, d: int) -> np.ndarray:
    """(d,N,3): the references as the coil matrix (100 ppm of 10^4 nT/A per entry), a rectangular ambient
    (standard uncertainties 2, 3, 1 nT) and the fit's noise (sigma per axis) could have made them."""
    ppm = 100e-6 * COIL_NT_PER_A
    dm = rng.standard_normal((d, 3, 3)) * ppm
    amb = rng.uniform(-np.sqrt(3), np.sqrt(3), (d, 1, 3)) * [2.0, 3.0, 1.0]
    noise = rng.standard_normal((d, len(ds), 3)) * sigma_nt
    return ds.ref_nt[None] + np.einsum("dij,nj->dni", dm, currents) + amb + noise


def test_the_linear_propagation_agrees_with_1e5_refits():
    """u of every T24 parameter from the law of propagation against the spread of 10^5 refits (one spread
    of 10^5 draws is within 0.22 % (1 sd) of the truth: 2 % is 9 sd); their correlations likewise."""
    ds, currents = small_case(1)
    cal = calib.fit(ds, "t24")
    sigma = np.array([cal.stats["sigma_nt"][a] for a in "xyz"])
    lin = propagate_linear(ds, cal, coil_sources(ds, currents), grid())
    rng = np.random.default_rng(2)
    draws = np.concatenate([absolute_refits(ds, drawn_references(ds, currents, sigma, rng, 20_000))
                            for _ in range(5)])
    u = np.sqrt(np.diag(lin.covariance))
    np.testing.assert_allclose(draws.std(axis=0, ddof=1), u, rtol=0.02)
    corr_mc = np.corrcoef(draws, rowvar=False)
    corr = lin.covariance / np.outer(u, u)
    assert np.max(np.abs(corr_mc - corr)) < 0.02
    assert [c.name for c in lin.contributions] == [STATISTICAL, "coil matrix", "ambient"]
    assert all(c.method == "exact (linear)" for c in lin.contributions)
    np.testing.assert_allclose(np.sqrt(np.diag(lin.contributions[0].covariance)),
                               ParamLayout.of(cal.params).flatten(cal.std_errors), rtol=1e-6)


def test_field_errors_per_grid_point_follow_the_covariance():
    ds, currents = small_case(3)
    cal = calib.fit(ds, "t24")
    lin = propagate_linear(ds, cal, coil_sources(ds, currents), grid())
    assert lin.field_covariance.shape == (52, 3, 3) and lin.radius_nt.shape == (52,)
    # the field error at a grid point is F dtheta: the radius of F C F^T, whatever the point's direction
    rng = np.random.default_rng(4)
    dtheta = rng.multivariate_normal(np.zeros(24), lin.covariance, 200_000)
    errors = np.einsum("ip,dp->di", lin.field_jacobian[7], dtheta)
    assert np.quantile(np.linalg.norm(errors, axis=1), 0.95) == pytest.approx(lin.radius_nt[7], rel=0.01)
    traces = np.trace(lin.field_covariance, axis1=1, axis2=2)
    assert lin.field_rms_nt == pytest.approx(np.sqrt(np.mean(traces)))


def test_cross_covariance_of_two_duts_sharing_the_coil_matrix():
    """Two DUTs' T24 calibrations made with the same drawn coil matrix: the refits' cross-covariance
    against J_a Sigma J_b^T (correlations within 0.02: ~7 sd of 10^5 draws)."""
    (ds_a, cur_a), (ds_b, cur_b) = small_case(5), small_case(6)
    cal_a, cal_b = calib.fit(ds_a, "t24"), calib.fit(ds_b, "t24")
    lin_a, lin_b = (propagate_linear(ds, cal, coil_sources(ds, cur, shared="coils")[:1], grid(),
                                     statistical=False)
                    for ds, cal, cur in ((ds_a, cal_a, cur_a), (ds_b, cal_b, cur_b)))
    cross = cross_covariance(lin_a, lin_b)
    rng = np.random.default_rng(7)
    dm = rng.standard_normal((100_000, 3, 3)) * 100e-6 * COIL_NT_PER_A
    fa = absolute_refits(ds_a, ds_a.ref_nt[None] + np.einsum("dij,nj->dni", dm, cur_a))
    fb = absolute_refits(ds_b, ds_b.ref_nt[None] + np.einsum("dij,nj->dni", dm, cur_b))
    mc = (fa - fa.mean(0)).T @ (fb - fb.mean(0)) / (len(fa) - 1)
    ua, ub = np.sqrt(np.diag(lin_a.covariance)), np.sqrt(np.diag(lin_b.covariance))
    assert np.max(np.abs((mc - cross) / np.outer(ua, ub))) < 0.02
    assert np.abs(cross).max() > 0
    unshared = propagate_linear(ds_b, cal_b, coil_sources(ds_b, cur_b)[:1], grid(), statistical=False)
    assert np.all(cross_covariance(lin_a, unshared) == 0)


def test_every_model_linearisation_against_refits():
    """d params / d q for a reference change and a temperature change (q moves the references by up to
    ~150 nT, the temperatures by 1 degC), against central differences of refits, in units of each
    parameter's statistical u: exact for T24 / T36 and references, first order otherwise (the scalar
    fit's Gauss-Newton map leaves out the residuals' curvature)."""
    coils = small_case(8, temps_c=(-20.0, 20.0, 60.0), samples=3)
    turned = scalar_case(9, temps_c=(-20.0, 20.0, 60.0), n=150)
    for model, (ds, currents), ref_tol, temp_tol in (("t24", coils, 1e-6, 1e-5), ("t36", coils, 1e-6, 1e-5),
                                                     ("p12", coils, 1e-6, 0), ("scalar", turned, 0.01, 1e-3)):
        a_ref = coil_sources(ds, currents)[0].ref_nt[:, :, :2] * 30.0
        a_temp = np.column_stack([np.ones(len(ds)), (ds.temp_c - 25.0) / 50.0])
        options = {"temperature_terms": True, "balance_orientations": False} if model == "scalar" else {}
        cal = calib.fit(ds, model, **options)
        layout = ParamLayout.of(cal.params)
        lin = linearised(ds, cal)

        def refit(d, cal=cal, layout=layout, options=options, model=model, lin=lin):
            if model == "scalar":  # warm-started: calib.fit's algebraic start needs one |B| or clearly many
                drawn = ScalarRefit(lin)(dref=(d.ref_nt - lin.ds.ref_nt)[None],
                                         dt=(d.temp_c - lin.ds.temp_c)[None])
                return layout.flatten(cal.params) + drawn[0][0]
            return layout.flatten(calib.fit(d, model, temp_ref_c=cal.temp_ref_c, **options).params)

        def moved(step, k, a_ref=a_ref, a_temp=a_temp, ds=ds):
            return {"ref_nt": ds.ref_nt + step * a_ref[:, :, k]}

        def warmed(step, k, a_temp=a_temp, ds=ds):
            return {"temp_c": ds.temp_c + step * a_temp[:, k]}

        for jac, change, tol in ((lin.ref_jacobian(a_ref), moved, ref_tol),
                                 (lin.temp_jacobian(a_temp), warmed, temp_tol)):
            for k in range(2):
                fd = (refit(dataclasses.replace(ds, **change(0.01, k)))
                      - refit(dataclasses.replace(ds, **change(-0.01, k)))) / 0.02
                u = np.sqrt(np.diag(lin.statistical_covariance()))
                assert np.all(np.abs(jac[:, k] - fd) <= tol * u), model


def test_the_batch_refits_equal_calib_fit_on_the_drawn_data():
    ds, _ = small_case(9, temps_c=(-20.0, 20.0, 60.0), samples=3)
    a_temp = np.column_stack([np.ones(len(ds)), ds.temp_c - 25.0])
    q = np.array([[0.3, 0.002], [-0.5, -0.004]])
    for model in ("t24", "t36"):
        cal = calib.fit(ds, model)
        layout = ParamLayout.of(cal.params)
        moved, failed = TemperatureRefit(linearised(ds, cal), a_temp)(q)
        assert not failed.any()
        for i in range(2):
            refit = calib.fit(dataclasses.replace(ds, temp_c=ds.temp_c + a_temp @ q[i]), model,
                              temp_ref_c=cal.temp_ref_c)
            np.testing.assert_allclose(layout.flatten(cal.params) + moved[i], layout.flatten(refit.params),
                                       rtol=1e-9, atol=1e-9 * np.abs(layout.flatten(cal.params)).max())
    ds, _ = scalar_case(10, temps_c=(-20.0, 20.0, 60.0), n=150)
    cal = calib.fit(ds, "scalar", temperature_terms=True, balance_orientations=False)
    layout, lin = ParamLayout.of(cal.params), linearised(ds, cal)
    dh = np.random.default_rng(10).normal(0, 10.0, (2, len(ds), 3))
    moved, failed = ScalarRefit(lin)(dh=dh)
    assert not failed.any()
    u = np.sqrt(np.diag(lin.statistical_covariance()))
    for i in range(2):
        refit = calib.fit(dataclasses.replace(ds, h_nt=ds.h_nt + dh[i]), "scalar", temp_ref_c=cal.temp_ref_c,
                          temperature_terms=True, balance_orientations=False)
        off = np.abs(layout.flatten(cal.params) + moved[i] - layout.flatten(refit.params))
        assert np.all(off <= 1e-4 * u + 1e-12)


def test_a_scalar_draw_far_off_or_not_finite_spoils_no_other_draw_and_warns_nothing():
    """Among the draws, one whose readings scatter a million times their noise (no ellipsoid near the
    calibration's) and one with a reading that is not finite: the second is counted failed, the others are
    their own data's least-squares solutions as tightly as ever (the tolerance is taken from the draws'
    spread, robustly), and no numpy warning reaches the operator's terminal."""
    import warnings

    ds, _ = scalar_case(10, temps_c=(-20.0, 20.0, 60.0), n=150)
    options = {"temperature_terms": True, "balance_orientations": False}
    cal = calib.fit(ds, "scalar", **options)
    lin = linearised(ds, cal)
    dh = np.random.default_rng(12).normal(0, 10.0, (4, len(ds), 3))
    dh[1] *= 1e6
    dh[3, 0, 0] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        moved, failed = ScalarRefit(lin)(dh=dh)
    assert failed[3] and not failed[0] and not failed[2]
    u = np.sqrt(np.diag(lin.statistical_covariance()))
    for i in (0, 2):
        assert np.all(_off_calib_fit(cal, moved[i], dataclasses.replace(ds, h_nt=ds.h_nt + dh[i]), options)
                      <= 1e-3 * u)


def test_scalar_draws_the_fixed_step_matrix_cannot_bring_to_rest_are_refitted_with_their_own(monkeypatch):
    """A turntable's scalar fit (bench/uncertainty.py coverage --table --model scalar, seed 24, world 0 dut1;
    480 readings at four temperatures): the site field's vertical part never reverses in the DUT's frame,
    so offset and scale along it lie in a narrow valley. Draws of its budget's inputs (readings, reference
    vectors, temperatures) moved the parameters by up to 13 u, and the steps with the step matrix taken at
    the calibration's solution diverged or were still going: 889 of 1000 draws failed, and the budget
    refused to state an uncertainty. Four of them: each is now its own data's least-squares solution, as
    calib.fit finds it."""
    data = np.load(Path(__file__).parent / "data" / "scalar_turntable_draws.npz")
    f = {k: data[k].astype(float) for k in data.files}
    ds = Dataset(h_nt=f["h_nt"], temp_c=f["temp_c"], ref_nt=f["ref_nt"], ref_norm_nt=None)
    options = {"temperature_terms": True, "balance_orientations": False}
    cal = calib.fit(ds, "scalar", **options)
    lin = linearised(ds, cal)
    draws = {"dh": f["dh"], "dref": f["dref"], "dt": f["dt"]}
    monkeypatch.setattr(mcrefit, "MAX_DAMPED_STEPS", 0)  # the fixed step matrix alone
    assert ScalarRefit(lin)(**draws)[1].all()
    monkeypatch.undo()
    moved, failed = ScalarRefit(lin)(**draws)
    assert not failed.any()
    u = np.sqrt(np.diag(lin.statistical_covariance()))
    assert np.max(np.abs(moved) / np.where(u > 0, u, np.inf)) > 10  # far from the calibration's solution
    for i in range(len(failed)):
        drawn = dataclasses.replace(ds, h_nt=ds.h_nt + f["dh"][i], temp_c=ds.temp_c + f["dt"][i],
                                    ref_nt=ds.ref_nt + f["dref"][i])
        assert np.all(_off_calib_fit(cal, moved[i], drawn, options) <= 1e-3 * u)


def _off_calib_fit(cal, moved: np.ndarray, drawn: Dataset, options: dict) -> np.ndarray:
    """|the refit's parameters - calib.fit's of the drawn data|, flat."""
    layout = ParamLayout.of(cal.params)
    refit = calib.fit(drawn, "scalar", temp_ref_c=cal.temp_ref_c, **options)
    return np.abs(layout.flatten(cal.params) + moved - layout.flatten(refit.params))


def test_a_t24_budget_without_monte_carlo_is_the_law_of_propagation():
    ds, currents = small_case(11)
    cal = calib.fit(ds, "t24")
    sources = [coil_sources(ds, currents)[0]]  # normal inputs, a linear model: nothing to draw
    b = budget(ds, cal, sources, grid(), rng=np.random.default_rng(12))
    assert b.monte_carlo is None and b.draws == 0 and "exact" in b.method
    lin = b.linear
    # the residual scatter is estimated with N - 8 degrees of freedom per axis, the coil matrix is known:
    # Welch-Satterthwaite gives more than N - 8, the more the coil matrix's share
    dof, dof_field = lin.effective_dof()
    assert np.all(dof > len(ds) - 8) and len(ds) - 8 < dof_field < np.max(dof)
    assert b.coverage_factor == pytest.approx(coverage_factor(dof_field)) and 2.0 < b.coverage_factor < 2.06
    widen = t_quantile(0.975, dof_field) / 1.959964
    assert b.expanded_vector_error_nt == pytest.approx(np.max(lin.radius_nt) * widen)
    stated = ParamLayout.of(cal.params).flatten(b.standard)
    np.testing.assert_allclose(stated, np.sqrt(np.diag(lin.covariance)))
    b_dof = np.ravel(b.effective_dof["b_nt"])
    k_b = np.array([coverage_factor(v) for v in b_dof])
    np.testing.assert_allclose(b.expanded["b_nt"], k_b * b.standard["b_nt"], rtol=1e-12)
    half = np.array([t_quantile(0.975, v) for v in b_dof]) * b.standard["b_nt"]
    low, high = b.interval["b_nt"]
    np.testing.assert_allclose(high - cal.params["b_nt"], half, rtol=1e-6)
    np.testing.assert_allclose(cal.params["b_nt"] - low, half, rtol=1e-6)
    back = Calibration.from_dict({**cal.to_dict(), "uncertainty": b.as_dict()})  # the file accepts it
    assert back.uncertainty["covariance"]["parameters"][:2] == ["S[0][0]", "S[0][1]"]
    assert len(back.uncertainty["vector_error_nt"]["per_point"]) == 52


def test_a_rectangular_input_gets_its_own_coverage_interval():
    """One rectangular offset making b: the 95 % interval of a uniform is +-1.645 u, not +-1.96 u. Asked to
    two digits (u = 30 nT: delta = 0.5 nT), the endpoints' scatter is below 0.25 nT, 3 % is ~6 of it."""
    ds, _ = small_case(13)
    cal = calib.fit(ds, "t24")
    big = offset_source("offset", len(ds), np.eye(3) * 30.0**2, distribution="rectangular")
    b = budget(ds, cal, [big], grid(), rng=np.random.default_rng(14), statistical=False, ndig=2)
    assert b.monte_carlo["converged"] and b.monte_carlo["refits"] == "none (linear maps)"
    half = (b.interval["b_nt"][1] - b.interval["b_nt"][0]) / 2
    np.testing.assert_allclose(half / b.standard["b_nt"], 0.95 * np.sqrt(3), rtol=0.03)


def test_a_temperature_source_is_refitted_and_every_model_states_its_method():
    ds, currents = small_case(15, temps_c=(-20.0, 20.0, 60.0), samples=2)
    turned, turned_currents = scalar_case(15, temps_c=(-20.0, 20.0, 60.0), n=100)
    g = (grid()[0], np.tile([-20.0, 60.0], 26))
    for model in ("t24", "t36", "p12", "scalar"):
        data, cur = (turned, turned_currents) if model == "scalar" else (ds, currents)
        temp = temperature_source("temperature", np.column_stack([np.ones(len(data)), data.temp_c - 25.0]),
                                  np.diag([0.3**2 / 3, 0.005**2 / 3]), distribution="rectangular")
        cal = calib.fit(data, model)
        b = budget(data, cal, [*coil_sources(data, cur), temp], g, rng=np.random.default_rng(16),
                   monte_carlo="always")
        assert b.stated and b.monte_carlo["converged"] and "Monte Carlo (GUM S1, adaptive)" in b.method
        assert b.monte_carlo["refits"] == ("every draw" if model in ("t24", "t36") else "none (linear maps)")
        lin_u = np.sqrt(np.diag(b.linear.covariance))
        got = ParamLayout.of(cal.params).flatten(b.standard)
        # nearly linear here: the draws' u within the adaptive run's own scatter of the propagated u
        np.testing.assert_allclose(got, lin_u, rtol=0.06, atol=1e-12 * lin_u.max())
        assert b.expanded_vector_error_nt >= b.vector_error_nt["percentile_95"] > 0
        if model in ("p12", "scalar"):
            assert any("first order" in n for n in b.notes)


def test_scalar_refitted_draws_agree_with_its_validated_map():
    ds, currents = scalar_case(17)
    cal = calib.fit(ds, "scalar", temperature_terms=False, balance_orientations=False)
    sources = coil_sources(ds, currents)
    mapped = budget(ds, cal, sources, grid(), rng=np.random.default_rng(18), monte_carlo="always")
    assert any("refitted draws stay within" in n and "it holds" in n for n in mapped.notes)
    assert mapped.monte_carlo["refits"] == "none (linear maps)"
    refitted = budget(ds, cal, sources, grid(), rng=np.random.default_rng(19), scalar_refits=True,
                      monte_carlo="always")
    assert refitted.monte_carlo["refits"] == "every draw" and refitted.failed_draws == 0
    for key in ("A", "c_nt"):
        np.testing.assert_allclose(refitted.standard[key], mapped.standard[key], rtol=0.1, atol=1e-12)
    assert refitted.expanded_vector_error_nt == pytest.approx(mapped.expanded_vector_error_nt, rel=0.1)


def test_a_scalar_fit_far_from_its_data_is_checked_on_its_intervals():
    """The scalar model without temperature terms on a T24 sensor over 80 degC: residuals of hundreds of
    nT. Its largest refitted draws stray from the first-order map by more than half the tolerance (second
    order: the largest of 100 draws), yet the paired check finds its 95 % intervals moved by less, and
    every draw refitted agrees with the map's u to within the tolerance."""
    ds, currents = small_case(17, temps_c=(-20.0, 60.0), samples=3)
    cal = calib.fit(ds, "scalar", temperature_terms=False, balance_orientations=False)
    b = budget(ds, cal, coil_sources(ds, currents), grid(), rng=np.random.default_rng(18))
    found = next(n for n in b.notes if "refitted draws" in n)
    assert "it holds" in found and "move its 95 % intervals by" in found and b.monte_carlo is None
    refitted = budget(ds, cal, coil_sources(ds, currents), grid(), rng=np.random.default_rng(19),
                      scalar_refits=True, monte_carlo="always")
    assert refitted.monte_carlo["refits"] == "every draw" and refitted.stated
    for key in ("A", "c_nt"):
        np.testing.assert_allclose(refitted.standard[key], b.standard[key], rtol=0.1, atol=1e-12)


def test_a_budget_that_cannot_be_stated_says_so():
    ds, currents = small_case(20)
    cal = calib.fit(ds, "t24")
    b = budget(ds, cal, [coil_sources(ds, currents)[0]], grid(), rng=np.random.default_rng(21))
    b.stated, b.notes = False, ["60 of 2000 refits failed"]
    with pytest.raises(FitError, match="cannot be stated: 60 of 2000 refits failed"):
        b.as_dict()
    assert cross_covariance_of(b, b).shape == (24, 24)


def test_the_old_monte_carlo_counts_the_draws_it_could_not_refit():
    ds, _ = small_case(22)
    cal = calib.fit(ds, "t24")
    calls = []

    def refit(d):  # every 25th refit fails the way a near-singular draw does
        calls.append(1)
        if len(calls) % 25 == 0:
            raise FitError("T24: the design is singular")
        return calib.fit(d, "t24", temp_ref_c=cal.temp_ref_c)

    offset = Source("offset", lambda r: Draw(ref_nt=np.broadcast_to(r.normal(0, 1.0, 3), ds.ref_nt.shape)))
    b = monte_carlo(ds, cal, [offset], refit, grid(), rng=np.random.default_rng(23), draws=100,
                    draws_per_source=50)
    assert b.failed_draws == 6 and any("refits failed" in n for n in b.notes)
    assert b.as_dict()["failed_draws"] == 6


def test_a_reference_magnetometers_error_moves_what_it_measured():
    """The source's first-order change of the references against the field a drawn reference calibration
    reports for the same readings, B = A2 A^-1 (B' - c) + c2."""
    from calib.uncertainty.propagation import affine_map, reference_source

    ref_ds, _ = synthetic.t24_dataset(np.random.default_rng(24), samples_per_point=2)
    ref_cal = calib.fit(ref_ds, "t24")
    layout = ParamLayout.of(ref_cal.params)
    measured = np.random.default_rng(25).normal(0, 30_000.0, (40, 3))
    u = layout.flatten(ref_cal.std_errors)
    source = reference_source("reference magnetometer", measured, ref_cal, np.diag(u**2), 23.0,
                              shared="reference magnetometer")
    dp = np.random.default_rng(26).normal(0, 1.0, u.size) * u
    drawn = Calibration("t24", layout.unflatten(layout.flatten(ref_cal.params) + dp), {}, ref_cal.temp_ref_c)
    (a, c), (a2, c2) = affine_map(ref_cal, 23.0), affine_map(drawn, 23.0)
    truth = (measured - c) @ np.linalg.solve(a.T, a2.T) + c2 - measured  # (A2 A^-1 (B' - c))^T, rows
    np.testing.assert_allclose(source.ref_nt @ dp, truth, atol=1e-3 * np.abs(truth).max())
    assert source.shared == "reference magnetometer" and source.covariance.shape == (24, 24)


def test_a_badly_described_source_is_one_line_naming_it():
    ds, currents = small_case(27)
    cal = calib.fit(ds, "t24")
    wrong_shape = offset_source("ambient", len(ds) - 1, np.eye(3))
    with pytest.raises(DataError, match=r"'ambient': ref_nt sensitivity has shape \(51, 3, 3\), expected"):
        propagate_linear(ds, cal, [wrong_shape], grid())
    lopsided = offset_source("ambient", len(ds), np.eye(3) + np.diag([2.0, 0.0], 1))
    with pytest.raises(DataError, match="source 'ambient': covariance must be a symmetric"):
        propagate_linear(ds, cal, [lopsided], grid())
    odd = dataclasses.replace(coil_sources(ds, currents)[0], distribution="triangular")
    known = r"distribution 'triangular' \(known: normal, rectangular, two-point\)"
    with pytest.raises(DataError, match=known):
        propagate_linear(ds, cal, [odd], grid())


def test_a_long_scalar_recording_is_refitted_on_a_thinned_share_that_spreads_as_the_whole(monkeypatch):
    """Refits of every draw cost as many rows as the data hold: beyond SCALAR_MC_ROWS they are made on an
    evenly spaced share, its noise scaled by M/N and its own solution the origin. Its u and its intervals
    are then the whole data's (the map's, which holds here), not sqrt(N/M) wider, nor shifted by the
    share's own solution."""
    import calib.uncertainty.budgeting as budgeting

    monkeypatch.setattr(budgeting, "SCALAR_MC_ROWS", 512)
    ds, currents = scalar_case(23, n=4096)
    cal = calib.fit(ds, "scalar", temperature_terms=False, balance_orientations=False)
    sources = coil_sources(ds, currents)
    whole = budget(ds, cal, sources, grid(), rng=np.random.default_rng(24), monte_carlo="never")
    thinned = budget(ds, cal, sources, grid(), rng=np.random.default_rng(25), scalar_refits=True,
                     monte_carlo="always")
    assert thinned.monte_carlo["refits"] == "every draw" and thinned.failed_draws == 0
    assert any("512 of its 4096 rows" in n for n in thinned.notes)
    for key in ("A", "c_nt"):
        np.testing.assert_allclose(thinned.standard[key], whole.standard[key], rtol=0.1, atol=1e-12)
        low, high = thinned.interval[key]
        middle = (np.asarray(low) + np.asarray(high)) / 2 - np.asarray(cal.params[key])
        assert np.all(np.abs(middle) <= 0.2 * np.asarray(whole.standard[key]) + 1e-12)
    assert thinned.expanded_vector_error_nt == pytest.approx(whole.expanded_vector_error_nt, rel=0.1)


def test_a_thinned_share_whose_own_solution_is_not_found_leaves_the_whole_data_to_refit(monkeypatch):
    import calib.uncertainty.budgeting as budgeting

    monkeypatch.setattr(budgeting, "SCALAR_MC_ROWS", 256)
    monkeypatch.setattr(ScalarRefit, "own_solution", lambda self: None)
    ds, currents = scalar_case(26, n=400)
    cal = calib.fit(ds, "scalar", temperature_terms=False, balance_orientations=False)
    b = budget(ds, cal, coil_sources(ds, currents), grid(), rng=np.random.default_rng(27), scalar_refits=True,
               monte_carlo="always")
    assert b.stated and b.monte_carlo["refits"] == "every draw"
    assert not any("rows, evenly spaced" in n for n in b.notes)


def test_one_singular_draw_fails_alone_in_a_stacked_solve():
    """The refits solve every draw's normal equations stacked (calib.uncertainty.mcrefit._solve): a singular
    one, whose error would spoil the whole stack, is NaN (then counted failed) and every other draw is
    solved."""
    rng = np.random.default_rng(4)
    a = rng.normal(size=(4, 5, 5))
    a[2] = 0.0
    for b in (rng.normal(size=(4, 5)), rng.normal(size=(4, 5, 3))):
        x = mcrefit._solve(a, b)
        assert x.shape == b.shape and np.all(np.isnan(x[2]))
        for i in (0, 1, 3):
            np.testing.assert_allclose(x[i], np.linalg.solve(a[i], b[i]), rtol=1e-12)
