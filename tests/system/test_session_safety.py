"""A whole `rig run` against the storage's failure modes: a resume of an edited plan is refused naming
the keys, a completed session is not run or fitted again, a full disk ends in one line with the exit
status recorded."""

from __future__ import annotations

import resource
import signal
import subprocess

import pytest

from rig.session.events import Kind
from rig.session.reader import SessionReader
from tests.system.campaign_helpers import REPO, SIM_STATION, first_point_line, rig_cmd, run_rig, small_plan

pytestmark = pytest.mark.system


def fits_of(session) -> list[tuple[str, str]]:
    with SessionReader(session) as r:
        return [(f["dut"], f["model"]) for f in r.fits()]


def test_a_completed_session_is_not_resumed_and_an_edited_plan_is_refused(tmp_path):
    plan = small_plan(tmp_path, samples=3)
    session = tmp_path / "run.session"
    first = run_rig("run", str(plan), "--station", str(SIM_STATION), "--session", str(session), "--no-live")
    assert first.returncode == 0, first.stderr
    fits = fits_of(session)
    cal = tmp_path / "run.mmc0.t24.yaml"
    written = cal.stat().st_mtime_ns

    again = run_rig("run", "--resume", str(session), "--no-live")
    assert again.returncode == 0, again.stderr
    assert "already complete; nothing to do" in again.stdout
    assert fits_of(session) == fits  # no second fit recorded
    assert cal.stat().st_mtime_ns == written

    # an interrupted session whose plan file was edited since
    stopped = tmp_path / "stopped.session"
    argv = rig_cmd("run", str(plan), "--station", str(SIM_STATION), "--session", str(stopped), "--no-live")
    proc = subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True)
    first_point_line(proc)
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=60)
    plan.write_text(plan.read_text().replace("samples_per_point: 3", "samples_per_point: 9")
                    .replace("dwell_s: 60", "dwell_s: 90"))
    refused = run_rig("run", "--resume", str(stopped), "--no-live")
    assert refused.returncode == 2
    assert refused.stderr.count("\n") == 1 and "cannot resume" in refused.stderr
    assert "keys changed: temperatures.stability.dwell_s, samples_per_point" in refused.stderr
    with SessionReader(stopped) as r:
        assert [e.kind for e in r.events()].count(Kind.START) == 1  # nothing ran


def _small_file_limit() -> None:
    """The child's files may not grow past 200 kB: its writes fail as on a full disk."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))


def test_a_full_disk_ends_the_run_in_one_line_with_its_exit_recorded(tmp_path):
    plan = small_plan(tmp_path, samples=40)
    session = tmp_path / "run.session"
    run = subprocess.run(rig_cmd("run", str(plan), "--station", str(SIM_STATION), "--session", str(session),
                                 "--no-live"), cwd=REPO, capture_output=True, text=True, timeout=120,
                         stdin=subprocess.DEVNULL, preexec_fn=_small_file_limit)
    assert run.returncode == 1, run.stderr
    assert "Traceback" not in run.stderr + run.stdout
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("run not completed: failed: ") and "cannot write to the session" in last
    with SessionReader(session) as r:
        info, summary = r.info(), r.summary()
    assert (info["exit_status"], info["exit_code"]) == ("failed", "store_failed")
    assert 0 < summary["points_done"] < summary["points_planned"]
