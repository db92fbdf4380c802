"""Every budget of a session (each DUT's T24, P12 and scalar calibration), timed: one process, or the DUTs
split over --jobs processes. Imports only `rig` and `calib`, from wherever PYTHONPATH points, so that
bench/uncertainty_timing.py times an older commit's code with it too.

    PYTHONPATH=CODE python bench/budget_timer.py SESSION [--jobs 2]     # prints the seconds

With --jobs N the DUTs are split over N processes, each timing its own budgets once its session is read
and its calibrations fitted; the figure is the slowest one's (they run side by side).
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor

MODELS = ("t24", "p12", "scalar")


def budgets(args) -> float:
    session, duts = args
    import calib
    from rig.budget.run_inputs import RunInputs
    from rig.session.reader import SessionReader

    with SessionReader(session) as reader:
        run = RunInputs.of_session(reader)
        data = {d: run.refined(reader.dataset(d))[0] for d in duts}
    cals = {}
    for d, ds in data.items():
        for model in MODELS:
            try:
                cals[d, model] = calib.fit(ds, model)
            except Exception:  # noqa: BLE001 - a model that cannot be fitted has no budget to time
                continue
    start = time.perf_counter()
    for (d, _), cal in cals.items():
        try:
            run.budget(d, data[d], cal)
        except Exception:  # noqa: BLE001 - a budget that cannot be made still took its time
            continue
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("session")
    parser.add_argument("--jobs", type=int, default=1)
    args = parser.parse_args()
    from rig.session.reader import SessionReader

    with SessionReader(args.session) as reader:
        duts = reader.duts()
    if args.jobs == 1:
        print(f"{budgets((args.session, duts)):.3f}")
        return
    parts = [(args.session, duts[i::args.jobs]) for i in range(args.jobs)]
    with ProcessPoolExecutor(args.jobs) as pool:  # the budgets' own time in each, side by side
        print(f"{max(pool.map(budgets, parts)):.3f}")


if __name__ == "__main__":
    main()
