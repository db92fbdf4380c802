"""Material that several test workers share, made once per test run: the first worker to come makes it
in a folder of the run's own, under a lock, and the others wait and read it."""

from __future__ import annotations

import fcntl
from collections.abc import Callable
from pathlib import Path


def made_once(tmp_path_factory, name: str, make: Callable[[Path], None]) -> Path:
    """The folder `name` of this test run, `make(folder)` run in it unless a worker already did."""
    base = tmp_path_factory.getbasetemp()  # this run's: a worker's is popen-gwN inside it
    shared = (base.parent if base.name.startswith("popen-gw") else base) / name
    shared.mkdir(exist_ok=True)
    with (shared.parent / f"{name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (shared / "made").is_file():
            make(shared)
            (shared / "made").touch()
    return shared
