"""A 1e6-row CSV (hx,hy,hz,temp,bx,by,bz in shortest exact form, 132 MB) written to a temporary directory:

- reading it with the compiled scanner (calib.io.csvio.read_csv with the compiled paths asked for: the
  scanner on every core, sha256 of the bytes alongside), and with the columnar pyarrow reader, which
  calib uses below csvfast.COMPILED_BREAK_EVEN_BYTES (loading numba would cost a new process more than
  the scanner saves) and wherever the scanner cannot read a file;
- the reference costs of the same bytes: reading them from the page cache, and hashing them;
- `rig refit --model t24` end to end in this process, with the compiled paths and as calib chooses for
  this size (pyarrow, numpy), and the scanner read's share of the first; as a new process:
  bench/startup.py.

Wall-clock medians of 5 (3 for the refit). Thread CPU time of the scanner on one core is printed too:
it does not swing with the machine's load as wall time does.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from timing import compiled_paths, median_time

from calib.io import csvfast, csvio
from rig.cli import main as rig_main

ROWS = 1_000_000
NAMES = ("hx", "hy", "hz", "temp", "bx", "by", "bz")


def _scanner_cpu_s(path: Path) -> float:
    """Thread CPU time of the compiled scanner over the whole file on one core (best of 3)."""
    scan = csvfast._scanner()
    data = path.read_bytes()
    buf = np.frombuffer(data, np.uint8)
    start = data.index(b"\n") + 1
    best = np.inf
    for _ in range(3):
        out = np.empty((data.count(b"\n") + 1, len(NAMES)))
        slow = np.empty((csvfast.SLOW_CELLS, 4), np.int64)
        t0 = time.thread_time()
        scan.parse(buf, start, len(data), 0, np.arange(len(NAMES)), out, out.view(np.uint64), slow)
        best = min(best, time.thread_time() - t0)
    return best


def main(rows: int = ROWS) -> None:
    if csvfast._scanner() is None:
        sys.exit("no compiled scanner (numba missing or MAGRIG_NO_NUMBA set): nothing to measure")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.csv"
        rng = np.random.default_rng(1)
        h, tau = rng.normal(0, 30_000, (rows, 3)), rng.uniform(-30, 70, rows)
        ref = h @ np.diag([1.02, 0.98, 1.01]) + 0.01 * tau[:, None] * h + rng.normal(0, 10, (rows, 3))
        csvio.write_csv(path, dict(zip(NAMES, [*h.T, tau, *ref.T], strict=True)))
        size_mb = path.stat().st_size / 1e6
        per_row = 1e6 / rows
        t_bytes = median_time(path.read_bytes)
        data = path.read_bytes()
        t_hash = median_time(lambda: hashlib.sha256(data).hexdigest())
        with compiled_paths():
            t_read = median_time(lambda: csvio.read_csv(path, extra_columns=False))
        t_cpu = _scanner_cpu_s(path)
        t_columnar = median_time(lambda: csvio.read_csv(path, extra_columns=False))  # calib's choice here
        codes = []

        def refit():
            with contextlib.redirect_stdout(io.StringIO()):  # the fit summary is not the point here
                args = ["refit", str(path), "--model", "t24", "-o", str(Path(tmp) / "cal.yaml")]
                codes.append(rig_main(args))

        with compiled_paths():
            refit()  # the first call loads the compiled kernels from their cache
            t_total = median_time(refit, repeat=3)
        refit()
        t_default = median_time(refit, repeat=3)
    if any(codes):
        sys.exit(max(codes))
    print(f"{rows:.0e} CSV rows, {size_mb:.0f} MB ({size_mb * 1e6 / rows:.0f} bytes/row):")
    print(f"  read with the scanner (+ sha256):         {t_read * per_row:.3f} us/row")
    print(f"  columnar pyarrow reader (calib's choice):  {t_columnar * per_row:.3f} us/row")
    print(f"  scanner alone on one core, CPU time:       {t_cpu * per_row:.3f} us/row "
          f"({t_cpu / (size_mb * 1e6) * 1e9:.2f} ns/byte)")
    print(f"  the bytes from the page cache:             {t_bytes * per_row:.3f} us/row; "
          f"their sha256 {t_hash * per_row:.3f} us/row")
    print(f"rig refit --model t24 end to end, compiled paths: {t_total * per_row:.2f} us/row, "
          f"of which the read {100 * t_read / t_total:.0f} %")
    print(f"rig refit --model t24 end to end as calib chooses for {size_mb:.0f} MB (pyarrow, numpy): "
          f"{t_default * per_row:.2f} us/row")


if __name__ == "__main__":
    main()
