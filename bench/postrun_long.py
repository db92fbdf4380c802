"""The post-run fits of a long session, timed per model, and how far their budgets moved from a saved run.

    PYTHONPATH=CODE python bench/postrun_long.py SESSION --dut dut3 --save before.json   # CODE's figures
    PYTHONPATH=. python bench/postrun_long.py SESSION --dut dut3 --against before.json   # and the change

Each model (T24, P12, scalar) is fitted and budgeted as `rig refit SESSION --dut D --model M` does it
(rig/analysis/sessionfit.py: references with the run's best ambient, the session's plan options); the
seconds are those of the fit with its budget (wall and the process's CPU time), the session read once.
With --against, prints the largest relative change of any budget line (contribution_nt), of the
parameters' expanded uncertainties and of expanded_vector_error_nt. Copy a session before timing it:
reading one takes its lock.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

MODELS = ("t24", "p12", "scalar")


def figures(session: str, dut: str, models) -> dict:
    from rig.analysis.sessionfit import SessionFitter
    from rig.session.reader import SessionReader, read_dataset

    start = time.perf_counter()
    ds = read_dataset(session, dut)
    with SessionReader(session) as reader:
        fitter = SessionFitter.of(reader)
    prepared = fitter.prepare(ds)
    out = {"read_s": time.perf_counter() - start, "rows": len(ds), "models": {}}
    for model in models:
        start, cpu = time.perf_counter(), time.process_time()
        cal, b = fitter.calibrate_budgeted(prepared, model)
        seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
        u = cal.uncertainty or {}
        out["models"][model] = {
            "seconds": seconds,
            "cpu_s": cpu,  # the process's CPU time: less moved by other loads than the wall time
            "method": u.get("method", ""),
            "budget": {c["source"]: c["contribution_nt"] for c in u.get("budget", [])},
            "expanded": {k: np.ravel(v).tolist() for k, v in (u.get("expanded") or {}).items()},
            "expanded_vector_error_nt": u.get("expanded_vector_error_nt"),
            "warnings": cal.stats.get("warnings", []),
        }
    return out


def _rel(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = np.maximum(np.abs(a), np.abs(b))
    return float(np.max(np.where(scale > 0, np.abs(a - b) / np.where(scale > 0, scale, 1.0), 0.0),
                        initial=0.0))


def compare(now: dict, before: dict) -> None:
    for model, m in now["models"].items():
        old = before["models"].get(model)
        line = f"{model:7s} {m['seconds']:7.2f} s (cpu {m['cpu_s']:7.2f} s)"
        if old is not None:
            lines = [_rel(m["budget"][k], old["budget"][k]) for k in m["budget"] if k in old["budget"]]
            missing = set(m["budget"]) ^ set(old["budget"])
            params = [_rel(m["expanded"][k], old["expanded"][k]) for k in m["expanded"]]
            old_cpu = old.get("cpu_s", float("nan"))
            line += (f"  before {old['seconds']:7.2f} s (cpu {old_cpu:7.2f} s)"
                     f"  budget lines {max(lines, default=0):.2e}"
                     f"  expanded {max(params, default=0):.2e}  expanded_vector_error_nt "
                     f"{_rel(m['expanded_vector_error_nt'], old['expanded_vector_error_nt']):.2e}"
                     + (f"  lines only in one: {sorted(missing)}" if missing else ""))
        print(line)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("session")
    parser.add_argument("--dut", default="dut3")
    parser.add_argument("--models", default=",".join(MODELS))
    parser.add_argument("--save")
    parser.add_argument("--against")
    args = parser.parse_args()
    now = figures(args.session, args.dut, args.models.split(","))
    print(f"{args.dut}: {now['rows']} rows, read and prepared in {now['read_s']:.2f} s")
    before = {"models": {}}
    if args.against:
        with open(args.against) as f:
            before = json.load(f)
    compare(now, before)
    if args.save:
        with open(args.save, "w") as f:
            json.dump(now, f, indent=1)


if __name__ == "__main__":
    main()
