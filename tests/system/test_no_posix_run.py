"""`rig run` needs no POSIX-only module: the demo plan runs on a simulated station in a process where
fcntl, termios, pty and tty cannot be imported (as on Windows), its session locked and unlocked; a live
holder refuses the run naming its pid, a dead one is reported and taken over; a simulated serial device
(a pty) is refused in one line before anything is written."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.system.campaign_helpers import DEMO_PLAN, REPO, rig_cmd, session_counts

pytestmark = pytest.mark.system

BLOCKED = ("fcntl", "termios", "pty", "tty")
SIM_4 = REPO / "configs" / "stations" / "sim-4.yaml"  # no serial device
BLOCKER = textwrap.dedent(f"""
    import sys

    BLOCKED = {BLOCKED!r}

    class PosixBlocker:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"No module named {{name!r}} (this test's stand-in for Windows)")
            return None

    sys.meta_path.insert(0, PosixBlocker())
    for loaded in [m for m in sys.modules if m.split(".")[0] in BLOCKED]:
        del sys.modules[loaded]
""")
HOLDER = textwrap.dedent("""
    import sys, time
    from rig.session.lock import SessionLock
    lock = SessionLock(sys.argv[1])
    lock.acquire()
    print("held", flush=True)
    time.sleep(600)
""")


@pytest.fixture
def no_posix_env(tmp_path) -> dict[str, str]:
    """The environment of a process whose imports of fcntl, termios, pty and tty fail."""
    folder = tmp_path / "blocker"
    folder.mkdir()
    (folder / "sitecustomize.py").write_text(BLOCKER)
    env = os.environ.copy()
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(folder), env.get("PYTHONPATH")) if p)
    return env


def run(args: list[str], env: dict, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)


def test_the_blocker_blocks(no_posix_env):
    for module in BLOCKED:
        probe = run([sys.executable, "-c", f"import {module}"], no_posix_env, timeout=60)
        assert probe.returncode != 0 and "stand-in for Windows" in probe.stderr, module


def test_rig_run_without_fcntl_termios_pty_locks_runs_and_unlocks(tmp_path, no_posix_env):
    session = tmp_path / "run.session"
    lock_file = Path(f"{session}.lock")
    args = rig_cmd("run", str(DEMO_PLAN), "--station", str(SIM_4), "--session", str(session), "--no-live")
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(session)], cwd=REPO, env=no_posix_env,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        refused = run(args, no_posix_env, timeout=120)
        assert refused.returncode != 0
        assert f"in use by running process {holder.pid}" in refused.stderr
        assert "Traceback" not in refused.stderr and not session.exists()
    finally:
        holder.send_signal(signal.SIGKILL)  # dies holding it: its marker names a dead process
        holder.wait()
        holder.stdout.close()
    assert lock_file.exists()

    done = run(args, no_posix_env)
    assert done.returncode == 0, done.stderr[-3000:]
    counts = session_counts(session)
    assert counts["completed"] and counts["done"] == counts["planned"] > 0
    from rig.session.reader import SessionReader

    with SessionReader(session) as reader:
        stale = [e for e in reader.events() if e.kind == "stale_lock"]
    assert [e.data.get("pid") for e in stale] == [holder.pid]
    assert not lock_file.exists()  # released at the end


def test_a_simulated_serial_device_is_refused_in_one_line_before_any_write(tmp_path, no_posix_env):
    session = tmp_path / "serial.session"
    refused = run(rig_cmd("run", str(DEMO_PLAN), "--session", str(session), "--no-live"), no_posix_env,
                  timeout=120)
    assert refused.returncode != 0
    lines = refused.stderr.strip().splitlines()
    assert len(lines) == 1 and "serial0" in lines[0] and "pseudo-terminal" in lines[0], refused.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker"]  # no session, no lock left
