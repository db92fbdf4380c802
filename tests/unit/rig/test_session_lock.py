"""The run lock cannot be held by two processes at once, not even when they race for a dead run's lock;
a session is created whole or not at all, even under kill -9."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rig.core.errors import SessionError
from rig.session.lock import SessionLock
from rig.session.reader import SessionReader
from rig.session.writer import Session

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "configs" / "plans" / "demo.yaml"
RACERS = 4
TRIALS = 50


def _race_once(lock_path: Path) -> list[bytes]:
    """RACERS forked processes try the lock at the same moment and hold what they got until told to
    stop; returns each one's answer: b"G" got it, b"B" busy."""
    go_r, go_w = os.pipe()
    answer_r, answer_w = os.pipe()
    stop_r, stop_w = os.pipe()
    children = []
    for _ in range(RACERS):
        pid = os.fork()
        if pid == 0:  # the child: wait for the start, try, report, hold until the parent says stop
            code = 0
            try:
                os.read(go_r, 1)
                lock = SessionLock(lock_path)
                try:
                    lock.acquire()
                    os.write(answer_w, b"G")
                except SessionError:
                    os.write(answer_w, b"B")
                os.read(stop_r, 1)
                lock.release()
            except BaseException:
                code = 1
            os._exit(code)
        children.append(pid)
    os.write(go_w, b"x" * RACERS)
    answers = [os.read(answer_r, 1) for _ in range(RACERS)]
    os.write(stop_w, b"x" * RACERS)
    for pid in children:
        assert os.waitpid(pid, 0)[1] == 0
    for fd in (go_r, go_w, answer_r, answer_w, stop_r, stop_w):
        os.close(fd)
    return answers


def test_racing_processes_never_share_the_lock_even_over_a_dead_holders_file(tmp_path):
    lock_path = tmp_path / "run.session"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    shared = 0
    for trial in range(TRIALS):
        if trial % 2:  # every other trial starts from a dead run's lock file
            Path(f"{lock_path}.lock").write_text(f"{dead}\n")
        answers = _race_once(lock_path)
        shared += answers.count(b"G") != 1
    assert shared == 0
    assert not Path(f"{lock_path}.lock").exists()  # the last holder released it


def test_a_dead_holder_is_reported_and_a_live_one_named(tmp_path):
    session = tmp_path / "run.session"
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import sys, time
        from rig.session.lock import SessionLock
        lock = SessionLock({str(session)!r}); lock.acquire()
        print("held", flush=True); time.sleep(60)
    """)], stdout=subprocess.PIPE, text=True, cwd=REPO)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(SessionError, match=f"in use by running process {holder.pid}"):
            SessionLock(session).acquire()
    finally:
        holder.send_signal(signal.SIGKILL)  # dies holding it: the kernel releases the lock
        holder.wait()
        holder.stdout.close()
    with SessionLock(session) as lock:
        assert lock.stale_pid == holder.pid
    with SessionLock(session) as lock:  # released cleanly last time: nothing stale
        assert lock.stale_pid is None


CREATOR = textwrap.dedent("""
    import sys, time
    from rig.config.loading import load_campaign
    from rig.schedules.compile import compile_plan
    from rig.session.writer import Session
    campaign = load_campaign(sys.argv[2])
    points = compile_plan(campaign.plan, campaign.station)

    def slowly():
        for i, p in enumerate(points):
            if i == len(points) // 2:
                print("creating", flush=True)
                time.sleep(60)
            yield p

    Session.create_for(sys.argv[1], campaign, slowly())
""")


def test_kill_9_during_creation_leaves_no_session_and_the_name_can_be_used_again(tmp_path):
    path = tmp_path / "run.session"
    proc = subprocess.Popen([sys.executable, "-c", CREATOR, str(path), str(DEMO)], stdout=subprocess.PIPE,
                            text=True, cwd=REPO)
    try:
        assert proc.stdout.readline().strip() == "creating"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
    assert not path.exists()  # no half-made session under the real name
    leftovers = [p.name for p in tmp_path.iterdir()]
    assert leftovers and all(name.startswith(".run.session.") for name in leftovers)

    from rig.config.loading import load_campaign
    from rig.schedules.compile import compile_plan

    campaign = load_campaign(DEMO)
    points = compile_plan(campaign.plan, campaign.station)
    Session.create_for(path, campaign, points).close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.session"]  # the dead build is gone
    with Session.open(path) as s:  # resumable: every point planned
        assert s.planned_point_ids() == [p.id for p in points]
    with SessionReader(path) as r:
        assert r.summary()["points_planned"] == len(points)


def test_create_never_replaces_an_existing_session(tmp_path):
    path = tmp_path / "run.session"
    path.write_bytes(b"someone else's file")
    with pytest.raises(SessionError, match="already exists"):
        Session.create(path, plan_text="p", station_text="s", plan_name="p", station_name="s", points=[],
                       simulated={})
    assert path.read_bytes() == b"someone else's file"
    assert [p.name for p in tmp_path.iterdir()] == ["run.session"]
