"""Calibration maths: pure numpy, arrays in, fitted models out. No I/O inside the solvers.

`calib.fit(dataset, model)` fits T24, P12 or the scalar (ellipsoid) model and returns a `Calibration`;
`calib.gram.GramAccumulator` is the streaming T24 solver a running campaign updates live;
`calib.calfile` saves/loads calibration files, `calib.csvio` reads/writes the CSV contract.
"""

from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.fitting import fit

__all__ = ["Calibration", "Dataset", "fit"]
