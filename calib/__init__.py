"""Calibration maths: pure numpy, arrays in, fitted models out. No I/O inside the solvers.

`calib.fit(dataset, model)` fits T24, P12 or the scalar (ellipsoid) model and returns a `Calibration`;
`calib.gram.GramAccumulator` is the streaming T24 solver a running campaign updates live;
`calib.calfile` saves/loads calibration files, `calib.csvio` reads/writes the CSV contract.

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
