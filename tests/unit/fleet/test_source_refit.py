"""The fleet's session reader (every table, introspected) and the per-session re-fit, without a database."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest

import calib
from rig import __version__
from rig.cli import main
from rig.core.errors import SessionError
from rig.fleet.push import dut_serials, verdict
from rig.fleet.refit import dut_datasets, refit_file
from rig.fleet.source import session_snapshot
from rig.session.reader import read_dataset
from rig.session.rows import SampleRow
from rig.session.writer import Session
from tests.fleet_sessions import Spec, record_points, write_session


def add_new_schema_parts(path: Path, verdicts: list[str]) -> None:
    """What a later session schema may add: a column on events, an acceptance results table."""
    conn = sqlite3.connect(path)
    with conn:
        conn.execute("ALTER TABLE events ADD COLUMN reason_code TEXT")
        conn.execute("UPDATE events SET reason_code = 'run.start'")
        conn.execute("CREATE TABLE acceptance (id INTEGER PRIMARY KEY, dut TEXT, check_name TEXT, "
                     "verdict TEXT)")
        conn.executemany("INSERT INTO acceptance (dut, check_name, verdict) VALUES ('dut1', ?, ?)",
                         [(f"check{i}", v) for i, v in enumerate(verdicts)])
    conn.close()


def test_snapshot_carries_every_table_and_new_columns(tmp_path):
    path = write_session(tmp_path / "a.session", Spec(duts=("dut1", "dut2"), serials=("SN-7", None)))
    add_new_schema_parts(path, ["PASS", "FAIL"])
    snap = session_snapshot(path)
    assert set(snap.tables) == {"session", "points", "samples", "events", "fits", "snapshots", "acceptance"}
    assert "reason_code" in snap.tables["events"].column_names
    assert [e["reason_code"] for e in snap.tables["events"].dicts()] == ["run.start"]
    assert len(snap.tables["samples"].rows) == len(Spec().points()) * 2 * Spec().samples
    assert dut_serials(snap) == {"dut1": "SN-7"}
    assert verdict(snap) == "FAIL"


def test_verdict_pass_only_when_every_row_passes(tmp_path):
    path = write_session(tmp_path / "a.session")
    assert verdict(session_snapshot(path)) is None
    add_new_schema_parts(path, ["pass", "PASS"])
    assert verdict(session_snapshot(path)) == "PASS"


def test_uid_is_stable_as_the_session_grows_and_the_hash_follows_the_content(tmp_path):
    spec = Spec(seed=3)
    path = write_session(tmp_path / "a.session", spec, upto=10, finish=False)
    first = session_snapshot(path)
    again = session_snapshot(path)
    assert again.content_hash() == first.content_hash()
    record_points(path, spec)
    grown = session_snapshot(path)
    assert grown.uid == first.uid
    assert grown.content_hash() != first.content_hash()
    other = session_snapshot(write_session(tmp_path / "b.session", Spec(seed=4)))
    assert other.uid != first.uid


def test_a_recorded_uid_is_the_identity(tmp_path):
    path = write_session(tmp_path / "a.session")
    conn = sqlite3.connect(path)
    with conn:
        conn.execute("ALTER TABLE session ADD COLUMN uid TEXT")
        conn.execute("UPDATE session SET uid = 'rig7-000123'")
    conn.close()
    assert session_snapshot(path).uid == "rig7-000123"


def test_not_a_session_is_refused_with_its_name(tmp_path):
    bad = tmp_path / "bad.session"
    bad.write_bytes(b"not a database at all")
    with pytest.raises(SessionError, match="bad.session: not a session file"):
        session_snapshot(bad)
    other = tmp_path / "other.db"
    sqlite3.connect(other).execute("CREATE TABLE t (x)").connection.close()
    with pytest.raises(SessionError, match="other.db: not a magrig session file"):
        session_snapshot(other)


def test_datasets_from_rows_match_read_dataset(tmp_path):
    """Flagged samples, a failed point and a missing DUT temperature handled as rig.session.writer does."""
    spec = Spec(duts=("dut1", "dut2"), directions=6)
    path = write_session(tmp_path / "a.session", spec, upto=14, finish=False)
    points = spec.points()
    with Session.open(path) as s:
        extra = points[14]
        s.record_point(extra.id, [
            SampleRow("dut1", 1.0, (1e4, 2e4, 3e4), (1e4, 2e4, 3e4), temp_c=None, ref_temp_c=24.5),
            SampleRow("dut1", 2.0, (9e9, 0, 0), (1e4, 2e4, 3e4), temp_c=25.0, flags=frozenset({"saturated"})),
            SampleRow("dut2", 3.0, (1e4, 2e4, 3e4), (1e4, 2e4, 3e4), temp_c=25.1),
        ])
        s.mark_point_failed(points[15].id, "coil fault")
    snap = session_snapshot(path)
    built = dut_datasets(snap.tables["points"].dicts(), snap.tables["samples"].dicts(), str(path))
    for dut in ("dut1", "dut2"):
        expected = read_dataset(path, dut)
        got = built[dut]
        for name in ("h_nt", "temp_c", "ref_nt"):
            np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))
        assert list(got.group) == list(expected.group)
        assert got.source["rows_rejected"] == expected.source["rows_rejected"]
    assert built["dut1"].source["rows_rejected"] == 1


def test_refit_file_gives_rig_refit_parameters(tmp_path):
    path = write_session(tmp_path / "a.session", Spec(seed=5))
    [row] = refit_file(str(path), "p12", __version__)
    assert row["status"] == "ok" and row["dut"] == "dut1" and row["station"] == "rig-a"
    cal = calib.fit(read_dataset(path), "p12", software_version=__version__)
    params = json.loads(row["params"])
    for name, value in cal.params.items():
        np.testing.assert_array_equal(np.asarray(params[name]), value)
    assert row["n"] == cal.stats["n"] and row["rms_after_nt"] == cal.stats["rms_after_nt"]


def test_refit_file_turns_a_damaged_file_and_a_bad_dut_into_failed_rows(tmp_path):
    bad = tmp_path / "bad.session"
    bad.write_bytes(b"\x00" * 100)
    [row] = refit_file(str(bad), "t24", __version__)
    assert row["status"] == "failed" and "not a session file" in row["reason"]
    spec = Spec(duts=("dut1", "dut2"))
    path = write_session(tmp_path / "a.session", spec, upto=2, finish=False)  # too few points for T24
    rows = refit_file(str(path), "t24", __version__)
    assert [r["status"] for r in rows] == ["failed", "failed"]
    assert all(r["reason"] for r in rows)


def test_no_database_reachable_is_one_line(capsys):
    code = main(["fleet", "list", "--db", "postgresql://nobody:secret@127.0.0.1:1/none"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("error: postgresql://nobody:***@127.0.0.1:1/none: cannot connect")
    assert "secret" not in err and len(err.strip().splitlines()) == 1
