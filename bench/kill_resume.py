"""kill -9 the demo campaign at 20 random moments (one fresh run each), resume each with
`rig run --resume`, and tally: every session must end complete with exactly the planned points and
samples, none recorded twice.

    python bench/kill_resume.py [--kills 20] [--seed 0]
"""

from __future__ import annotations

import argparse
import random
import signal
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rig.config.loading import load_campaign  # noqa: E402
from rig.schedules.compile import compile_plan  # noqa: E402
from tests.system.campaign_helpers import (  # noqa: E402
    DEMO_PLAN,
    SIM_STATION,
    popen_rig,
    run_rig,
    session_counts,
)


def one_kill(tmp: Path, station: Path, delay_s: float, n_points: int, expected: dict) -> tuple[str, str]:
    """(outcome, detail) of one kill-and-resume cycle."""
    session = tmp / "run.session"
    proc = popen_rig("run", str(DEMO_PLAN), "--station", str(station), "--session", str(session), "--no-live")
    time.sleep(delay_s)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    if proc.returncode == 0:
        return "finished before the kill", ""
    if not session.exists():
        return "killed before the session existed", ""
    done_before = session_counts(session)["done"]
    resumed = run_rig("run", "--resume", str(session), "--no-live", timeout=180)
    if resumed.returncode != 0:
        return "resume FAILED", resumed.stderr.strip().splitlines()[-1]
    after = session_counts(session)
    ok = (after["completed"] and after["done"] == after["planned"] == n_points
          and after["per_point_dut"] == expected and after["orphan_samples"] == 0)
    detail = f"killed after {done_before} points"
    if not ok:
        detail += f"; after resume: {after['done']} of {after['planned']} done, status {after['status']}"
    return ("complete, exact" if ok else "WRONG"), detail


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--kills", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    tally: dict[str, int] = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp_root:
        station = SIM_STATION
        campaign = load_campaign(DEMO_PLAN, station)
        points = compile_plan(campaign.plan, campaign.station)
        per_point = campaign.plan.samples_per_point
        expected = {(p.id, d.name): per_point for p in points for d in campaign.station.duts}
        for i in range(args.kills):
            delay_s = rng.uniform(0.3, 8.0)  # the demo takes 8-10 s here, start-up included
            with tempfile.TemporaryDirectory(dir=tmp_root) as tmp:
                outcome, detail = one_kill(Path(tmp), station, delay_s, len(points), expected)
            tally[outcome] = tally.get(outcome, 0) + 1
            print(f"kill {i + 1:2d} at {delay_s:5.2f} s: {outcome} {detail}", flush=True)
    print(f"tally over {args.kills} kills ({time.perf_counter() - t0:.0f} s):")
    for outcome, n in sorted(tally.items()):
        print(f"  {outcome}: {n}")


if __name__ == "__main__":
    main()
