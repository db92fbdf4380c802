"""What the compiled parts of calib (gram_kernel, csvfast) share: whether numba may be used, whether it is
worth loading for an input, and how many cores their threads may take."""

from __future__ import annotations

import os


def numba_allowed() -> bool:
    """False when MAGRIG_NO_NUMBA asks for the plain paths (same numbers, no compiling)."""
    return os.environ.get("MAGRIG_NO_NUMBA", "") not in ("1", "true", "yes")


def worth_compiled(size: float, break_even: float) -> bool:
    """Whether an input of `size` (rows, bytes) takes the compiled path: numba allowed and `size` at least
    `break_even`, the size from which the compiled path saves more than loading numba and the cached
    kernels costs a new process (about a second: numba's import and its compiler context). It depends on
    the input alone, never on what the process did before, so one input gives the same numbers in any
    process (the Gram sums of the two paths differ in rounding)."""
    return numba_allowed() and size >= break_even


def cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
