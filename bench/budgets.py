"""The uncertainty budgets of a 64-DUT campaign (calib/uncertainty/budgeting.py): time per DUT and model, and
the whole campaign's budgets on one process and on two.

Each DUT: the demo plan's data (26 coil fields at -20 and 60 degC, 5 samples each: 260 samples) of a
synthetic T24 sensor, fitted with T24, P12 and the scalar model, and the inputs rig/budget.py draws today,
described as input quantities: the coil matrix (9 entries, 100 ppm), the reference magnetometer (its
calibration as B = T B' + d: 9 + 3 quantities, 20 ppm and 2 nT), the ambient (3, 2 nT), the DUT's position
(3, +-0.5 mm rectangular, 0.1 %/mm), the coil geometry (6, +-0.5 mm rectangular) and the temperature
(offset +-0.3 degC and gradient +-0.005 degC/degC, rectangular). The grid: the 26 fields at both ends.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/budgets.py [--duts 64] [--never]

--never: the law of propagation alone (no Monte Carlo), for comparison.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import calib  # noqa: E402
from calib import synthetic  # noqa: E402
from calib.uncertainty.budgeting import budget  # noqa: E402
from calib.uncertainty.propagation import InputSource, matrix_source, offset_source, temperature_source  # noqa: E402

COIL_NT_PER_A = 10_000.0
MODELS = ("t24", "p12", "scalar")


def dut_inputs(seed: int):
    rng = np.random.default_rng(seed)
    ds, _ = synthetic.t24_dataset(rng, temps_c=(-20.0, 60.0), samples_per_point=5)
    n, currents = len(ds), ds.ref_nt / COIL_NT_PER_A
    m = COIL_NT_PER_A * np.eye(3)
    reference = np.zeros((n, 3, 12))  # B = T B' + d: the change (dT B', dd) of every reference
    for i in range(3):
        reference[:, i, 3 * i:3 * i + 3] = ds.ref_nt
        reference[:, i, 9 + i] = 1.0
    sources = [
        matrix_source("coil matrix", currents, np.eye(9).reshape(9, 3, 3), np.eye(9) * (100e-6 * 1e4) ** 2,
                      shared="coil matrix"),
        InputSource("reference magnetometer", np.diag([20e-6**2] * 9 + [4.0] * 3), ref_nt=reference),
        offset_source("ambient", n, np.eye(3) * 4.0, shared="ambient"),
        matrix_source("position", currents, 1e-3 * m[None] * rng.normal(size=(3, 3, 3)), np.eye(3) * 0.25 / 3,
                      distribution="rectangular"),
        matrix_source("coil geometry", currents, 1e-3 * m[None] * rng.normal(size=(6, 3, 3)),
                      np.eye(6) * 0.25 / 3, distribution="rectangular"),
        temperature_source("temperature", np.column_stack([np.ones(n), ds.temp_c - 25.0]),
                           np.diag([0.3**2 / 3, 0.005**2 / 3]), distribution="rectangular"),
    ]
    fields = 50_000.0 * synthetic.coil_directions()
    grid = (np.repeat(fields, 2, axis=0), np.tile([-20.0, 60.0], len(fields)))
    return ds, sources, grid


def one_dut(args) -> dict[str, float]:
    seed, never = args
    ds, sources, grid = dut_inputs(seed)
    out = {}
    for model in MODELS:
        cal = calib.fit(ds, model)
        start = time.perf_counter()
        b = budget(ds, cal, sources, grid, rng=np.random.default_rng(seed),
                   monte_carlo="never" if never else "auto")
        out[model] = time.perf_counter() - start
        out[model + " draws"] = b.draws
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--duts", type=int, default=64)
    parser.add_argument("--never", action="store_true")
    args = parser.parse_args()
    jobs = [(seed, args.never) for seed in range(args.duts)]
    one_dut(jobs[0])  # imports and first calls out of the figures
    start = time.perf_counter()
    rows = [one_dut(job) for job in jobs]
    serial = time.perf_counter() - start
    with ProcessPoolExecutor(2) as pool:
        list(pool.map(one_dut, jobs[:2]))
        start = time.perf_counter()
        list(pool.map(one_dut, jobs))
        parallel = time.perf_counter() - start
    how = "law of propagation only" if args.never else "auto (Monte Carlo where needed)"
    print(f"{args.duts} DUTs, {how}")
    for model in MODELS:
        t = np.array([r[model] for r in rows]) * 1e3
        d = np.array([r[model + " draws"] for r in rows])
        print(f"  {model:7s} per DUT: median {np.median(t):6.1f} ms, max {t.max():6.1f} ms; "
              f"draws median {np.median(d):.0f}, max {d.max():.0f}")
    print(f"  all budgets: {serial:.2f} s on one process, {parallel:.2f} s on two")


if __name__ == "__main__":
    main()
