"""The ambient over a run from the reference's measurements (rig/reference/ambient.py), and its line of the
budget (rig/fieldsources/ambientlines.py): noise about a steady or drifting lab is averaged; a lab that
moves between measurements by more than their noise is taken epoch by epoch."""

from __future__ import annotations

import numpy as np

from calib.dataset import Dataset
from rig.fieldsources.ambientlines import ambient_source
from rig.reference.ambient import AmbientModel

SE = 0.7  # nT, one measurement's standard error
TIMES = np.array([0.0, 3600.0, 7200.0, 10800.0, 14400.0])


def _measurements(values) -> list[dict]:
    return [{"t": t, "vector_nt": list(v), "std_error_nt": [SE] * 3}
            for t, v in zip(TIMES, values, strict=True)]


def test_noise_about_a_steady_lab_is_averaged():
    rng = np.random.default_rng(1)
    values = np.array([16_000.0, 300.0, 43_000.0]) + rng.normal(0, SE, (5, 3))
    model = AmbientModel.fit(_measurements(values))
    assert not model.anchored and not model.drifting
    np.testing.assert_allclose(model.at([500.0, 9000.0]), np.tile(values.mean(axis=0), (2, 1)), atol=1e-9)


def test_a_lab_that_moves_between_measurements_is_taken_epoch_by_epoch():
    """The chamber's heater and compressor fields follow the temperature step: each step's measurement is
    the best estimate for its points, not a line through all of them."""
    steps = np.array([[0, 0, 0], [40, -20, 60], [-30, 10, -50], [35, -25, 70], [0, 5, -10]], float)
    values = np.array([16_000.0, 300.0, 43_000.0]) + steps
    model = AmbientModel.fit(_measurements(values))
    assert model.anchored and model.as_dict()["per_epoch"]
    np.testing.assert_allclose(model.at([100.0, 3700.0, 9000.0, 20000.0]), values[[0, 1, 2, 4]], atol=1e-9)
    times = np.array([100.0, 3700.0, 9000.0])
    source = ambient_source(model, times, "ambient")
    ds = Dataset(h_nt=np.zeros((3, 3)), temp_c=np.zeros(3), ref_nt=np.zeros((3, 3)))
    a, _ = source.sensitivities(ds)
    variance = np.einsum("niq,qr,njr->nij", a, source.covariance, a)  # each sample's reference error
    for n in range(3):
        expected = SE**2 + model.excess_nt**2  # its epoch's measurement, and the lab moving that much again
        np.testing.assert_allclose(np.diag(variance[n]), expected, rtol=1e-9)
    assert variance[0, 0, 0] > 20.0**2  # the excess, some 30 nT, not the measurements' 0.7 nT
    np.testing.assert_allclose(np.einsum("iq,qr,jr->ij", a[0], source.covariance, a[1]), 0.0)  # epochs apart
    # that excess is estimated from five measurements less the mean: 4 degrees of freedom, one estimate per
    # axis over every epoch (they are all off by the same factor), the measurements' own error known
    assert [e.dof for e in source.estimated] == [4, 4, 4]
    for i, e in enumerate(source.estimated):
        np.testing.assert_allclose(np.diag(source.covariance)[e.index] - e.variance, SE**2, rtol=1e-9)
        assert len(e.index) == 5 and np.all(e.index % 3 == i)


def test_a_drift_carries_each_epochs_measurement_on():
    drift = np.array([20.0, -10.0, 5.0]) / 3600.0  # nT/s
    steps = np.array([[0, 0, 0], [40, -20, 60], [-30, 10, -50], [35, -25, 70], [0, 5, -10]], float)
    values = np.array([16_000.0, 300.0, 43_000.0]) + steps + TIMES[:, None] * drift * 30
    model = AmbientModel.fit(_measurements(values))
    assert model.anchored and model.drifting  # 600 nT/h
    np.testing.assert_allclose(model.at([3700.0])[0], values[1] + 100.0 * model.coef[1], atol=1e-9)
