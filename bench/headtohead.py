"""Head to head on the same synthetic scalar-calibration data: ours against PyPI magcal 1.0.1 and magcc 0.1.1.

Install the other tools into the environment yourself to measure them (they are not dependencies):
    pip install magcal==1.0.1 magcc==0.1.1
A tool that fails to install or import is skipped with a message.

Data: 2000 random orientations in a 50000 nT field, 10 nT noise per axis, ~2 % scale, ~2 % cross-axis,
2000 nT offsets. Errors on 5000 fresh readings: |B| error RMS, and vector error RMS after the best rotation
(scalar calibration fixes the field only up to a rotation, for every tool alike).
"""

from __future__ import annotations

import numpy as np

import calib
from calib import synthetic

FIELD_NT = 50_000.0


def best_rotation_rms(estimate: np.ndarray, truth: np.ndarray) -> float:
    """RMS of R estimate - truth with R the best proper rotation (Kabsch)."""
    u, _, vt = np.linalg.svd(estimate.T @ truth)
    d = np.sign(np.linalg.det(u @ vt))
    rot = (u @ np.diag([1, 1, d]) @ vt).T
    return float(np.sqrt(np.mean(np.sum((estimate @ rot.T - truth) ** 2, axis=1))))


def ours(train):
    cal = calib.fit(train, "scalar", field_norm_nt=FIELD_NT)
    return cal.apply


def magcc_lm(train):
    from magcc.magcc import calibrate_lm

    hard, soft, _, _ = calibrate_lm(train.h_nt, FIELD_NT)
    return lambda h: (h - hard) @ soft.T


def magcal_ellipsoid(train):
    from magcal.core import MagnetometerCalibrator

    fitter = MagnetometerCalibrator.__new__(MagnetometerCalibrator)  # no serial port needed for fitting
    p = fitter.ellipsoid_fit(train.h_nt)
    # magcal maps onto a unit sphere; scale to the known field for a fair |B| comparison
    return lambda h: FIELD_NT * (h - p["center"]) @ p["transform_matrix"].T


def main() -> None:
    tools = {
        "magrig scalar (ours)": ours,
        "magcc 0.1.1 calibrate_lm": magcc_lm,
        "magcal 1.0.1 ellipsoid_fit": magcal_ellipsoid,
    }
    results = {name: ([], []) for name in tools}
    for seed in range(10):
        rng = np.random.default_rng(seed)
        train, truth = synthetic.scalar_dataset(rng, n=2000, field_nt=FIELD_NT)
        val, _ = synthetic.scalar_dataset(rng, params=truth.params, n=5000, field_nt=FIELD_NT)
        true_field = truth.apply(val.h_nt)
        for name, tool in list(tools.items()):
            try:
                apply = tool(train)
            except Exception as err:  # another tool's failure only skips that tool
                print(f"skipping {name}: {type(err).__name__}: {err}")
                del tools[name]
                continue
            field = apply(val.h_nt)
            results[name][0].append(np.sqrt(np.mean((np.linalg.norm(field, axis=1) - FIELD_NT) ** 2)))
            results[name][1].append(best_rotation_rms(field, true_field))
    print("head to head, 10 seeds, 10 nT noise per axis (lower is better):")
    print(f"  {'tool':30s} {'|B| error RMS (nT)':>20s} {'vector error RMS (nT)':>22s}")
    for name, (norm_err, vec_err) in results.items():
        if norm_err:
            print(f"  {name:30s} {np.mean(norm_err):20.2f} {np.mean(vec_err):22.2f}")


if __name__ == "__main__":
    main()
