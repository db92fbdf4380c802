"""T24 through the streaming Gram accumulator: truth recovery, streaming algebra, std errors, diagnostics."""

import numpy as np
import pytest

import calib
from calib import compiled, synthetic
from calib.errors import FitError
from calib.models import gram_kernel
from calib.models.gram import GramAccumulator


def _dataset(seed=0, **kw):
    return synthetic.t24_dataset(np.random.default_rng(seed), **kw)


def test_recovers_truth_within_a_few_standard_errors():
    ds, truth = _dataset(1)
    cal = calib.fit(ds, "t24")
    for name, value in cal.params.items():
        z = (value - truth.params[name]) / cal.std_errors[name]
        assert np.max(np.abs(z)) < 4.5, name
    assert cal.stats["rms_after_nt"] == pytest.approx(10.0, rel=0.05)
    assert cal.stats["rms_before_nt"] > 100
    assert len(cal.stats["per_group"]) == 6


def test_chunked_and_merged_equal_one_shot():
    ds, _ = _dataset(2)
    one = GramAccumulator(20.0)
    one.add(ds.h_nt, ds.temp_c, ds.ref_nt)
    chunked = GramAccumulator(20.0)
    for lo in range(0, len(ds), 77):
        chunked.add(ds.h_nt[lo : lo + 77], ds.temp_c[lo : lo + 77], ds.ref_nt[lo : lo + 77])
    half = len(ds) // 2
    a, b = GramAccumulator(20.0), GramAccumulator(20.0)
    a.add(ds.h_nt[:half], ds.temp_c[:half], ds.ref_nt[:half])
    b.add(ds.h_nt[half:], ds.temp_c[half:], ds.ref_nt[half:])
    merged = a.merge(b)
    ref = one.solve().params
    for acc in (chunked, merged):
        assert acc.n == one.n
        np.testing.assert_allclose(acc.gram, one.gram, rtol=1e-12, atol=1e-12 * np.abs(one.gram).max())
        for name, value in acc.solve().params.items():
            np.testing.assert_allclose(value, ref[name], rtol=1e-9, atol=1e-12)


def test_merge_refuses_different_reference_temperatures():
    with pytest.raises(FitError, match="centred at"):
        GramAccumulator(20.0).merge(GramAccumulator(25.0))


def test_memory_does_not_grow_with_samples():
    ds, _ = _dataset(3)
    acc = GramAccumulator()

    def held_bytes():
        return sum(v.nbytes for v in vars(acc).values() if isinstance(v, np.ndarray))

    acc.add(ds.h_nt, ds.temp_c, ds.ref_nt)
    after_one = held_bytes()
    for _ in range(20):
        acc.add(ds.h_nt, ds.temp_c, ds.ref_nt)
    assert held_bytes() == after_one < 4_000_000  # fixed 11x11 sums plus one chunk buffer
    assert acc.n == 21 * len(ds)


def test_reference_temperature_does_not_change_the_absolute_parameters():
    ds, _ = _dataset(4)
    p20 = calib.fit(ds, "t24", temp_ref_c=20.0)
    p0 = calib.fit(ds, "t24", temp_ref_c=0.0)
    for name in p20.params:
        np.testing.assert_allclose(p20.params[name], p0.params[name], rtol=1e-8, atol=1e-9)
        np.testing.assert_allclose(p20.std_errors[name], p0.std_errors[name], rtol=1e-6)


def test_standard_errors_match_monte_carlo_scatter():
    rng = np.random.default_rng(5)
    params = synthetic.random_t24_params(rng)
    fits = []
    for seed in range(150):
        ds, _ = synthetic.t24_dataset(np.random.default_rng(100 + seed), params=params, samples_per_point=2)
        fits.append(calib.fit(ds, "t24"))
    for name in ("S", "K", "b_nt", "kb_nt_per_c"):
        scatter = np.std([f.params[name] for f in fits], axis=0, ddof=1)
        predicted = np.mean([f.std_errors[name] for f in fits], axis=0)
        ratio = scatter / predicted
        assert 0.75 < np.mean(ratio) < 1.25, name  # 150 runs: the mean ratio is known to a few percent
        assert np.all((ratio > 0.6) & (ratio < 1.5)), name


def test_one_temperature_says_k_and_kb_are_not_identifiable():
    ds, _ = _dataset(6, temps_c=[25.0], temp_jitter_c=0.05)
    acc = GramAccumulator(25.0)
    acc.add(ds.h_nt, ds.temp_c, ds.ref_nt)
    message = acc.identifiability()
    assert "K and kb" in message and "add a temperature step or fit P12" in message
    with pytest.raises(FitError, match="not identifiable"):
        acc.solve()


def test_too_few_samples_and_empty_fail_cleanly():
    acc = GramAccumulator()
    with pytest.raises(FitError, match="0 samples"):
        acc.solve()
    ds, _ = _dataset(7)
    acc.add(ds.h_nt[:5], ds.temp_c[:5], ds.ref_nt[:5])
    with pytest.raises(FitError, match="5 samples, more than 8 needed"):
        acc.solve()


def test_planar_directions_are_named():
    dirs = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0.7, 0.7, 0], [-0.7, 0.7, 0]], float)
    ds, _ = _dataset(8, directions=dirs)
    # noisy raw readings scatter out of the plane; the reference field does not
    with pytest.raises(
        FitError, match=r"spans fewer than three directions \(nothing along \[0.00, 0.00, 1.00\]"
    ):
        calib.fit(ds, "t24")


def test_directions_only_at_one_temperature_name_k_and_kb():
    ds_a, _ = _dataset(9, temps_c=[0.0], noise_nt=0.0, temp_jitter_c=0.0)
    # at the second temperature the field always points the same way
    ds_b, _ = _dataset(
        9, temps_c=[50.0], directions=np.array([[0.0, 0.0, 1.0]]), noise_nt=0.0, temp_jitter_c=0.0
    )
    acc = GramAccumulator(25.0)
    acc.add(ds_a.h_nt, ds_a.temp_c, ds_a.ref_nt)
    acc.add(ds_b.h_nt, ds_b.temp_c, ds_b.ref_nt)
    message = acc.identifiability()
    assert message is not None and "K" in message and "not identifiable" in message
    assert "two or more temperature steps" in message


def test_solve_after_each_point_is_cheap_and_grows_into_a_fit():
    ds, _ = _dataset(10, samples_per_point=3)
    acc = GramAccumulator(20.0)
    outcomes = []
    for lo in range(0, len(ds), 3):
        acc.add(ds.h_nt[lo : lo + 3], ds.temp_c[lo : lo + 3], ds.ref_nt[lo : lo + 3])
        outcomes.append(acc.identifiability() is None)
    assert not outcomes[0] and outcomes[-1]
    assert acc.solve().stats["n"] == len(ds)


def _random_columns(n, seed=12):
    rng = np.random.default_rng(seed)
    h, ref = rng.normal(0, 3e4, (n, 3)), rng.normal(0, 3e4, (n, 3))
    temp, weights = rng.uniform(-30, 70, n), rng.uniform(0, 2, n)
    weights[::5] = 0.0  # flagged outliers: no weight, not counted
    return h, temp, ref, weights


def _assert_same_gram(actual, expected, rtol=1e-12):
    """Entry by entry, relative to the scale of its row and column (an entry may cancel to ~0)."""
    d = np.sqrt(np.diag(expected))
    np.testing.assert_array_less(np.abs(actual - expected) / np.outer(d, d), rtol)


@pytest.fixture(params=["numba", "numpy"])
def gram_path(request, monkeypatch):
    """Run a test through the compiled kernel and through the numpy fallback."""
    if request.param == "numba":
        pytest.importorskip("numba")
        if gram_kernel._compiled() is None:
            pytest.skip("numba kernel did not compile here")
    else:
        monkeypatch.setattr(gram_kernel, "_KERNEL", [None])
    return request.param


def test_gram_over_several_blocks_equals_the_direct_product(gram_path):
    n = int(2.5 * gram_kernel.KERNEL_ROWS)  # two full kernel calls and a partial one
    h, temp, ref, weights = _random_columns(n)
    t = temp - 20.0
    z = np.column_stack([np.ones(n), t, h, t[:, None] * h, ref])
    acc = GramAccumulator(20.0)
    acc.add(h, temp, ref, weights=weights)  # weighted first: nothing of the weights may stay behind
    acc.add(h, temp, ref)
    expected = (z * weights[:, None]).T @ z + z.T @ z
    _assert_same_gram(acc.gram, expected)
    assert acc.n == n + np.count_nonzero(weights)
    assert (acc.temp_min_c, acc.temp_max_c) == (temp.min(), temp.max())


def test_compiled_kernel_and_numpy_fallback_give_the_same_sums():
    pytest.importorskip("numba")
    if gram_kernel._compiled() is None:
        pytest.skip("numba kernel did not compile here")
    h, temp, ref, weights = _random_columns(20_000, seed=13)
    cases = {
        "plain": (h, temp, ref, None),
        "weighted": (h, temp, ref, weights),
        "one temperature": (h, np.array([31.5]), ref, None),
        "strided columns": (np.asfortranarray(h)[::2], temp[::2], ref[::2], weights[::2]),
    }
    for name, (hh, tt, rr, ww) in cases.items():
        compiled = gram_kernel.gram_numba(hh, tt, rr, ww, 20.0)
        fallback = gram_kernel.gram_numpy(hh, tt, rr, ww, 20.0)
        _assert_same_gram(compiled[0], fallback[0])
        assert compiled[1:] == fallback[1:], name


def test_without_numba_the_numpy_path_is_used(monkeypatch):
    monkeypatch.setattr(gram_kernel, "_KERNEL", [])
    monkeypatch.setenv("MAGRIG_NO_NUMBA", "1")
    assert gram_kernel._compiled() is None
    ds, _ = _dataset(14)
    acc = GramAccumulator(20.0)
    acc.add(ds.h_nt, ds.temp_c, ds.ref_nt)
    assert acc.solve().stats["n"] == len(ds)


def test_a_kernel_that_fails_to_compile_falls_back_with_a_warning(monkeypatch):
    numba = pytest.importorskip("numba")
    monkeypatch.setattr(gram_kernel, "_KERNEL", [])
    monkeypatch.delenv("MAGRIG_NO_NUMBA", raising=False)

    def broken_njit(*args, **kwargs):
        raise numba.core.errors.TypingError("no typing for this kernel")

    monkeypatch.setattr(numba, "njit", broken_njit)
    with pytest.warns(UserWarning, match="using numpy"):
        assert gram_kernel._compiled() is None


def test_rows_cut_over_cores_give_the_same_sums_every_time(monkeypatch):
    pytest.importorskip("numba")
    if gram_kernel._compiled() is None:
        pytest.skip("numba kernel did not compile here")
    h, temp, ref, weights = _random_columns(20_000, seed=21)
    single = gram_kernel.gram_numba(h, temp, ref, weights, 20.0)
    monkeypatch.setattr(gram_kernel, "PARALLEL_ROWS", 1000)
    monkeypatch.setattr(compiled, "cores", lambda: 3)  # three uneven parts
    first = gram_kernel.gram_numba(h, temp, ref, weights, 20.0)
    again = gram_kernel.gram_numba(h, temp, ref, weights, 20.0)
    np.testing.assert_array_equal(first[0], again[0])  # a fixed order of sums, whatever the threads did
    _assert_same_gram(first[0], single[0])
    assert first[1:] == single[1:]
