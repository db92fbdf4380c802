"""A campaign in a process of its own that stops at a moment the test chooses, never after a wall-clock
sleep: `python -m tests.system.controlled_run SESSION PLAN STATION --at WHERE:N --then kill|hold`.

WHERE says when, counted in the run's own recorded points:
    point:N    after the N-th point is recorded (between two points);
    collect:N  inside the N-th point's collection, its samples read, nothing of it recorded yet;
    commit:N   inside the N-th point's write transaction, its samples inserted, not committed;
    decision:N after the point that records the run's N-th decision (a sequential schedule).
`--then kill` sends SIGKILL to itself there (what `kill -9` or a power cut does); `--then hold` prints
`holding` and waits until its stdin has a line (or closes), then goes on. Every recorded point prints
`point ID` as it is recorded, so a test can follow the run.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys

from rig.config.loading import load_campaign
from rig.run.campaign import run_campaign
from rig.session import rows, writer


def stop_here(then: str) -> None:
    if then == "kill":
        os.kill(os.getpid(), signal.SIGKILL)
    print("holding", flush=True)
    sys.stdin.readline()


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("session")
    parser.add_argument("plan")
    parser.add_argument("station")
    parser.add_argument("--at", required=True)
    parser.add_argument("--then", choices=("kill", "hold"), required=True)
    args = parser.parse_args(argv)
    where, n = args.at.split(":")
    n = int(n)
    recorded = {"points": 0}

    if where in ("collect", "commit"):  # the N-th recording, stopped before or inside its transaction
        record = writer.Session.record_point

        def record_point(self, *a, **k):
            recorded["points"] += 1
            if recorded["points"] == n and where == "collect":
                stop_here(args.then)
            return record(self, *a, **k)

        writer.Session.record_point = record_point
        if where == "commit":
            insert = rows.insert_temperatures

            def insert_then_stop(conn, temps):
                insert(conn, temps)
                if recorded["points"] == n:
                    stop_here(args.then)

            writer.insert_temperatures = insert_then_stop

    def follow(status, runner):
        def on_point(point_id: str) -> None:
            print(f"point {point_id}", flush=True)
            recorded["checkpoints"] = recorded.get("checkpoints", 0) + 1
            if where == "point" and recorded["checkpoints"] == n:
                stop_here(args.then)
            if where == "decision" and len(runner.session.decisions()) >= n:
                stop_here(args.then)

        runner.on_point.append(on_point)
        return None

    outcome = run_campaign(campaign=load_campaign(args.plan, args.station), session_path=args.session,
                           display_factory=follow)
    print(f"exit {outcome.result.status}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
