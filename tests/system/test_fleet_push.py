"""`rig push` and `rig fleet list` against a real PostgreSQL server (started by the test suite)."""

from __future__ import annotations

import datetime as dt
import os
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import psycopg
import pytest

from rig.cli import main
from rig.fleet import push as push_module
from rig.fleet.push import push_snapshot
from rig.fleet.schema import connect
from rig.fleet.source import session_snapshot
from tests import pg_server
from tests.fleet_sessions import Spec, record_points, write_session

REPO = Path(__file__).resolve().parents[2]


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def dump(url: str) -> dict[str, list[tuple]]:
    """Every row of every fleet table, sorted; the push time left out (it says when, not what)."""
    out = {}
    with psycopg.connect(url) as conn:
        tables = [r[0] for r in conn.execute(
            "SELECT table_name FROM information_schema.tables WHERE table_schema = 'magrig'")]
        for table in sorted(tables):
            cur = conn.execute(f'SELECT * FROM magrig."{table}"')
            names = [d.name for d in cur.description]
            keep = [i for i, n in enumerate(names) if n != "pushed_at"]
            out[table] = sorted((tuple(row[i] for i in keep) for row in cur), key=repr)
    return out


def count(url: str, table: str) -> int:
    with psycopg.connect(url) as conn:
        return conn.execute(f'SELECT count(*) FROM magrig."{table}"').fetchone()[0]


def test_push_twice_changes_nothing(tmp_path, fleet_db, capsys):
    paths = [write_session(tmp_path / f"s{i}.session", Spec(seed=i, duts=("dut1", "dut2"))) for i in (1, 2)]
    code, out, err = run(capsys, "push", *paths, "--db", fleet_db)
    assert code == 0, err
    assert [line.split()[0] for line in out.splitlines()] == ["added", "added", "pushed"]
    assert out.splitlines()[-1] == "pushed 2 added"
    first = dump(fleet_db)
    with psycopg.connect(fleet_db) as conn:
        pushed_at = conn.execute("SELECT uid, pushed_at FROM magrig.fleet_sessions ORDER BY uid").fetchall()
    assert len(first["samples"]) == 2 * len(Spec().points()) * 2 * Spec().samples
    assert len(first["points"]) == 2 * len(Spec().points())

    code, out, _ = run(capsys, "push", *paths, "--db", fleet_db)
    assert code == 0 and out.splitlines()[-1] == "pushed 0 added, 2 unchanged"
    assert dump(fleet_db) == first
    with psycopg.connect(fleet_db) as conn:
        again = conn.execute("SELECT uid, pushed_at FROM magrig.fleet_sessions ORDER BY uid").fetchall()
    assert again == pushed_at


def test_copies_hold_the_session_file_exactly(tmp_path, fleet_db):
    path = write_session(tmp_path / "a.session", Spec(seed=9))
    snap = session_snapshot(path)
    with connect(fleet_db) as conn:
        push_snapshot(conn, snap)
        for name, table in snap.tables.items():
            cols = ", ".join(f'"{c}"' for c in table.column_names)
            rows = conn.execute(f'SELECT {cols} FROM magrig."{name}" WHERE session_uid = %s', (snap.uid,))
            assert sorted(rows.fetchall(), key=repr) == sorted(table.rows, key=repr), name


def test_a_failed_push_leaves_nothing_and_the_next_push_completes(tmp_path, fleet_db, monkeypatch):
    """An error inside the transaction (here: right after the samples went in) rolls the session back."""
    path = write_session(tmp_path / "a.session", Spec(seed=2, duts=("dut1", "dut2")))
    real_copy = push_module.copy_rows

    def copy_then_fail(conn, uid, table):
        real_copy(conn, uid, table)
        if table.name == "samples":
            raise psycopg.OperationalError("connection lost (simulated)")

    monkeypatch.setattr(push_module, "copy_rows", copy_then_fail)
    with connect(fleet_db) as conn:
        with pytest.raises(Exception, match="connection lost"):
            push_snapshot(conn, session_snapshot(path))
    assert count(fleet_db, "fleet_sessions") == 0
    with psycopg.connect(fleet_db) as conn:
        copies = [r[0] for r in conn.execute(
            "SELECT table_name FROM information_schema.tables WHERE table_schema = 'magrig'")]
    assert "samples" not in copies  # even the table made for it went with the rollback
    monkeypatch.undo()

    assert main(["push", str(path), "--db", fleet_db]) == 0
    clean = pg_server.create_database_like(fleet_db, "fleet_clean_a")
    assert main(["push", str(path), "--db", clean]) == 0
    assert dump(fleet_db) == dump(clean)


KILLER = textwrap.dedent("""
    import os, signal, sys
    from rig.fleet import push
    real_copy, copied = push.copy_rows, []
    def copy_then_die(conn, uid, table):
        real_copy(conn, uid, table)
        copied.append(table.name)
        if copied.count("samples") == 2:  # the second session's samples are in, its transaction still open
            os.kill(os.getpid(), signal.SIGKILL)
    push.copy_rows = copy_then_die
    from rig.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def test_a_killed_push_resumes(tmp_path, fleet_db):
    """kill -9 of `rig push` in the middle of a session's transaction, then the same push again."""
    paths = [write_session(tmp_path / f"s{i}.session", Spec(seed=i)) for i in (1, 2, 3)]
    done = subprocess.run([sys.executable, "-c", KILLER, "push", *map(str, paths), "--db", fleet_db],
                          cwd=REPO, capture_output=True, text=True, timeout=120, env=os.environ.copy())
    assert done.returncode == -9, done.stderr
    with psycopg.connect(fleet_db) as conn:
        uids = {r[0] for r in conn.execute("SELECT uid FROM magrig.fleet_sessions")}
        n_samples = conn.execute("SELECT count(*) FROM magrig.samples").fetchone()[0]
    assert uids == {session_snapshot(paths[0]).uid}  # s1 whole, nothing of s2
    assert n_samples == len(session_snapshot(paths[0]).tables["samples"].rows)

    assert main(["push", *map(str, paths), "--db", fleet_db]) == 0
    clean = pg_server.create_database_like(fleet_db, "fleet_clean_b")
    assert main(["push", *map(str, paths), "--db", clean]) == 0
    assert dump(fleet_db) == dump(clean)


def test_a_grown_session_is_replaced_whole(tmp_path, fleet_db, capsys):
    spec = Spec(seed=4, duts=("dut1", "dut2"))
    path = write_session(tmp_path / "running.session", spec, upto=10, finish=False)
    code, out, _ = run(capsys, "push", path, "--db", fleet_db)
    assert code == 0 and "added" in out
    assert count(fleet_db, "samples") == 10 * 2 * spec.samples
    record_points(path, spec)  # the campaign went on and finished
    code, out, _ = run(capsys, "push", path, "--db", fleet_db)
    assert code == 0 and "replaced" in out
    clean = pg_server.create_database_like(fleet_db, "fleet_clean_c")
    assert main(["push", str(path), "--db", clean]) == 0
    assert dump(fleet_db) == dump(clean)
    with psycopg.connect(fleet_db) as conn:
        done, status = conn.execute("SELECT points_done, exit_status FROM magrig.fleet_sessions").fetchone()
    assert (done, status) == (len(spec.points()), "completed")


def test_new_columns_and_tables_arrive_without_code_changes(tmp_path, fleet_db):
    old = write_session(tmp_path / "old.session", Spec(seed=1))
    assert main(["push", str(old), "--db", fleet_db]) == 0
    new = write_session(tmp_path / "new.session", Spec(seed=2))
    conn = sqlite3.connect(new)
    with conn:
        conn.execute("ALTER TABLE events ADD COLUMN reason_code TEXT")
        conn.execute("UPDATE events SET reason_code = 'run.start'")
        conn.execute("CREATE TABLE acceptance_results (dut TEXT PRIMARY KEY, verdict TEXT, margin_nt REAL)")
        conn.execute("INSERT INTO acceptance_results VALUES ('dut1', 'PASS', 12.5)")
    conn.close()
    assert main(["push", str(new), "--db", fleet_db]) == 0
    uid = session_snapshot(new).uid
    with psycopg.connect(fleet_db) as pg:
        codes = set(pg.execute("SELECT session_uid, reason_code FROM magrig.events").fetchall())
        accepted = pg.execute("SELECT session_uid, dut, verdict, margin_nt FROM magrig.acceptance_results")
        assert accepted.fetchall() == [(uid, "dut1", "PASS", 12.5)]
        row = pg.execute("SELECT verdict FROM magrig.fleet_sessions WHERE uid = %s", (uid,)).fetchone()
    assert codes == {(session_snapshot(old).uid, None), (uid, "run.start")}
    assert row == ("PASS",)


def test_the_runs_acceptance_and_temperature_tables_are_pushed_whole(tmp_path, fleet_db):
    """Tables the store makes when first needed, several rows per session: acceptance (no key of its
    own) and the cockpit's temperatures."""
    from rig.session.rows import TemperatureRow
    from rig.session.writer import Session

    path = write_session(tmp_path / "s.session", Spec(seed=3, duts=("dut1", "dut2")))
    with Session.open(path) as s:
        s.record_acceptance([{"dut": d, "model": "t24", "passed": int(d == "dut1"), "verdict": v,
                              "failed": "" if v == "PASS" else "fit_rms 30 nT > 20", "heldout_rms_nt": 25.0,
                              "fit_rms_nt": 20.0 + i * 10, "lag_s": None, "notes": ""}
                             for i, (d, v) in enumerate((("dut1", "PASS"), ("dut2", "FAIL")))])
        s.record_temperatures([TemperatureRow(100.0 * i, 25.0, None, 24.0 + i,
                                              {"dut1": 23.0 + i, "dut2": None}) for i in range(3)])
    assert main(["push", str(path), "--db", fleet_db]) == 0
    uid = session_snapshot(path).uid
    with psycopg.connect(fleet_db) as pg:
        verdicts = pg.execute("SELECT dut, verdict FROM magrig.acceptance WHERE session_uid = %s "
                              "ORDER BY dut", (uid,)).fetchall()
        air = pg.execute("SELECT air_c FROM magrig.temperatures WHERE session_uid = %s ORDER BY id",
                         (uid,)).fetchall()
        verdict = pg.execute("SELECT verdict FROM magrig.fleet_sessions WHERE uid = %s", (uid,)).fetchone()
    assert verdicts == [("dut1", "PASS"), ("dut2", "FAIL")] and verdict == ("FAIL",)
    assert air == [(24.0,), (25.0,), (26.0,)]


def test_push_goes_on_past_a_bad_file_and_says_so(tmp_path, fleet_db, capsys):
    good = write_session(tmp_path / "good.session", Spec(seed=1))
    bad = tmp_path / "bad.session"
    bad.write_bytes(b"garbage")
    code, out, err = run(capsys, "push", bad, good, "--db", fleet_db)
    assert code == 2
    assert f"failed     {bad}: not a session file" in out and "added" in out
    assert "1 of 2 session(s) not pushed" in err and "Traceback" not in err
    assert count(fleet_db, "fleet_sessions") == 1


@pytest.fixture(scope="module")
def fleet(pg, tmp_path_factory) -> tuple[str, dict[str, Path]]:
    """Four sessions on two stations and three days, with serials and acceptance verdicts, pushed."""
    url = pg_server.create_database(pg, "fleet_listing")
    tmp_path = tmp_path_factory.mktemp("fleet")
    specs = {
        "a": Spec(seed=1, station="rig-a", duts=("dut1",), serials=("SN-100",), day=dt.date(2026, 3, 2)),
        "b": Spec(seed=2, station="rig-a", duts=("dut1", "dut2"), serials=("SN-200", "SN-201"),
                  day=dt.date(2026, 3, 5)),
        "c": Spec(seed=3, station="rig-b", duts=("dut1",), serials=("SN-300",), day=dt.date(2026, 3, 5)),
        "d": Spec(seed=4, station="rig-b", duts=("dutX",), day=dt.date(2026, 3, 9)),
    }
    paths = {k: write_session(tmp_path / f"{k}.session", s) for k, s in specs.items()}
    for key, verdicts in (("a", ["PASS"]), ("b", ["PASS", "FAIL"]), ("c", ["PASS", "PASS"])):
        conn = sqlite3.connect(paths[key])
        with conn:
            conn.execute("CREATE TABLE acceptance (id INTEGER PRIMARY KEY, verdict TEXT)")
            conn.executemany("INSERT INTO acceptance (verdict) VALUES (?)", [(v,) for v in verdicts])
        conn.close()
    assert main(["push", str(tmp_path), "--db", url]) == 0
    return url, paths


@pytest.mark.parametrize(("args", "expected"), [
    ((), "abcd"),
    (("--station", "rig-b"), "cd"),
    (("--dut", "dut2"), "b"),
    (("--dut", "SN-300"), "c"),
    (("--since", "2026-03-05"), "bcd"),
    (("--until", "2026-03-05"), "a"),
    (("--since", "2026-03-03", "--until", "2026-03-09"), "bc"),
    (("--verdict", "PASS"), "ac"),
    (("--verdict", "fail"), "b"),
    (("--station", "rig-a", "--verdict", "PASS"), "a"),
    (("--dut", "nobody"), ""),
])
def test_fleet_list_filters(fleet, capsys, args, expected):
    url, paths = fleet
    code, out, err = run(capsys, "fleet", "list", "--db", url, *args)
    assert code == 0, err
    listed = "".join(sorted(k for k, p in paths.items() if str(p.resolve()) in out))
    assert listed == expected
    if expected:
        assert f"{len(expected)} session(s)" in out
    else:
        assert "no sessions match" in out


@pytest.mark.parametrize(("args", "expected"), [
    (("--station", "rig-b"), "cd"),
    (("--verdict", "fail"), "b"),
])
def test_rig_sessions_lists_the_fleet_database_with_db(fleet, capsys, args, expected):
    url, paths = fleet
    code, out, err = run(capsys, "sessions", "--db", url, *args)
    assert code == 0, err
    assert "".join(sorted(k for k, p in paths.items() if str(p.resolve()) in out)) == expected


def test_rig_sessions_filters_without_db_are_refused(tmp_path, capsys):
    code, out, err = run(capsys, "sessions", str(tmp_path), "--station", "rig-a")
    assert code == 2 and "--station" in err and "--db" in err
