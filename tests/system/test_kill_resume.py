"""kill -9 at a moment the test chooses (between points, inside a point's collection, inside its write
transaction), then `rig run --resume`: the session ends complete with exactly the planned points and
samples, none recorded twice, and the dead run's lock is reported and taken over. A live run refuses a
second run on its session."""

from __future__ import annotations

import signal

import pytest

from rig.config.loading import load_campaign
from rig.schedules.compile import compile_plan
from tests.system.campaign_helpers import (
    SIM_STATION,
    controlled_run,
    events,
    final_snapshots,
    killed_at,
    run_rig,
    session_counts,
    small_plan,
)

pytestmark = pytest.mark.system


@pytest.mark.parametrize("at", ["point:3", "collect:5", "commit:2"])
def test_kill_9_then_resume_completes_without_duplicates(tmp_path, at):
    station = SIM_STATION
    plan = small_plan(tmp_path, samples=8)
    session = tmp_path / "run.session"
    reported = killed_at(session, plan, station, at)
    before = session_counts(session)
    assert before["status"] is None  # nothing ran after the kill
    n = int(at.split(":")[1])
    assert before["done"] == (n if at.startswith("point") else n - 1) == len(reported)  # whole points only
    assert before["orphan_samples"] == 0
    assert (tmp_path / "run.session.lock").exists()

    resumed = run_rig("run", "--resume", str(session), "--no-live")
    assert resumed.returncode == 0, resumed.stderr
    assert "took over the lock of dead run" in resumed.stdout

    campaign = load_campaign(plan, station)
    points = compile_plan(campaign.plan, campaign.station)
    duts = [d.name for d in campaign.station.duts]
    after = session_counts(session)
    assert after["completed"] and after["status"] == "completed"
    assert after["planned"] == after["done"] == len(points)
    assert after["per_point_dut"] == {(p.id, d): 8 for p in points for d in duts}
    assert after["orphan_samples"] == 0
    assert any(kind == "stale_lock" for kind, _ in events(session))
    assert not (tmp_path / "run.session.lock").exists()
    assert final_snapshots(session)["coils"][-1]["enabled"] == [False, False, False]
    assert (tmp_path / f"run.{duts[0]}.t24.yaml").is_file()


def test_a_live_run_refuses_a_second_run_on_its_session(tmp_path):
    session = tmp_path / "run.session"
    proc = controlled_run(session, small_plan(tmp_path, samples=2), SIM_STATION, "point:1", "hold")
    try:
        lines = iter(proc.stdout.readline, "")
        assert next(line for line in lines if not line.startswith("point ")).strip() == "holding"
        second = run_rig("run", "--resume", str(session), "--no-live")
        assert second.returncode == 2
        assert "in use by running process" in second.stderr and str(proc.pid) in second.stderr
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.stdin.write("go on\n")
        proc.stdin.flush()
        proc.communicate(timeout=120)
    assert session_counts(session)["status"] == "aborted"
