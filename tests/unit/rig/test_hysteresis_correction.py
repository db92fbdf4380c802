"""The DUT's thermal hysteresis corrected in its readings before the fits (rig/budget/hysteresis.py)."""

from __future__ import annotations

import numpy as np

import calib
from calib import synthetic
from calib.uncertainty.linearise import linearised
from rig.budget.hysteresis import corrected
from rig.budget.modelerror import CORRECTED, model_sources

STEPS = [-20.0, 0.0, 25.0, 60.0, 10.0]  # cooled to -20, heated to 60, then cooled to 10
DIRECTIONS = {-20.0: -1.0, 0.0: 1.0, 25.0: 1.0, 60.0: 1.0, 10.0: -1.0}


def _hysteretic(rng, offset_raw: np.ndarray):
    """Readings of a T24 DUT whose offset stands +offset_raw after a heating and -offset_raw after a
    cooling, at points of four samples, with the thermal direction of every sample."""
    ds, truth = synthetic.t24_dataset(rng, temps_c=STEPS, samples_per_point=4, noise_nt=20.0,
                                      temp_jitter_c=0.0)
    direction = np.array([DIRECTIONS[t] for t in ds.temp_c])
    ds.h_nt = ds.h_nt + direction[:, None] * offset_raw
    ds.columns["point"] = np.array([f"T{g}-F{i // 4 % 26}" for i, g in enumerate(ds.group)], object)
    return ds, truth, direction


def test_the_hysteresis_is_corrected_to_the_mean_thermal_state_and_only_its_uncertainty_stays():
    """Uncorrected, the offsets and their temperature coefficients take the history's imbalance (three
    heating steps of five): several standard errors off the DUT's mean thermal state. Corrected, T24's
    parameters are the mean state's within their statistics; the budget keeps the correction's u (the
    term fitted again, about zero) and the state at a point of use (+-d)."""
    rng = np.random.default_rng(41)
    offset_raw = np.array([150.0, -100.0, 80.0])
    ds, truth, direction = _hysteretic(rng, offset_raw)
    fixed, checks = corrected(ds, direction)
    d = -truth.params["S"] @ offset_raw  # in the field: B = S (h - d_n offset) + ...
    np.testing.assert_allclose(fixed.source[CORRECTED], d, atol=15.0)
    assert any(c["name"] == "thermal hysteresis" and c["p"] < 1e-6 for c in checks)  # as measured
    for data, near in ((ds, False), (fixed, True)):
        cal = calib.fit(data, "t24")
        u = np.sqrt(np.diag(linearised(data, cal).statistical_covariance()))
        error = np.concatenate([np.ravel(cal.params[k] - truth.params[k]) for k in ("b_nt", "kb_nt_per_c")])
        z = np.abs(error) / u[-6:]  # the layout ends with b and kb
        assert (np.max(z) < 4.5) == near
    cal = calib.fit(fixed, "t24")
    cal.stats["model_checks"] = checks
    sources, _, _, correction = model_sources(fixed, cal, direction)
    names = [s.name for s in sources]
    state = sources[names.index("thermal hysteresis state")]
    np.testing.assert_allclose(np.sqrt(np.diag(state.covariance)), np.abs(d), rtol=0.1)
    assert correction is not None  # its uncertainty is the budget's linearisation's (the next test)
    assert not any(s.name.startswith("model checks") and "hysteresis" in s.name for s in sources)


def test_data_without_a_hysteresis_are_left_as_they_are():
    rng = np.random.default_rng(42)
    ds, _, direction = _hysteretic(rng, np.zeros(3))
    fixed, checks = corrected(ds, direction)
    assert fixed is ds and CORRECTED not in fixed.source and checks
    assert corrected(ds, None) == (ds, None)
    few = ds.subset(slice(0, 6))  # too few for T24: another model may still be fitted to them
    assert corrected(few, direction[:6]) == (few, None)


def test_the_budget_takes_the_correction_along_as_the_whole_procedure_moves():
    """Noise and an error of the references that is one offset per temperature step (an unsteady lab, an
    offset's wander) move the hysteresis estimate too: a cooling step's offset is partly taken for the
    hysteresis and corrected away. The parameters' spread over such draws of the whole procedure (the
    correction, then T24) is what the budget states through the corrected linearisation; through the plain
    one it is not."""
    from calib.uncertainty.correction import Corrected
    from calib.uncertainty.propagation import InputSource
    from calib.uncertainty.rowgroups import RowGroups
    from rig.budget.modelerror import TermsFit

    rng = np.random.default_rng(43)
    clean, _, direction = _hysteretic(rng, np.array([150.0, -100.0, 80.0]))
    steps = np.unique(clean.group, return_inverse=True)[1]
    step_nt, noise_nt = 40.0, 20.0

    def procedure(seed):
        r = np.random.default_rng(seed)
        ref = clean.ref_nt + r.normal(0, step_nt, (5, 3))[steps]
        ds = calib.Dataset(clean.h_nt + r.normal(0, noise_nt, clean.h_nt.shape), clean.temp_c, ref,
                           group=clean.group, columns=dict(clean.columns))
        fixed, checks = corrected(ds, direction)
        cal = calib.fit(fixed, "t24")
        cal.stats["model_checks"] = checks
        return fixed, cal

    spread = np.std([np.concatenate([np.ravel(procedure(k)[1].params[n]) for n in ("b_nt", "kb_nt_per_c")])
                     for k in range(300)], axis=0)
    fixed, cal = procedure(1000)
    offsets = InputSource("step offsets", np.eye(15) * step_nt**2, ref_nt=RowGroups.offsets(steps, 5))
    terms = TermsFit(fixed, cal, direction, np.ones(len(fixed)))
    noise = np.full(3, noise_nt)  # the drawn noise (the synthetic readings' own is the same in every draw)
    plain = linearised(fixed, cal, noise_nt=noise)
    taken = Corrected(linearised(fixed, cal, noise_nt=noise), terms.data_correction(direction, noise))
    stated = {}
    for name, lin in (("plain", plain), ("taken", taken)):
        jac = lin.ref_jacobian(offsets.sensitivities(fixed)[0])
        cov = lin.statistical_covariance() + jac @ offsets.covariance @ jac.T
        stated[name] = np.sqrt(np.diag(cov))[-6:] / spread  # b and kb close the layout
    np.testing.assert_allclose(stated["taken"], 1.0, atol=0.15)
    assert np.all(stated["plain"][3:] < 0.85)  # kb: the step offsets the correction takes along, missed
