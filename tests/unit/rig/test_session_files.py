"""Session files one can trust: readers never write beside a session (also in a read-only folder, also on
a WAL that was never checkpointed), damaged or foreign files are refused in one line, version 1 files
still read and migrate, written files follow the umask, a full disk ends in one line."""

from __future__ import annotations

import functools
import os
import shutil
import sqlite3
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from drivers.clock import SimClock
from rig.cli import main
from rig.core.errors import SessionError
from rig.engine.commands import FAILED, CollectPoint, Task
from rig.engine.executor import Engine
from rig.report.sources import from_session
from rig.session.events import Kind, Reason
from rig.session.reader import SessionReader
from rig.session.rows import SampleRow
from rig.session.schema import SCHEMA_VERSION
from rig.session.writer import Session
from tests.helpers.readonly import without_override
from tests.helpers.v1_session import write_v1_session

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "configs" / "plans" / "demo.yaml"

# Writes a session of the demo plan, records 3 points, then dies without closing (as kill -9 would):
# the file keeps a write-ahead log that was never checkpointed into it, and the log's index (-shm).
KILLED_WRITER = textwrap.dedent("""
    import os, sys
    from rig.config.loading import load_campaign
    from rig.schedules.compile import compile_plan
    from rig.session.rows import SampleRow
    from rig.session.writer import Session
    campaign = load_campaign(sys.argv[2])
    points = compile_plan(campaign.plan, campaign.station)
    s = Session.create_for(sys.argv[1], campaign, points)
    for p in points[:3]:
        s.record_point(p.id, [SampleRow("mmc0", float(i), (1.0, 2.0, 3.0), p.field_nt, temp_c=20.0)
                              for i in range(4)])
    if sys.argv[3] == "close":
        s.close()
    os._exit(0)
""")


def write_session(path: Path, how: str) -> None:
    subprocess.run([sys.executable, "-c", KILLED_WRITER, str(path), str(DEMO), how], check=True, cwd=REPO)


def make_states(folder: Path) -> dict[str, Path]:
    """The three shapes a session file is found in: closed; killed (log + index); a copy of a killed
    one without its index (the log alone)."""
    closed, killed = folder / "closed.session", folder / "killed.session"
    write_session(closed, "close")
    write_session(killed, "kill")
    assert Path(f"{killed}-wal").stat().st_size > 0 and Path(f"{killed}-shm").exists()
    copied = folder / "copied.session"
    shutil.copyfile(killed, copied)
    shutil.copyfile(f"{killed}-wal", f"{copied}-wal")
    return {"closed": closed, "killed": killed, "copied": copied}


def listing(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_size for p in folder.iterdir()}


def test_readers_create_nothing_beside_a_session_in_any_state(tmp_path, capsys):
    states = make_states(tmp_path)
    before = listing(tmp_path)
    for name, path in states.items():
        with SessionReader(path) as r:
            assert r.summary()["points_done"] == 3, name  # the log's points are seen
            assert len(r.dataset("mmc0")) == 12
        out = tmp_path.parent / f"{name}.csv"
        assert main(["export", str(path), "-o", str(out)]) == 0
        refit = ["refit", str(path), "--model", "p12", "-o", str(tmp_path.parent / f"{name}.yaml")]
        assert main(refit) in (0, 2)  # 3 points may not determine the fit: reading is what counts
    capsys.readouterr()
    assert main(["sessions", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()[1:]
    assert len(lines) == 3 and all(" 3/" in line for line in lines)
    assert listing(tmp_path) == before  # no -wal, -shm or journal appeared, nothing changed size


READ_ALL = textwrap.dedent("""
    import sys
    from rig.session.reader import SessionReader
    for path in sys.argv[1:]:
        with SessionReader(path) as r:
            print(r.summary()["points_done"], len(r.dataset("mmc0")))
""")


def test_sessions_read_in_a_folder_nobody_may_write_to(tmp_path):
    """Every state reads in a folder chmod'ed read-only, by a process that cannot override it."""
    folder = tmp_path / "sessions"
    folder.mkdir()
    states = make_states(folder)
    before = listing(folder)
    folder.chmod(0o555)
    try:
        probe = subprocess.run(without_override([sys.executable, "-c", f"open({str(folder / 'x')!r}, 'w')"]),
                               capture_output=True, text=True)
        assert probe.returncode != 0 and "Permission denied" in probe.stderr  # the folder is really read-only
        paths = [str(p) for p in states.values()]
        done = subprocess.run(without_override([sys.executable, "-c", READ_ALL, *paths]), capture_output=True,
                              text=True, cwd=REPO)
        assert done.returncode == 0, done.stderr
        assert done.stdout.split("\n")[:3] == ["3 12"] * 3
        sessions = subprocess.run(without_override([sys.executable, "-m", "rig", "sessions", str(folder)]),
                                  capture_output=True, text=True, cwd=REPO)
        assert sessions.returncode == 0 and "SKIPPED" not in sessions.stdout, sessions.stdout
        assert sessions.stdout.count(" 3/104 ") == 3
    finally:
        folder.chmod(0o755)
    assert listing(folder) == before


def test_rig_run_into_a_read_only_folder_is_one_line(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    out.chmod(0o555)
    try:
        argv = [sys.executable, "-m", "rig", "run", str(DEMO), "--out", str(out), "--no-live"]
        run = subprocess.run(without_override(argv), capture_output=True, text=True, cwd=REPO,
                             stdin=subprocess.DEVNULL)
    finally:
        out.chmod(0o755)
    assert run.returncode == 2, run.stderr
    assert run.stderr.count("\n") == 1 and "Traceback" not in run.stderr
    assert run.stderr.startswith("error: ") and str(out) in run.stderr
    assert list(out.iterdir()) == []


def test_random_bytes_and_truncated_sessions_are_refused_in_one_line(tmp_path, capsys):
    good = make_states(tmp_path)["closed"]
    noise = tmp_path / "noise.session"
    noise.write_bytes(os.urandom(8192))
    size = good.stat().st_size
    cut_at_page = tmp_path / "cut.session"
    cut_at_page.write_bytes(good.read_bytes()[: size // 2 // 4096 * 4096])
    cut_mid_page = tmp_path / "cutmid.session"
    cut_mid_page.write_bytes(good.read_bytes()[:5000])
    for bad in (noise, cut_at_page, cut_mid_page):
        with pytest.raises(SessionError, match="not a session file|damaged") as info:
            SessionReader(bad)
        assert str(bad) in str(info.value)
        for argv in (["refit", str(bad), "-o", str(tmp_path / "x.yaml")], ["export", str(bad), "-o", "x.csv"],
                     ["report", str(bad), "-o", str(tmp_path / "r")], ["run", "--resume", str(bad)]):
            assert main(argv) == 2, argv
            err = capsys.readouterr().err
            assert err.startswith("error: ") and err.count("\n") == 1 and str(bad) in err, (argv, err)
    assert main(["sessions", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count("SKIPPED") == 3 and "closed.session" in out and "noise.session" in out


def test_version_1_sessions_read_with_codes_and_migrate_on_resume(tmp_path, capsys):
    path = tmp_path / "old.session"
    write_v1_session(path)
    with SessionReader(path) as r:
        assert r.version == 1
        holds = [(e.point_id, e.code) for e in r.events() if e.kind == Kind.HOLD]
        assert holds == [("T02-F01", Reason.STABILITY_TIMEOUT), ("T02-F02", Reason.CHAMBER_ALARM)]
        assert r.summary()["points_done"] == 4 and r.info()["exit_code"] is None
    inputs = from_session(path)
    assert inputs.steps[2].settle_timeouts == 1
    assert any("1 hold(s) during the run: T02-F02 (chamber alarm)" in w for w in inputs.warnings)
    assert main(["sessions", str(tmp_path)]) == 0
    assert "4/4" in capsys.readouterr().out

    with Session.open(path, clock=SimClock()) as s:  # a resume migrates it
        s.log_event(Kind.HOLD, "new", code=Reason.DEVICE_TIMEOUT, point_id="T01-F01", device="coils")
    with SessionReader(path) as r:
        assert r.version == SCHEMA_VERSION
        codes = [(e.kind, e.code, e.point_id) for e in r.events()]
        assert codes[3] == ("hold", Reason.STABILITY_TIMEOUT, "T02-F01")
        assert codes[5] == ("pause", Reason.OPERATOR_PAUSE, "T02-F02")
        assert codes[-1] == ("hold", Reason.DEVICE_TIMEOUT, "T01-F01")
        assert r.info()["plan_sha256"] is not None


def test_an_edited_recorded_plan_is_refused_on_resume(tmp_path):
    path = make_states(tmp_path)["closed"]
    with sqlite3.connect(path) as conn:
        conn.execute("UPDATE session SET plan_text = plan_text || '# edited'")
    conn.close()
    with pytest.raises(SessionError, match="recorded plan text no longer matches its recorded sha256"):
        Session.open(path)


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o027, 0o640)])
def test_written_files_follow_the_umask(tmp_path, umask, mode):
    import numpy as np

    from calib import synthetic
    from calib.fitting import fit
    from calib.io import calfile

    old = os.umask(umask)
    try:
        ds, _ = synthetic.t24_dataset(np.random.default_rng(1), samples_per_point=1)
        calfile.save(fit(ds, "t24"), tmp_path / "cal.yaml")
        session = tmp_path / "s.session"
        write_session(session, "close")
        assert main(["export", str(session), "-o", str(tmp_path / "out.csv")]) == 0
    finally:
        os.umask(old)
    for name in ("cal.yaml", "s.session", "out.csv"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == mode, name


class FullDisk:
    """A connection whose writes of `table` fail as SQLite fails on a full disk."""

    def __init__(self, conn: sqlite3.Connection, table: str):
        self._conn, self._table = conn, table

    def _check(self, sql: str) -> None:
        if f"INSERT INTO {self._table}" in sql:
            raise sqlite3.OperationalError("database or disk is full")

    def execute(self, sql, *args):
        self._check(sql)
        return self._conn.execute(sql, *args)

    def executemany(self, sql, *args):
        self._check(sql)
        return self._conn.executemany(sql, *args)

    def __getattr__(self, name):
        return getattr(self._conn, name)


def test_a_full_disk_fails_the_run_in_one_line_and_records_its_exit(tmp_path, capsys):
    points = [type("P", (), dict(id=f"T01-F0{i}", index=i, temp_index=1, setpoint_c=20.0, field_index=i,
                                 target={}))() for i in range(1, 4)]
    s = Session.create(tmp_path / "s.session", plan_text="p", station_text="s", plan_name="p",
                       station_name="s", points=points, simulated={}, clock=SimClock())
    row = SampleRow("mmc0", 0.0, (1.0, 2.0, 3.0), (0.0, 0.0, 1.0), temp_c=20.0)
    s.record_point("T01-F01", [row])
    s._conn = FullDisk(s._conn, "samples")
    full = r"s\.session: cannot write to the session \(database or disk is full\)"
    with pytest.raises(SessionError, match=full):
        s.record_point("T01-F02", [row])
    assert s.done_point_ids() == {"T01-F01"}  # nothing half-written

    def collect(cmd: CollectPoint) -> None:
        s.record_point(cmd.point, [row])

    def take(pid: str, retake: bool):
        yield CollectPoint(pid)

    steps = [Task(p.id, functools.partial(take, p.id)) for p in points[1:]]
    result = Engine({CollectPoint: collect}, devices=[], clock=SimClock(), session=s).run(steps, {"T01-F01"})
    s.close()
    assert result.status == FAILED and result.code == Reason.STORE_FAILED
    assert "database or disk is full" in result.reason and "\n" not in result.reason
    with SessionReader(tmp_path / "s.session") as r:
        info = r.info()
        faults = [e for e in r.events() if e.kind == Kind.FAULT]
    assert (info["exit_status"], info["exit_code"]) == ("failed", "store_failed")
    assert faults[0].point_id == "T01-F02" and faults[0].code == Reason.STORE_FAILED


def test_sessions_shows_why_a_run_stopped_from_its_code(tmp_path, capsys):
    from tests.helpers.synthetic_session import SynthOptions, build_session

    build_session(tmp_path / "aborted.session",
                  SynthOptions(temps_c=(0.0, 20.0), directions=6, samples=1, abort_at_step=2))
    build_session(tmp_path / "done.session", SynthOptions(temps_c=(0.0,), directions=6, samples=1))
    assert main(["sessions", str(tmp_path)]) == 0
    lines = {line.split()[0]: line for line in capsys.readouterr().out.splitlines()[1:]}
    assert "aborted (retakes_exhausted)" in lines["aborted.session"]
    assert " completed " in lines["done.session"] and "completed (" not in lines["done.session"]
