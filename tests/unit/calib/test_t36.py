"""T36 (T24 plus quadratic temperature terms): exact recovery, the absolute-tau conversion, streaming,
standard errors, what it refuses, and its place in the registry, the calibration file and calib.apply."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.dataset import Dataset
from calib.errors import FitError
from calib.io import calfile
from calib.models import registry
from calib.models.t36 import T36Accumulator, reference_map

TEMPS_C = (-30.0, 0.0, 20.0, 45.0, 70.0)


def t36_params(rng: np.random.Generator) -> dict:
    p = synthetic.random_t24_params(rng)
    p["K2"] = rng.normal(0, 2e-6, (3, 3))
    p["kb2_nt_per_c2"] = rng.normal(0, 0.01, 3)
    return p


def t36_dataset(rng, params, temps_c=TEMPS_C, noise_nt=10.0, samples=4, field_nt=50_000.0):
    """Raw readings of a sensor obeying T36 exactly (plus white noise on the readings)."""
    dirs = synthetic.coil_directions()
    temps = np.repeat(np.asarray(temps_c, float), len(dirs) * samples)
    temps = temps + rng.normal(0, 0.05, temps.size)
    ref = field_nt * np.tile(np.repeat(dirs, samples, axis=0), (len(temps_c), 1))
    t, t2 = temps[:, None, None], (temps**2)[:, None, None]
    m = params["S"][None] + t * params["K"][None] + t2 * params["K2"][None]
    rhs = ref - params["b_nt"] - t[:, :, 0] * params["kb_nt_per_c"] - t2[:, :, 0] * params["kb2_nt_per_c2"]
    h = np.linalg.solve(m, rhs[..., None])[..., 0] + rng.normal(0, noise_nt, ref.shape)
    return Dataset(h_nt=h, temp_c=temps, ref_nt=ref, source={"kind": "synthetic t36"})


def test_noise_free_data_give_the_truth_in_the_absolute_convention():
    rng = np.random.default_rng(1)
    truth = t36_params(rng)
    cal = calib.fit(t36_dataset(rng, truth, noise_nt=0.0), "t36")
    assert cal.model == "t36" and cal.temp_ref_c == 20.0  # centred inside, stated in absolute tau
    for name, value in truth.items():
        np.testing.assert_allclose(cal.params[name], value, rtol=1e-7, atol=1e-9 * np.abs(value).max(),
                                   err_msg=name)


def test_the_centred_solve_agrees_with_a_direct_absolute_least_squares_fit():
    rng = np.random.default_rng(2)
    ds = t36_dataset(rng, t36_params(rng))
    cal = calib.fit(ds, "t36", temp_ref_c=5.0)
    t, h = ds.temp_c, ds.h_nt
    x = np.column_stack([np.ones(len(t)), t, t * t, h, t[:, None] * h, (t * t)[:, None] * h])
    scale = np.linalg.norm(x, axis=0)
    beta = np.linalg.lstsq(x / scale, ds.ref_nt, rcond=None)[0] / scale[:, None]
    np.testing.assert_allclose(cal.params["S"], beta[3:6].T, rtol=1e-8)
    np.testing.assert_allclose(cal.params["K2"], beta[9:12].T, rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(cal.params["kb2_nt_per_c2"], beta[2], rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(cal.params["b_nt"], beta[0], rtol=1e-7, atol=1e-6)


def test_chunked_and_merged_sums_equal_one_pass():
    rng = np.random.default_rng(3)
    ds = t36_dataset(rng, t36_params(rng))
    one = T36Accumulator(20.0)
    one.add(ds.h_nt, ds.temp_c, ds.ref_nt)
    a, b = T36Accumulator(20.0), T36Accumulator(20.0)
    for lo in range(0, len(ds), 97):
        (a if lo % 2 else b).add(ds.h_nt[lo:lo + 97], ds.temp_c[lo:lo + 97], ds.ref_nt[lo:lo + 97])
    merged = a.merge(b)
    assert merged.n == one.n == len(ds)
    for name, value in one.solve().params.items():
        np.testing.assert_allclose(merged.solve().params[name], value, rtol=1e-9, atol=1e-13)
    with pytest.raises(FitError, match="centred at"):
        T36Accumulator(20.0).merge(T36Accumulator(25.0))


def test_standard_errors_match_the_scatter_of_repeated_fits():
    """300 noise draws on one design: the refits' spread of each parameter over its stated standard error
    (averaged over the draws, so the noise estimate's own scatter averages out). One spread of 300 draws is
    within 4.1 % (1 sd) of the truth: 20 % is ~5 sd for each of the 36, 5 % ~6 sd for their median."""
    rng = np.random.default_rng(4)
    clean = t36_dataset(rng, t36_params(rng), noise_nt=0.0, samples=1)
    fits = []
    for _ in range(300):
        noisy = dataclasses.replace(clean, h_nt=clean.h_nt + rng.normal(0, 10.0, clean.h_nt.shape))
        fits.append(calib.fit(noisy, "t36", temp_ref_c=20.0))
    ratios = np.concatenate([(np.std([f.params[k] for f in fits], axis=0, ddof=1)
                              / np.mean([f.std_errors[k] for f in fits], axis=0)).ravel()
                             for k in fits[0].params])
    assert 0.95 < np.median(ratios) < 1.05
    assert np.all((ratios > 0.8) & (ratios < 1.2))


def test_what_the_data_cannot_identify_is_named():
    rng = np.random.default_rng(5)
    truth = t36_params(rng)
    with pytest.raises(FitError, match="fewer than three distinct temperatures.*K2 and kb2 cannot be ident"):
        calib.fit(t36_dataset(rng, truth, temps_c=(-30.0, 70.0)), "t36")
    with pytest.raises(FitError, match="K, kb, K2 and kb2 are not identifiable"):
        calib.fit(t36_dataset(rng, truth, temps_c=(20.0,)), "t36")
    flat = t36_dataset(rng, truth)
    flat.ref_nt[:, 2] = 0.0
    with pytest.raises(FitError, match="fewer than three directions"):
        calib.fit(flat, "t36")
    few = t36_dataset(rng, truth).subset(slice(0, 12))
    with pytest.raises(FitError, match="12 samples, more than 12 needed"):
        calib.fit(few, "t36")


def test_the_calibration_file_round_trips_and_applies(tmp_path):
    rng = np.random.default_rng(6)
    ds = t36_dataset(rng, t36_params(rng))
    cal = calib.fit(ds, "t36")
    for name in ("cal.yaml", "cal.json"):
        calfile.save(cal, tmp_path / name)
        back = calfile.load(tmp_path / name)
        assert back.model == "t36" and back.temp_ref_c == cal.temp_ref_c
        for key in cal.params:
            assert np.array_equal(back.params[key], cal.params[key])
            assert back.params[key].shape == cal.params[key].shape
            assert np.array_equal(back.std_errors[key], cal.std_errors[key])
        np.testing.assert_array_equal(back.apply(ds.h_nt, ds.temp_c), cal.apply(ds.h_nt, ds.temp_c))
    residual = cal.apply(ds.h_nt, ds.temp_c) - ds.ref_nt
    assert cal.stats["rms_after_nt"] == pytest.approx(np.sqrt(np.mean(residual**2)), rel=1e-9)
    assert cal.stats["rms_after_nt"] < 12.0  # ~ the 10 nT noise through S


def test_t36_is_a_registered_vector_model_needing_temperature():
    spec = registry.spec("t36")
    assert spec.vector and spec.needs_temperature and spec.params == registry.PARAM_SHAPES["t36"]
    assert set(spec.params) == {"S", "K", "K2", "b_nt", "kb_nt_per_c", "kb2_nt_per_c2"}
    rng = np.random.default_rng(7)
    ds, truth = synthetic.t24_dataset(rng, temps_c=TEMPS_C, samples_per_point=3)
    cal = calib.fit(ds, "t36", robust=True)  # T24 truth: T36's curvature terms come out near zero
    assert np.all(np.abs(cal.params["K2"]) < 5 * cal.std_errors["K2"] + 1e-12)
    assert np.all(np.abs(cal.params["S"] - truth.params["S"]) < 5 * cal.std_errors["S"])


def test_the_reference_map_is_the_refit_of_a_changed_reference():
    rng = np.random.default_rng(8)
    ds = t36_dataset(rng, t36_params(rng))
    cal = calib.fit(ds, "t36", temp_ref_c=20.0)
    change = rng.normal(0, 50.0, ds.ref_nt.shape)
    refit = calib.fit(dataclasses.replace(ds, ref_nt=ds.ref_nt + change), "t36", temp_ref_c=20.0)
    mapped = reference_map(ds, None, 20.0)(change)
    for key in cal.params:
        np.testing.assert_allclose(cal.params[key] + mapped[key], refit.params[key], rtol=1e-7, atol=1e-12)
