"""The paper's closed form against our solver and a 60-digit solution of the same normal equations."""

import numpy as np

from calib import synthetic
from calib.models import t24_paper
from calib.models.gram import GramAccumulator


def _case(temps_c, seed=0):
    ds, _ = synthetic.t24_dataset(
        np.random.default_rng(seed),
        temps_c=temps_c,
        field_nt=100_000.0,
        samples_per_point=2,
        temp_jitter_c=0.0,
    )
    exact = t24_paper.exact_solution(ds.h_nt, ds.temp_c, ds.ref_nt)
    paper = t24_paper.paper_solution(ds.h_nt, ds.temp_c, ds.ref_nt)
    acc = GramAccumulator(round(float(np.mean(temps_c)), 1))
    acc.add(ds.h_nt, ds.temp_c, ds.ref_nt)
    ours = acc.solve().params
    return t24_paper.digits_kept(paper, exact), t24_paper.digits_kept(ours, exact), paper, ours


def test_wide_temperature_span_both_agree_with_the_exact_solution():
    paper_digits, our_digits, paper, ours = _case(np.linspace(-40, 85, 6))
    assert our_digits > 12 and paper_digits > 11
    for name in ours:
        np.testing.assert_allclose(paper[name], ours[name], rtol=1e-9, atol=1e-12 * np.abs(ours[name]).max())


def test_narrow_temperature_span_the_closed_form_loses_digits():
    # all temperatures within 25 +- 0.5 degC: absolute tau makes the 1 and tau columns nearly parallel
    paper_digits, our_digits, _, _ = _case(np.linspace(24.5, 25.5, 6))
    assert our_digits > 10
    assert paper_digits < our_digits - 1.5
