"""Wall-clock timing shared by the benches (run as scripts: `python bench/NAME.py`)."""

from __future__ import annotations

import contextlib
import time

import numpy as np


def median_time(fn, repeat: int = 5) -> float:
    """Median wall time of `repeat` calls of fn(), in seconds."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


@contextlib.contextmanager
def compiled_paths():
    """The compiled scanner and Gram kernel for every input size while inside (calib takes them only
    from their break-even sizes on, where they repay loading numba in a new process)."""
    from calib.io import csvfast
    from calib.models import gram_kernel

    saved = csvfast.COMPILED_BREAK_EVEN_BYTES, gram_kernel.COMPILED_BREAK_EVEN_ROWS
    csvfast.COMPILED_BREAK_EVEN_BYTES = gram_kernel.COMPILED_BREAK_EVEN_ROWS = 0
    try:
        yield
    finally:
        csvfast.COMPILED_BREAK_EVEN_BYTES, gram_kernel.COMPILED_BREAK_EVEN_ROWS = saved
