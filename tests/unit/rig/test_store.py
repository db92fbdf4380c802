"""The session store: WAL, one transaction per point (all or nothing, even under kill -9 and Ctrl-C),
resume, read-back as a calib Dataset, and clear errors for files that are not sessions."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from calib.dataset import Dataset
from drivers.base import FieldSample
from drivers.clock import SimClock
from rig.config.loading import load_campaign
from rig.core.errors import SessionError
from rig.schedules.compile import compile_plan
from rig.session.events import Kind, Reason
from rig.session.reader import SessionReader, read_dataset
from rig.session.rows import SampleRow
from rig.session.schema import SCHEMA_VERSION
from rig.session.writer import Session

DEMO = Path(__file__).resolve().parents[3] / "configs" / "plans" / "demo.yaml"


@pytest.fixture(scope="module")
def campaign():
    return load_campaign(DEMO)


@pytest.fixture(scope="module")
def points(campaign):
    return compile_plan(campaign.plan, campaign.station)


def session_tables(path) -> dict:
    with SessionReader(path) as r:
        return {"session": r.info(), "points": r.points(), "events": r.events(), "fits": r.fits(),
                "snapshots": r.snapshots()}


def summarize(path) -> dict:
    with SessionReader(path) as r:
        return r.summary()


def new_session(tmp_path, campaign, points, name="s.magrig") -> Session:
    return Session.create_for(tmp_path / name, campaign, points, operator="op", clock=SimClock())


def rows_for(point, dut="mmc0", n=5, flags=frozenset(), temp_c=None):
    out = []
    for i in range(n):
        h = (1000.0 * point.field_index + i, 2.0 * i, -3.0)
        out.append(SampleRow(dut=dut, t=1000.0 * point.index + i, field_nt=h, ref_field_nt=point.field_nt,
                             temp_c=point.setpoint_c + 0.1 if temp_c is None else temp_c,
                             ref_temp_c=point.setpoint_c, counts=(1, 2, 3), flags=flags))
    return out


def test_session_file_is_wal_with_foreign_keys_and_marked_as_ours(tmp_path, campaign, points):
    s = new_session(tmp_path, campaign, points)
    conn = s._conn
    assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert conn.execute("PRAGMA foreign_keys").fetchone()[0] == 1
    assert conn.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    with pytest.raises(sqlite3.IntegrityError):  # samples must belong to a planned point
        conn.execute("INSERT INTO samples (point_id, dut, t, hx, hy, hz, bx, by, bz) "
                     "VALUES ('T99-F99', 'x', 0, 0, 0, 0, 0, 0, 0)")
    s.close()
    info = session_tables(tmp_path / "s.magrig")["session"]
    assert info["plan_text"] == campaign.plan_text and info["station_text"] == campaign.station_text
    assert info["operator"] == "op" and info["plan_name"] == "demo"


def test_create_refuses_to_overwrite(tmp_path, campaign, points):
    new_session(tmp_path, campaign, points).close()
    with pytest.raises(SessionError, match="already exists"):
        new_session(tmp_path, campaign, points)


def test_points_are_planned_then_done_and_survive_reopening(tmp_path, campaign, points):
    s = new_session(tmp_path, campaign, points)
    assert s.planned_point_ids() == [p.id for p in points] and s.done_point_ids() == set()
    for p in points[:3]:
        s.record_point(p.id, rows_for(p), {"settle_s": 12.5, "stable": True})
    s.close()
    again = Session.open(tmp_path / "s.magrig")
    assert again.done_point_ids() == {p.id for p in points[:3]}
    with pytest.raises(SessionError, match=f"{points[1].id} is already recorded"):
        again.record_point(points[1].id, rows_for(points[1]))
    with pytest.raises(SessionError, match="T77-F01 is not in the plan"):
        again.record_point("T77-F01", [])
    again.close()


def test_a_failure_inside_the_point_leaves_nothing(tmp_path, campaign, points):
    s = new_session(tmp_path, campaign, points)

    def rows_then_crash():
        yield from rows_for(points[0], n=3)
        raise RuntimeError("DUT unplugged mid-point")

    with pytest.raises(RuntimeError):
        s.record_point(points[0].id, rows_then_crash())
    assert s.done_point_ids() == set()
    assert s._conn.execute("SELECT count(*) FROM samples").fetchone()[0] == 0
    s.record_point(points[0].id, rows_for(points[0]))  # the retake goes in cleanly
    assert s._conn.execute("SELECT count(*) FROM samples").fetchone()[0] == 5


WRITER = textwrap.dedent("""
    import sys, time
    from rig.config.loading import load_campaign
    from rig.schedules.compile import compile_plan
    from rig.session.rows import SampleRow
    from rig.session.writer import Session
    campaign = load_campaign(sys.argv[2])
    points = compile_plan(campaign.plan, campaign.station)
    s = Session.create_for(sys.argv[1], campaign, points)

    def rows(p):
        for i in range(5000):
            if p.index == 2 and i == 2500:  # half-way through the third point: tell the test, then hang
                print("mid-point", flush=True)
                time.sleep(60)
            yield SampleRow("mmc0", float(i), (1.0, 2.0, 3.0), p.field_nt, temp_c=20.0)

    for p in points:
        s.record_point(p.id, rows(p))
""")


def test_kill_9_mid_write_leaves_whole_points_only(tmp_path, points):
    path = tmp_path / "killed.magrig"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path), str(DEMO)], stdout=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout.readline().strip() == "mid-point"  # the third point's transaction is open
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
    conn = sqlite3.connect(path)
    per_point = dict(conn.execute(
        "SELECT p.id, count(s.id) FROM points p LEFT JOIN samples s ON s.point_id = p.id GROUP BY p.id"))
    done = {r[0] for r in conn.execute("SELECT id FROM points WHERE state = 'done'")}
    conn.close()
    assert done == {points[0].id, points[1].id}
    for point, n in per_point.items():
        assert n == (5000 if point in done else 0), point
    resumed = Session.open(path)
    assert resumed.done_point_ids() == done
    row = SampleRow("mmc0", 0.0, (1.0, 2.0, 3.0), (0.0, 0.0, 1.0), temp_c=20.0)
    resumed.record_point(points[2].id, [row])
    resumed.close()


def test_ctrl_c_during_the_commit_is_held_until_the_point_is_stored(tmp_path, campaign, points,
                                                                   default_sigint):
    s = new_session(tmp_path, campaign, points)

    def rows_with_ctrl_c():
        rows = rows_for(points[0], n=4)
        yield from rows[:2]
        os.kill(os.getpid(), signal.SIGINT)
        yield from rows[2:]

    with pytest.raises(KeyboardInterrupt):
        s.record_point(points[0].id, rows_with_ctrl_c())
    assert s.done_point_ids() == {points[0].id}
    assert s._conn.execute("SELECT count(*) FROM samples").fetchone()[0] == 4
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_the_dataset_holds_the_unflagged_sample_rows_in_their_order(tmp_path, campaign, points):
    s = new_session(tmp_path, campaign, points)
    s.record_point(points[0].id, rows_for(points[0], n=3) + rows_for(points[0], n=1, flags={"overflow"}))
    s.record_point(points[40].id, rows_for(points[40], n=2) + rows_for(points[40], n=1, temp_c=None))
    s.close()
    with SessionReader(tmp_path / "s.magrig") as reader:
        _, rows = reader.sample_rows("mmc0")
        ds = reader.dataset("mmc0")
    good = [r for r in rows if not r["flags"]]
    assert ds.n == len(good) == 6
    assert np.array_equal(ds.h_nt, [[r["hx"], r["hy"], r["hz"]] for r in good])
    assert np.array_equal(ds.ref_nt, [[r["bx"], r["by"], r["bz"]] for r in good])
    assert np.array_equal(ds.temp_c, [r["temp"] for r in good])
    assert list(ds.group) == [r["group"] for r in good]
    assert list(ds.columns["point"]) == [r["point"] for r in good]
    assert np.array_equal(ds.columns["t"], [r["t"] for r in good])


def test_read_dataset_round_trip(tmp_path, campaign, points):
    s = new_session(tmp_path, campaign, points)
    fs = FieldSample(t=5.0, field_nt=(11.0, 12.0, 13.0), counts=(7, 8, 9), temp_c=-19.5,
                     offset_nt=(0.5, 0.25, 0.125))
    first = [SampleRow.from_field_sample("mmc0", fs, points[0].field_nt, ref_temp_c=-19.0)]
    s.record_point(points[0].id, first + rows_for(points[0], n=3) + rows_for(points[0], dut="serial0"))
    s.record_point(points[32].id, rows_for(points[32], n=2) + rows_for(points[32], n=1, flags={"overflow"})
                   + rows_for(points[32], n=1, temp_c=None))
    s.record_point(points[33].id, [SampleRow("mmc0", 9.0, (1.0, 1.0, 1.0), points[33].field_nt,
                                             temp_c=None, ref_temp_c=3.5)])
    s.close()
    ds = read_dataset(tmp_path / "s.magrig", "mmc0")
    assert isinstance(ds, Dataset)
    assert ds.n == 1 + 3 + 2 + 1 + 1
    assert np.allclose(ds.h_nt[0], [11.0, 12.0, 13.0]) and ds.temp_c[0] == -19.5
    assert np.allclose(ds.ref_nt[0], points[0].field_nt) and np.allclose(ds.ref_nt[-1], points[33].field_nt)
    assert ds.temp_c[-1] == 3.5  # no DUT temperature: the reference sensor's
    assert list(ds.group[[0, 4]]) == ["T01 -20.0C", "T02 0.0C"]
    assert list(ds.columns["point"][[0, 4, 7]]) == [points[0].id, points[32].id, points[33].id]
    assert ds.source["rows_total"] == 9 and ds.source["rows_rejected"] == 1 and ds.source["kind"] == "session"
    assert len(ds.source["sha256"]) == 64
    serial = read_dataset(tmp_path / "s.magrig", "serial0")
    assert serial.n == 5


def test_numpy_values_are_stored_as_plain_numbers(tmp_path, campaign, points):
    s = new_session(tmp_path, campaign, points)
    row = SampleRow("mmc0", np.float64(1.5), np.array([1.0, 2.0, 3.0]), np.array(points[0].field_nt),
                    temp_c=np.float32(20.25), counts=np.array([131072, 5, -7], dtype=np.int64))
    s.record_point(points[0].id, [row])
    stored = s._conn.execute("SELECT t, hx, cx, cz, temp_c, typeof(cx) FROM samples").fetchone()
    assert tuple(stored) == (1.5, 1.0, 131072, -7, 20.25, "integer")
    s.close()


def test_dut_choice_errors_list_the_duts(tmp_path, campaign, points):
    s = new_session(tmp_path, campaign, points)
    path = tmp_path / "s.magrig"
    with pytest.raises(SessionError, match="no samples yet"):
        read_dataset(path)
    s.record_point(points[0].id, rows_for(points[0]) + rows_for(points[0], dut="serial0"))
    with pytest.raises(SessionError, match=r"several DUTs \(mmc0, serial0\): choose one with --dut"):
        read_dataset(path)
    with pytest.raises(SessionError, match=r"no DUT named 'hmc9' \(DUTs: mmc0, serial0\)"):
        read_dataset(path, "hmc9")
    s.close()


def test_files_that_are_not_sessions(tmp_path, campaign, points):
    junk = tmp_path / "junk.magrig"
    junk.write_bytes(b"this is not a database at all " * 200)
    other = tmp_path / "other.sqlite"
    with sqlite3.connect(other) as conn:
        conn.execute("CREATE TABLE t (x)")
    for path, message in [(junk, "not a session file or damaged"), (other, "not a magrig session file"),
                          (tmp_path / "missing.magrig", "no such session file")]:
        with pytest.raises(SessionError, match=message) as info:
            read_dataset(path)
        assert str(path) in str(info.value)
        with pytest.raises(SessionError, match=message):
            Session.open(path)


def test_a_damaged_session_file(tmp_path, campaign, points):
    s = new_session(tmp_path, campaign, points)
    for p in points[:4]:
        s.record_point(p.id, rows_for(p, n=200))
    s.close()
    path = tmp_path / "s.magrig"
    data = bytearray(path.read_bytes())
    data[len(data) // 2:] = b"\xff" * (len(data) - len(data) // 2)
    path.write_bytes(bytes(data))
    with pytest.raises(SessionError, match=str(path)):
        read_dataset(path, "mmc0")


def test_a_newer_schema_is_refused(tmp_path, campaign, points):
    new_session(tmp_path, campaign, points).close()
    with sqlite3.connect(tmp_path / "s.magrig") as conn:
        conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    with pytest.raises(SessionError, match=f"schema version {SCHEMA_VERSION + 1}"):
        Session.open(tmp_path / "s.magrig")


def test_events_snapshots_fits_and_finish(tmp_path, campaign, points):
    s = new_session(tmp_path, campaign, points)
    s.log_event("warning", "chamber: read PV: try 1 of 3 failed", device="chamber", logger="magrig.transport")
    s.log_event(Kind.HOLD, "temperature out of band", code=Reason.TEMP_OUT_OF_BAND, point_id="T01-F02",
                device="mmc0", retake=1)
    s.record_snapshot("mmc0", {"model": "MMC5983MA", "product_id": 0x30})
    s.record_point(points[0].id, rows_for(points[0]))
    s.record_fit("mmc0", "t24", {"params": {"b_nt": np.array([1.0, 2.0, 3.0])}}, residual_rms_nt=42.5)
    s.mark_point_failed(points[1].id, "chamber alarm")
    s.finish("aborted", "operator aborted")
    assert not s.completed
    s.close()
    tables = session_tables(tmp_path / "s.magrig")
    typed = [(e.level, e.kind, e.code, e.device, e.point_id) for e in tables["events"]]
    assert typed == [("WARNING", "warning", Reason.LOGGED, "chamber", None),
                     ("INFO", "hold", Reason.TEMP_OUT_OF_BAND, "mmc0", "T01-F02")]
    assert tables["events"][1].data == {"retake": 1}
    assert '"b_nt": [1.0, 2.0, 3.0]' in tables["fits"][0]["calibration_json"]
    assert tables["points"][1]["state"] == "failed" and tables["points"][1]["reason"] == "chamber alarm"
    summary = summarize(tmp_path / "s.magrig")
    assert summary["points_done"] == 1 and summary["points_failed"] == 1
    assert summary["points_planned"] == len(points) and summary["duts"] == ["mmc0"]
    assert summary["exit_status"] == "aborted" and summary["completed"] is False
    assert summary["last_fit"]["residual_rms_nt"] == 42.5
    assert summary["simulated"]["chamber"] is True


def test_finish_marks_a_complete_run(tmp_path, campaign, points):
    few = points[:2]
    s = new_session(tmp_path, campaign, few)
    for p in few:
        s.record_point(p.id, rows_for(p, n=1))
    s.finish("completed", "all points collected")
    assert s.completed
    s.close()
    assert summarize(tmp_path / "s.magrig")["completed"] is True


def test_writes_from_another_thread(tmp_path, campaign, points):
    import threading

    s = new_session(tmp_path, campaign, points)
    worker = threading.Thread(target=s.log_event, args=("warning", "from a simulator thread"))
    worker.start()
    worker.join()
    s.record_point(points[0].id, rows_for(points[0]))
    assert [e.message for e in session_tables(s.path)["events"]] == ["from a simulator thread"]
    s.close()


def test_a_decision_is_stored_with_its_point_or_not_at_all(tmp_path, campaign, points):
    """A sequential schedule's decision (the next sweep's points) goes in the point's own transaction."""
    from types import SimpleNamespace

    from rig.session.rows import Decision

    s = new_session(tmp_path, campaign, points[:2])
    nxt = [SimpleNamespace(id=f"L01-S0002-F0{i}", index=2 + i, temp_index=2, setpoint_c=20.0, field_index=i,
                           target={"field_nt": [1.0, 0.0, 0.0]}) for i in (1, 2)]
    s.record_point(points[0].id, rows_for(points[0]))
    bad = Decision({"leg": 1, "sweep": 2}, (nxt[0], nxt[0]))  # the same point twice: the insert fails
    with pytest.raises(sqlite3.IntegrityError):
        s.record_point(points[1].id, rows_for(points[1]), decision=bad)
    assert s.done_point_ids() == {points[0].id} and s.decisions() == []
    assert s.planned_point_ids() == [p.id for p in points[:2]]
    s.record_point(points[1].id, rows_for(points[1]), decision=Decision({"leg": 1, "sweep": 2}, tuple(nxt)))
    assert s.planned_point_ids() == [points[0].id, points[1].id, *(p.id for p in nxt)]
    assert s.decisions() == [{"leg": 1, "sweep": 2, "after_point": points[1].id}]
    s.close()
    with SessionReader(tmp_path / "s.magrig") as reader:
        assert reader.decisions() == [{"leg": 1, "sweep": 2, "after_point": points[1].id}]
        assert reader.summary()["points_planned"] == 4
