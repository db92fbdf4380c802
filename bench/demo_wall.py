"""The demo's wall time on 64 DUTs against 2 (bench/uncertainty_timing.py's timing without the budgets):
`rig run` of configs/plans/demo.yaml on configs/stations/sim-64.yaml, on the README's demo station
(configs/stations/sim.yaml: an MMC5983MA and a serial magnetometer, "readme") and on two of sim-64's
MMC5983MA ("2": the same world and kinds as the 64), each in a new process, --repeat times in turn; each
run's wall time, its CPU time (user + system: on a machine other work shares, the steadier figure), the
post-run fits' share, and the medians' ratios of the 64 to each. --before COMMIT runs that commit's code
(a `git archive` copy) in turn with this one, so both come from the same minutes of the same machine
(several commits: each in turn, the figures per change). The ratios are also given without the post-run
fits. --free-physics runs every version in a world whose DUT physics costs nearly nothing
(bench/free_physics.py): what is left, less the post-run fits, is the floor that the drivers, the
register transfers, the session and the engine set on the ratio.

    python bench/demo_wall.py [--repeat 1] [--out DIR] [--only 64|2|readme] [--before COMMIT ...]
                              [--free-physics]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.uncertainty_timing import REPO, STATION64, _checkout, _postrun_s, _run, _two_duts  # noqa: E402

README_STATION = REPO / "configs" / "stations" / "sim.yaml"


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--only", choices=["64", "2", "readme"])
    parser.add_argument("--before", nargs="*", default=[], help="commits to time in turn with this code")
    parser.add_argument("--free-physics", action="store_true", help="the DUTs' physics costing nothing")
    args = parser.parse_args()
    launcher = Path(__file__).with_name("free_physics.py") if args.free_physics else None
    out = args.out or Path(tempfile.mkdtemp(prefix="demo-wall-"))
    out.mkdir(parents=True, exist_ok=True)
    two = _two_duts(out)
    codes = [("after", REPO)] + [(commit[:8], _checkout(commit, out)) for commit in args.before]
    runs: dict[tuple[str, str], list[tuple[float, float, float]]] = {}
    for k in range(args.repeat):
        for version, code in codes:
            for label, station in (("64", STATION64), ("2", two), ("readme", README_STATION)):
                if args.only and label != args.only:
                    continue
                cpu0 = _children_cpu_s()
                wall, session = _run(code, station, out / version / f"{label}-{k}", launcher)
                cpu = _children_cpu_s() - cpu0
                fits = _postrun_s(session) or 0.0
                runs.setdefault((version, label), []).append((wall, cpu, wall - fits))
                print(f"{version}: {label} {wall:.1f} s wall, {cpu:.1f} s CPU (post-run fits "
                      f"{fits:.1f} s)", flush=True)
    for version, _ in codes:
        for two_label, what in (("2", "2 of its MMC5983MA"), ("readme", "the README demo")):
            if (version, "64") in runs and (version, two_label) in runs:
                w64, c64, b64 = (statistics.median(x) for x in zip(*runs[(version, "64")], strict=True))
                w2, c2, b2 = (statistics.median(x) for x in zip(*runs[(version, two_label)], strict=True))
                print(f"{version}, medians: 64 DUTs {w64:.1f} s wall ({c64:.1f} s CPU), {what} {w2:.1f} s "
                      f"({c2:.1f} s CPU): ratio {w64 / w2:.2f} wall, {c64 / c2:.2f} CPU; without the "
                      f"post-run fits {b64:.1f} / {b2:.1f} s = {b64 / b2:.2f}")


if __name__ == "__main__":
    main()
