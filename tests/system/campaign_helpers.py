"""Shared by the campaign system tests: run `rig` in a subprocess, build small plans, read sessions."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
DEMO_PLAN = REPO / "configs" / "plans" / "demo.yaml"
SIM_STATION = REPO / "configs" / "stations" / "sim.yaml"


def small_plan(tmp_path: Path, *, steps=(10, 40), samples=5, dwell_s=60, name="small") -> Path:
    """A short campaign: 2 temperatures x 6 axis directions."""
    plan = {
        "name": name,
        "temperatures": {"steps": list(steps), "ramp_c_per_min": 5.0,
                         "stability": {"band_c": 0.5, "rate_c_per_min": 0.3, "dwell_s": dwell_s}},
        "fields": {"kind": "directions", "magnitude_nt": 50000,
                   "directions": [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]},
        "samples_per_point": samples,
        "settle_s": 0.2,
        "fit": {"models": ["t24"]},
    }
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return path


def quick_demo(tmp_path: Path, *, steps=(-20, 60), samples: int = 2, name: str = "demo") -> Path:
    """The demo plan at fewer temperatures and samples: for tests whose point is not the campaign's size."""
    plan = yaml.safe_load(DEMO_PLAN.read_text())
    plan.pop("station", None)
    plan["name"] = name
    plan["temperatures"]["steps"] = list(steps)
    plan["samples_per_point"] = samples
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return path


def rig_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "rig", *args]


def run_rig(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(rig_cmd(*args), cwd=REPO, capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL, env=os.environ.copy())


def controlled_run(session, plan, station, at: str, then: str = "kill") -> subprocess.Popen:
    """A campaign in its own process that stops at `at` (tests/system/controlled_run.py): killed with
    SIGKILL there, or holding until its stdin gets a line."""
    return subprocess.Popen([sys.executable, "-m", "tests.system.controlled_run", str(session), str(plan),
                             str(station), "--at", at, "--then", then], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, stdin=subprocess.PIPE, text=True)


def killed_at(session, plan, station, at: str) -> list[str]:
    """Run until `at`, be killed there (SIGKILL); the ids of the points it reported recorded."""
    proc = controlled_run(session, plan, station, at, "kill")
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == -signal.SIGKILL, (proc.returncode, err[-2000:])
    return [line.split()[1] for line in out.splitlines() if line.startswith("point ")]


def first_point_line(proc: subprocess.Popen) -> str:
    """The progress line of the first recorded point (`rig run` names its station first), or "" when the
    run ended before one."""
    for line in iter(proc.stdout.readline, ""):
        if " done (" in line:
            return line
    return ""


def popen_rig(*args: str) -> subprocess.Popen:
    return subprocess.Popen(rig_cmd(*args), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True)


def query(session: Path, sql: str, *params) -> list[tuple]:
    conn = sqlite3.connect(f"file:{session}?mode=ro", uri=True)
    try:
        return conn.execute(sql, params).fetchall()
    finally:
        conn.close()


def session_counts(session: Path) -> dict:
    """Points planned/done, samples per (point, dut), duplicates, exit status."""
    planned = query(session, "SELECT count(*) FROM points")[0][0]
    done = query(session, "SELECT count(*) FROM points WHERE state = 'done'")[0][0]
    per = query(session, "SELECT point_id, dut, count(*) FROM samples GROUP BY point_id, dut")
    orphan = query(session, "SELECT count(*) FROM samples s JOIN points p ON p.id = s.point_id "
                            "WHERE p.state != 'done'")[0][0]
    status, completed = query(session, "SELECT exit_status, completed FROM session")[0]
    return {"planned": planned, "done": done, "per_point_dut": {(p, d): n for p, d, n in per},
            "orphan_samples": orphan, "status": status, "completed": bool(completed)}


def final_snapshots(session: Path) -> dict[str, list[dict]]:
    rows = query(session, "SELECT device, describe_json FROM snapshots WHERE device LIKE '% final' "
                          "ORDER BY id")
    out: dict[str, list[dict]] = {}
    for device, text in rows:
        out.setdefault(device.removesuffix(" final"), []).append(json.loads(text))
    return out


def events(session: Path) -> list[tuple[str, str]]:
    return query(session, "SELECT kind, message FROM events ORDER BY id")
