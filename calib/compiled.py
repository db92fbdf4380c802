"""What the compiled parts of calib (gram_kernel, csvfast) share: whether numba may be used, and how
many cores their threads may take."""

from __future__ import annotations

import os


def numba_allowed() -> bool:
    """False when MAGRIG_NO_NUMBA asks for the plain paths (same numbers, no compiling)."""
    return os.environ.get("MAGRIG_NO_NUMBA", "") not in ("1", "true", "yes")


def cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
