"""End-to-end `rig refit --model t24` of a 1e6-row CSV written to a temporary directory: time per row,
and the share of it spent reading the file (csvio.read_csv as refit calls it). Medians of 3 runs.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
from pathlib import Path

import numpy as np
from timing import median_time

from calib import csvio
from rig.cli import main as rig_main

ROWS = 1_000_000


def main(rows: int = ROWS) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.csv"
        rng = np.random.default_rng(1)
        h, tau = rng.normal(0, 30_000, (rows, 3)), rng.uniform(-30, 70, rows)
        ref = h @ np.diag([1.02, 0.98, 1.01]) + 0.01 * tau[:, None] * h + rng.normal(0, 10, (rows, 3))
        names = ("hx", "hy", "hz", "temp", "bx", "by", "bz")
        csvio.write_csv(path, dict(zip(names, [*h.T, tau, *ref.T], strict=True)))
        size_mb = path.stat().st_size / 1e6
        t_read = median_time(lambda: csvio.read_csv(path, extra_columns=False), repeat=3)
        codes = []

        def refit():
            with contextlib.redirect_stdout(io.StringIO()):  # the fit summary is not the point here
                args = ["refit", str(path), "--model", "t24", "-o", str(Path(tmp) / "cal.yaml")]
                codes.append(rig_main(args))

        t_total = median_time(refit, repeat=3)
    if any(codes):
        sys.exit(max(codes))
    print(
        f"rig refit on {rows:.0e} CSV rows ({size_mb:.0f} MB): {t_total / rows * 1e6:.2f} us/row end to end, "
        f"CSV read {t_read / rows * 1e6:.2f} us/row ({100 * t_read / t_total:.0f} % of it)"
    )


if __name__ == "__main__":
    main()
