"""Calibration maths: pure numpy, arrays in, fitted models out. No I/O inside the solvers.

`calib.fit(dataset, model)` fits T24, T36 (T24 with quadratic temperature terms), P12 or the scalar
(ellipsoid) model and returns a `Calibration`;
`calib.models.gram.GramAccumulator` is the streaming T24 solver a running campaign updates live;
`calib.io.calfile` saves/loads calibration files, `calib.io.csvio` reads/writes the CSV contract;
`calib.checks.model_checks` tests what T24 leaves out, `calib.models.tempmodel` chooses T24 or T36,
`calib.uncertainty.budgeting` states a calibration's uncertainty (linear propagation and adaptive Monte
Carlo).

The three names below are loaded on first use, so `import calib.errors` (which every CLI start needs)
does not import numpy and the solvers.
"""

from __future__ import annotations

import importlib

_HOMES = {"Calibration": "calib.calibration", "Dataset": "calib.dataset", "fit": "calib.fitting"}

__all__ = ["Calibration", "Dataset", "fit"]


def __getattr__(name: str):
    if name not in _HOMES:
        raise AttributeError(f"module 'calib' has no attribute {name!r}")
    value = getattr(importlib.import_module(_HOMES[name]), name)
    globals()[name] = value  # later lookups skip this function
    return value
