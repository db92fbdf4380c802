"""Throughput of the streaming T24 fit, against the time numpy needs just to sum the same input arrays.

Times are medians of 5 runs (the machine is shared). The main figure is the compiled kernel, over one
contiguous part of the rows per core (from 2 x 2**18 rows on); calib runs it for inputs from
gram_kernel.COMPILED_BREAK_EVEN_ROWS rows on (below, loading numba costs a new process more than the
kernel saves, bench/startup.py), so here it is asked for at every size. The one-core figures (wall and
thread CPU time) force a single part. The numpy path calib takes below the break-even is printed too.
The end-to-end `rig refit` of a CSV is bench/csv_refit.py.
"""

from __future__ import annotations

import time
import tracemalloc

import numpy as np
from timing import compiled_paths, median_time

from calib import compiled, synthetic
from calib.models import gram_kernel
from calib.models.gram import GramAccumulator

BREAK_EVEN_ROWS = gram_kernel.COMPILED_BREAK_EVEN_ROWS  # calib's, before compiled_paths() lowers it


def _thread_time(fn) -> float:
    t0 = time.thread_time()
    fn()
    return time.thread_time() - t0


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

    def fit_one_core():
        cores = compiled.cores
        compiled.cores = lambda: 1
        try:
            return fit()
        finally:
            compiled.cores = cores

    t_sum = median_time(lambda: (np.sum(h), np.sum(tau), np.sum(ref)))
    t_fit = median_time(fit)
    # CPU time of this thread, best of 7 taken in turns: what a quiet machine shows on a busy one
    cpu_sum = cpu_fit = np.inf
    for _ in range(7):
        cpu_sum = min(cpu_sum, _thread_time(lambda: (np.sum(h), np.sum(tau), np.sum(ref))))
        cpu_fit = min(cpu_fit, _thread_time(fit_one_core))
    t_one = median_time(fit_one_core)
    t_plain = median_time(lambda: gram_kernel.gram_numpy(h, tau, ref, None, 20.0))
    tracemalloc.start()
    fit()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(
        f"N = {n:.0e}: fit {t_fit * 1e3:.0f} ms, np.sum {t_sum * 1e3:.0f} ms, "
        f"extra peak memory {peak / 1e6:.2f} MB"
    )
    cores = compiled.cores()
    print(f"  throughput: {n / t_fit:.3g} samples/s, {t_fit / t_sum:.2f} x np.sum ({cores} cores)")
    print(f"  one core: {n / t_one:.3g} samples/s, {t_one / t_sum:.2f} x np.sum")
    print(f"  one core, thread CPU time, best of 7: {cpu_fit * 1e3:.0f} ms, {cpu_fit / cpu_sum:.2f} x np.sum")
    print(f"  numpy path (calib's below {BREAK_EVEN_ROWS} rows): Gram sums "
          f"{t_plain * 1e3:.0f} ms, {t_plain / t_sum:.2f} x np.sum")


if __name__ == "__main__":
    if gram_kernel._compiled() is None:
        print("no compiled kernel (numba missing or MAGRIG_NO_NUMBA set): the figures are the numpy path's")
    with compiled_paths():
        streaming(1_000_000)
        streaming(10_000_000)
