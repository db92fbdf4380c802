"""T24 fit of an in-memory dataset through the streaming Gram accumulator."""

from __future__ import annotations

import numpy as np

from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.equations import t24_regressors
from calib.errors import DataError
from calib.models.gram import GramAccumulator, absolute_transform, unpack
from calib.stats.residuals import default_temp_ref_c


def fit_weighted(ds: Dataset, weights: np.ndarray | None, temp_ref_c: float | None):
    """(Calibration, vector residuals (N,3)) of a weighted T24 fit."""
    if ds.temp_c is None:
        raise DataError("T24 needs the DUT temperature of every sample (column temp); fit P12 without it")
    if ds.ref_nt is None:
        raise DataError("T24 needs the reference field vector of every sample (columns bx,by,bz)")
    ref_c = default_temp_ref_c(ds.temp_c) if temp_ref_c is None else temp_ref_c
    acc = GramAccumulator(ref_c)
    acc.add(ds.h_nt, ds.temp_c, ds.ref_nt, weights)
    cal: Calibration = acc.solve()
    residuals = cal.apply(ds.h_nt, ds.temp_c)  # a fresh array: the reference is taken off in place
    residuals -= ds.ref_nt
    return cal, residuals


def reference_map(ds: Dataset, weights: np.ndarray | None, temp_ref_c: float):
    """For fixed readings and temperatures the T24 parameters are linear in the reference vectors: the
    function from a change of the references (N,3) to the change of every parameter (the uncertainty
    budget's fast path for inputs that move only the reference)."""
    x = t24_regressors(ds.h_nt, ds.temp_c, temp_ref_c)
    w = np.ones(len(ds)) if weights is None else np.asarray(weights, float)
    scale = np.linalg.norm(x * np.sqrt(w)[:, None], axis=0)
    xs = x / scale
    solve = np.linalg.solve(xs.T @ (xs * w[:, None]), (xs * w[:, None]).T) / scale[:, None]  # (8,N)
    to_abs = absolute_transform(temp_ref_c)

    def change(ref_change_nt: np.ndarray) -> dict[str, np.ndarray]:
        return unpack(to_abs @ (solve @ ref_change_nt))

    return change
