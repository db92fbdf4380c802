"""A new process's cost: `rig --version`, and `rig refit --model t24` of a 1e6-row CSV (the file of
csv_refit.py) run as a new process (with and without MAGRIG_NO_NUMBA=1), against the same refit inside
a process that has already run it once, first on the paths calib chooses for this size (pyarrow, numpy),
then with the compiled scanner and Gram kernel asked for. Wall-clock medians of 7 new processes (5
in-process refits), one untimed run first (page cache, and the compiled kernels' on-disk cache).
Process CPU time (user + sys) of the new processes too: it swings less with the load than wall time.

`python -X importtime -c 'from rig.cli import main; main(["--version"])'` shows where the imports go.
"""

from __future__ import annotations

import contextlib
import io
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from timing import compiled_paths, median_time

from calib.io import csvfast, csvio
from calib.models import gram_kernel
from rig.cli import main as rig_main

ROWS = 1_000_000
NAMES = ("hx", "hy", "hz", "temp", "bx", "by", "bz")
RIG = [str(Path(sys.executable).parent / "rig")]  # the installed command, as a user runs it


def write_csv(path: Path, rows: int) -> None:
    rng = np.random.default_rng(1)
    h, tau = rng.normal(0, 30_000, (rows, 3)), rng.uniform(-30, 70, rows)
    ref = h @ np.diag([1.02, 0.98, 1.01]) + 0.01 * tau[:, None] * h + rng.normal(0, 10, (rows, 3))
    csvio.write_csv(path, dict(zip(NAMES, [*h.T, tau, *ref.T], strict=True)))


def new_process(args: list[str], repeat: int = 7, env: dict | None = None) -> tuple[float, float]:
    """(median wall time, median CPU time user + sys) of `rig ARGS` as a new process, in seconds."""
    walls, cpus = [], []
    for k in range(repeat + 1):  # the first run warms the page cache and the kernels' on-disk cache
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        subprocess.run(RIG + args, check=True, stdout=subprocess.DEVNULL, env=env)
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if k:
            walls.append(wall)
            cpus.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return float(np.median(walls)), float(np.median(cpus))


def main(rows: int = ROWS) -> None:
    no_numba = {**os.environ, "MAGRIG_NO_NUMBA": "1"}
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    wall, cpu = new_process(["--version"])
    print(f"rig --version, new process: {wall:.3f} s (CPU {cpu:.3f} s)")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.csv"
        write_csv(path, rows)
        args = ["refit", str(path), "--model", "t24", "-o", str(Path(tmp) / "cal.yaml")]
        t_new = new_process(args)
        t_plain = new_process(args, repeat=3, env=no_numba)

        def in_process():
            with contextlib.redirect_stdout(io.StringIO()):
                if rig_main(args):
                    sys.exit("rig refit failed")

        in_process()
        t_in = median_time(in_process)
        t_in_compiled = float("nan")
        if gram_kernel._compiled() is not None and csvfast._scanner() is not None:
            with compiled_paths():
                in_process()
                t_in_compiled = median_time(in_process)
    print(f"rig refit --model t24 of {rows:.0e} CSV rows:")
    print(f"  new process:                           {t_new[0]:.3f} s (CPU {t_new[1]:.3f} s)")
    print(f"  new process, MAGRIG_NO_NUMBA=1:        {t_plain[0]:.3f} s (CPU {t_plain[1]:.3f} s)")
    print(f"  inside a process that ran it once:     {t_in:.3f} s "
          f"(so starting costs {t_new[0] - t_in:.3f} s)")
    print(f"  inside it, compiled paths asked for:   {t_in_compiled:.3f} s")


if __name__ == "__main__":
    main()
