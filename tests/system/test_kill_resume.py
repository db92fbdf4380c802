"""kill -9 at a random moment, then `rig run --resume`: the session ends complete with exactly the
planned points and samples, none recorded twice, and the dead run's lock is reported and taken over."""

from __future__ import annotations

import random
import signal
import time

import pytest

from rig.reference.loading import load_campaign
from rig.schedules.compile import compile_plan
from tests.system.campaign_helpers import (
    SIM_STATION,
    events,
    final_snapshots,
    popen_rig,
    run_rig,
    session_counts,
    small_plan,
)

pytestmark = pytest.mark.system


@pytest.mark.parametrize("seed", [1, 2])
def test_kill_9_then_resume_completes_without_duplicates(tmp_path, seed):
    station = SIM_STATION
    plan = small_plan(tmp_path, samples=8)
    session = tmp_path / "run.session"
    proc = popen_rig("run", str(plan), "--station", str(station), "--session", str(session), "--no-live")
    proc.stdout.readline()  # first point recorded: the session exists and the run is busy
    time.sleep(random.Random(seed).uniform(0.0, 1.5))
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    before = session_counts(session)
    assert before["status"] is None  # nothing ran after the kill
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
    station = SIM_STATION
    session = tmp_path / "run.session"
    proc = popen_rig("run", str(small_plan(tmp_path, samples=20)), "--station", str(station),
                     "--session", str(session), "--no-live")
    try:
        proc.stdout.readline()
        second = run_rig("run", "--resume", str(session), "--no-live")
        assert second.returncode == 2
        assert "in use by running process" in second.stderr and str(proc.pid) in second.stderr
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)
    assert session_counts(session)["status"] == "aborted"
