"""Wall-clock timing shared by the benches (run as scripts: `python bench/NAME.py`)."""

from __future__ import annotations

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
