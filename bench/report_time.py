"""Time to build the calibration report of a full campaign.

    python bench/report_time.py [--temps 8] [--fields 48] [--samples 50] [--duts 2] [--keep DIR]
    python bench/report_time.py --session SESSION     # time the report of an existing session instead

The synthetic session is the size of configs/plans/full-campaign.yaml (8 temperatures x 48 field vectors,
the cube's 24 rotations at 30 and 60 uT, x 50 samples x 2 DUTs = 38 400 samples). It is written through
the store API (rig.session.writer.Session) with calib's synthetic T24 data, 1 % outliers and a few flagged
samples. Then the report is built from it as `rig report` builds it: three models fitted per DUT (robust), a
5-fold held-out comparison of each, the figures and the HTML page. Printed: wall seconds for the session file
and for the whole report, and where the report's time goes.

--blas-threads (default 1) sets OPENBLAS_NUM_THREADS before numpy loads: on a small machine shared with
other work, OpenBLAS's own threads fight for the cores and the scalar model's fits slow down by 10x or
more; "auto" leaves the library's default.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TEMPS_C = (-30.0, -15.0, 0.0, 15.0, 25.0, 40.0, 55.0, 70.0)


def field_vectors(n: int):
    """The full campaign's field set: 24 cube rotations at 30 and 60 uT (48); other n: Fibonacci at 50 uT."""
    from calib.stats.directions import fibonacci_directions
    from rig.fieldsources import fieldsets

    if n == 48:
        return fieldsets.scaled(fieldsets.cube24_directions(), [30_000.0, 60_000.0])
    return 50_000.0 * fibonacci_directions(n)


def write_synthetic_session(path: Path, args) -> None:
    import numpy as np

    sys.path.insert(0, str(REPO))  # the synthetic session generator is a test helper
    from tests.helpers.synthetic_session import SynthOptions, build_session

    temps = TEMPS_C[: args.temps] if args.temps <= len(TEMPS_C) else tuple(np.linspace(-30, 70, args.temps))
    opts = SynthOptions(
        temps_c=temps,
        field_vectors_nt=field_vectors(args.fields),
        samples=args.samples,
        duts=tuple(f"dut{i + 1}" for i in range(args.duts)),
        outlier_fraction=0.01,
        saturated_points=("T03-F07", "T05-F30"),
        finish="completed",
    )
    path.unlink(missing_ok=True)
    t0 = time.perf_counter()
    build_session(path, opts)
    n = args.temps * args.fields * args.samples * args.duts
    print(
        f"session: {args.temps} temperatures x {args.fields} fields x {args.samples} samples x "
        f"{args.duts} DUTs = {n} samples, {path.stat().st_size / 1e6:.1f} MB, "
        f"written through the store in {time.perf_counter() - t0:.2f} s"
    )


def time_report(session: Path, out_dir: Path) -> None:
    from rig.report import build, evaluate, page

    t0 = time.perf_counter()
    html_path = build.build_report(session, out_dir=out_dir)
    t_total = time.perf_counter() - t0
    print(
        f"report: {t_total:.2f} s wall for the whole report ({html_path.stat().st_size / 1e6:.1f} MB HTML, "
        f"{len(list(out_dir.glob('*.png')))} PNG figures)"
    )

    t0 = time.perf_counter()
    inputs = build.read_inputs(session)
    t_read = time.perf_counter() - t0
    t0 = time.perf_counter()
    results = [evaluate.analyse_dut(d, inputs.steps) for d in inputs.duts]
    t_analyse = time.perf_counter() - t0
    t0 = time.perf_counter()
    for r in results:
        page.dut_figures(r)
    t_figures = time.perf_counter() - t0
    print(
        f"  where it goes (measured again, piece by piece): read the session {t_read:.2f} s, "
        f"fits + 5-fold comparison {t_analyse:.2f} s, "
        f"figures {t_figures:.2f} s (one DUT after another, on one core)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--temps", type=int, default=8)
    ap.add_argument("--fields", type=int, default=48)
    ap.add_argument("--samples", type=int, default=50)
    ap.add_argument("--duts", type=int, default=2)
    ap.add_argument("--session", type=Path, help="Report on this session file instead of a synthetic one.")
    ap.add_argument("--keep", type=Path, help="Write the session and report here (default: a temp folder).")
    ap.add_argument("--blas-threads", default="1", help="OPENBLAS_NUM_THREADS for this run, or 'auto'.")
    args = ap.parse_args()
    if args.blas_threads != "auto":
        os.environ["OPENBLAS_NUM_THREADS"] = args.blas_threads  # before numpy is first imported
    print(
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset (library default)')}, "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        session = args.session
        if session is None:
            session = folder / "full-campaign.session"
            write_synthetic_session(session, args)
        time_report(session, folder / "report")


if __name__ == "__main__":
    main()
