"""The field magnitudes a calibration was made at, as guards where it is used (`rig apply`): rows whose |h|
lies well outside them (the calibration is extrapolated there: a scale error grows with |h|), and input whose
magnitudes say it is in another unit than the calibration's (gauss fed as nT reads 1e-5 of the field).

    outside, text = outside_magnitudes([lo, hi], h_nt)   # rows beyond [lo, hi] by more than MARGIN
    suspect = unit_suspected([lo, hi], h_nt)              # "gauss given as nT", or None
"""

from __future__ import annotations

import numpy as np

MARGIN = 0.10  # a row's |h| more than 10 % below the least or above the largest calibrated
# a raw unit's size in nT, and how far off the calibrated magnitudes its numbers land when read as nT
UNIT_NT = {"gauss": 1e5, "mT": 1e6, "uT": 1e3, "nT": 1.0}
UNIT_FACTOR = 30.0  # a typical |h| this far from the calibrated ones is not a field: a unit


def outside_magnitudes(span_nt, h_nt, margin: float = MARGIN) -> np.ndarray:
    """Rows (bool) whose |h| is below (1 - margin) lo or above (1 + margin) hi of the calibrated span."""
    lo, hi = float(span_nt[0]), float(span_nt[1])
    norm = np.linalg.norm(np.atleast_2d(np.asarray(h_nt, float)), axis=1)
    return (norm < (1 - margin) * lo) | (norm > (1 + margin) * hi)


def unit_suspected(span_nt, h_nt) -> str | None:
    """Words for the unit mistake the input's median |h| suggests (e.g. "values about 1e-05 of the
    calibrated magnitudes: gauss given as nT?"), or None when its magnitudes are within UNIT_FACTOR of
    the calibrated ones."""
    norm = np.linalg.norm(np.atleast_2d(np.asarray(h_nt, float)), axis=1)
    norm = norm[np.isfinite(norm)]
    middle = float(np.sqrt(float(span_nt[0]) * float(span_nt[1])))
    if not norm.size or middle <= 0:
        return None
    ratio = float(np.median(norm)) / middle
    if ratio <= 0 or 1 / UNIT_FACTOR < ratio < UNIT_FACTOR:
        return None
    # the unit whose size in nT best explains the ratio (numbers in that unit read as nT)
    guess = min((u for u in UNIT_NT if u != "nT"), key=lambda u: abs(np.log10(ratio * UNIT_NT[u])))
    if abs(np.log10(ratio * UNIT_NT[guess])) < 1:
        why = f"{guess} given as nT?"
    elif ratio > 1:
        why = "counts given as nT, or the wrong --counts-per-unit?"
    else:
        why = "the wrong --raw-unit?"
    return f"values about {ratio:.0e} of the calibrated magnitudes: {why}"
