"""Throughput of the streaming T24 fit, against the time numpy needs just to sum the same input arrays.

Times are medians of 5 runs (the machine is shared). The main figure is one thread; a second line
splits the rows over two threads with one accumulator each, merged (see README: little gain here).
Also the end-to-end time per row of `rig refit` on a 1e6-row CSV (read, fit, statistics, write).
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
import time
import tracemalloc
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from calib import csvio, synthetic
from calib.gram import GramAccumulator
from rig.cli import main as rig_main


def _median_time(fn, repeat: int = 5) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _inputs(n: int, rng: np.random.Generator):
    params = synthetic.random_t24_params(rng)
    tau = rng.uniform(-30, 70, n)
    h = rng.normal(0, 30_000, (n, 3))
    ref = (
        h @ params["S"].T
        + tau[:, None] * (h @ params["K"].T)
        + params["b_nt"]
        + tau[:, None] * params["kb_nt_per_c"]
    )
    ref += rng.normal(0, 10, ref.shape)
    return h, tau, ref


def streaming(n: int) -> None:
    h, tau, ref = _inputs(n, np.random.default_rng(0))

    def fit():
        acc = GramAccumulator(20.0)
        acc.add(h, tau, ref)
        return acc.solve()

    def fit_two_threads():
        halves = [GramAccumulator(20.0), GramAccumulator(20.0)]
        rows = (slice(0, n // 2), slice(n // 2, n))
        with ThreadPoolExecutor(2) as pool:  # numpy and BLAS release the GIL
            list(pool.map(lambda acc, sl: acc.add(h[sl], tau[sl], ref[sl]), halves, rows))
        return halves[0].merge(halves[1]).solve()

    t_sum = _median_time(lambda: (np.sum(h), np.sum(tau), np.sum(ref)))
    t_fit = _median_time(fit)
    t_two = _median_time(fit_two_threads)
    tracemalloc.start()
    fit()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(
        f"N = {n:.0e}: fit {t_fit * 1e3:.0f} ms, np.sum {t_sum * 1e3:.0f} ms, "
        f"extra peak memory {peak / 1e6:.2f} MB"
    )
    print(f"  throughput: {n / t_fit:.3g} samples/s, {t_fit / t_sum:.2f} x np.sum")
    print(f"  two threads, merged halves: {n / t_two:.3g} samples/s, {t_two / t_sum:.2f} x np.sum")


def end_to_end(rows: int = 1_000_000) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.csv"
        h, tau, ref = _inputs(rows, np.random.default_rng(1))
        csvio.write_csv(
            path,
            {
                "hx": h[:, 0],
                "hy": h[:, 1],
                "hz": h[:, 2],
                "temp": tau,
                "bx": ref[:, 0],
                "by": ref[:, 1],
                "bz": ref[:, 2],
            },
        )
        t0 = time.perf_counter()
        csvio.read_csv(path)
        t_read = time.perf_counter() - t0
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):  # the fit summary is not the point here
            code = rig_main(["refit", str(path), "--model", "t24", "-o", str(Path(tmp) / "cal.yaml")])
        t_total = time.perf_counter() - t0
    if code:
        sys.exit(code)
    print(
        f"rig refit on {rows:.0e} CSV rows: {t_total / rows * 1e6:.2f} us/row end to end "
        f"(CSV read alone {t_read / rows * 1e6:.2f} us/row)"
    )


if __name__ == "__main__":
    streaming(1_000_000)
    streaming(10_000_000)
    end_to_end()
