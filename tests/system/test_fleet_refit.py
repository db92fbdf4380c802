"""`rig refit-all` on a local Dask cluster, from a folder and from the fleet database, held to `rig refit`."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import psycopg
import pyarrow.parquet as pq
import pytest

from rig import __version__
from rig.cli import main
from rig.fleet.source import session_snapshot
from tests.fleet_sessions import Spec, write_session


def one_by_one(path: Path, dut: str, model: str, tmp_path: Path) -> dict:
    """`rig refit` of one DUT, as a user runs it; the calibration file read back (JSON keeps every digit)."""
    out = tmp_path / f"{path.stem}-{dut}-{model}.json"
    assert main(["refit", str(path), "--dut", dut, "--model", model, "-o", str(out)]) == 0
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> dict[str, Path]:
    """Three good sessions (one with two DUTs), and three that cannot all be fitted."""
    folder = tmp_path_factory.mktemp("sessions")
    good = {
        "g1": write_session(folder / "g1.session", Spec(seed=1, duts=("dut1", "dut2"))),
        "g2": write_session(folder / "g2.session", Spec(seed=2, station="rig-b")),
        "g3": write_session(folder / "g3.session", Spec(seed=3)),
    }
    short = write_session(folder / "short.session", Spec(seed=4), upto=2, finish=False)  # 2 points: too few
    damaged = folder / "damaged.session"
    shutil.copy(good["g3"], damaged)
    with open(damaged, "r+b") as f:  # the SQLite header survives, the pages behind it do not
        f.seek(100)
        f.write(b"\xff" * 4000)
    (folder / "notes.session").write_text("not a session\n")
    return {**good, "short": short, "damaged": damaged, "notes": folder / "notes.session"}


def rows_by_key(path: Path) -> dict[tuple[str, str], dict]:
    return {(Path(r["source"]).stem, r["dut"]): r for r in pq.read_table(path).to_pylist()}


def assert_same_fit(row: dict, cal: dict) -> None:
    assert row["status"] == "ok" and row["reason"] == ""
    params, errors = json.loads(row["params"]), json.loads(row["std_errors"])
    assert params.keys() == cal["params"].keys()
    for name in cal["params"]:
        np.testing.assert_array_equal(np.asarray(params[name]), np.asarray(cal["params"][name]))
        np.testing.assert_array_equal(np.asarray(errors[name]), np.asarray(cal["std_errors"][name]))
    assert row["n"] == cal["stats"]["n"]
    assert row["rms_after_nt"] == cal["stats"]["rms_after_nt"]


def test_refit_all_from_a_folder_matches_rig_refit(sessions, tmp_path, capsys):
    folder = sessions["g1"].parent
    out = tmp_path / "results.parquet"
    code = main(["refit-all", str(folder), "--model", "t24", "--out", str(out), "--workers", "2",
                 "--no-progress"])
    text = capsys.readouterr().out
    assert code == 0
    assert "re-fitted 4 DUT(s) of 6 session(s) with t24; 3 failed" in text
    rows = rows_by_key(out)
    assert set(rows) == {("g1", "dut1"), ("g1", "dut2"), ("g2", "dut1"), ("g3", "dut1"), ("short", "dut1"),
                         ("damaged", ""), ("notes", "")}
    for key in (("g1", "dut1"), ("g1", "dut2"), ("g2", "dut1"), ("g3", "dut1")):
        assert_same_fit(rows[key], one_by_one(sessions[key[0]], key[1], "t24", tmp_path))
        assert rows[key]["session_uid"] == session_snapshot(sessions[key[0]]).uid
        assert rows[key]["software_version"] == __version__
    assert rows[("g2", "dut1")]["station"] == "rig-b"
    for key in (("short", "dut1"), ("damaged", ""), ("notes", "")):
        assert rows[key]["status"] == "failed" and rows[key]["params"] is None
    assert "damaged" in rows[("damaged", "")]["reason"]
    assert "not a session file" in rows[("notes", "")]["reason"]
    assert rows[("short", "dut1")]["reason"]  # what calib said about too few points
    assert f"failed {sessions['notes']} (session): " in text


def test_refit_all_from_the_database_matches_and_writes_results_back(sessions, fleet_db, tmp_path, capsys):
    pushable = [sessions[k] for k in ("g1", "g2", "g3", "short")]
    assert main(["push", *map(str, pushable), "--db", fleet_db]) == 0
    out = tmp_path / "db.parquet"
    code = main(["refit-all", "--db", fleet_db, "--model", "p12", "--out", str(out), "--workers", "2",
                 "--no-progress"])
    text = capsys.readouterr().out
    assert code == 0 and "re-fitted 4 DUT(s) of 4 session(s) with p12; 1 failed" in text
    rows = rows_by_key(out)
    for key in (("g1", "dut1"), ("g1", "dut2"), ("g2", "dut1"), ("g3", "dut1")):
        assert_same_fit(rows[key], one_by_one(sessions[key[0]], key[1], "p12", tmp_path))
    assert rows[("short", "dut1")]["status"] == "failed"

    with psycopg.connect(fleet_db) as conn:
        stored = conn.execute(
            "SELECT session_uid, dut, model, software_version, status, params FROM magrig.refit_results"
        ).fetchall()
    assert len(stored) == 5
    by_uid = {(row[0], row[1]): row[2:] for row in stored}
    g2 = by_uid[(session_snapshot(sessions["g2"]).uid, "dut1")]
    assert g2[:3] == ("p12", __version__, "ok") and g2[3] == json.loads(rows[("g2", "dut1")]["params"])

    # Run again: the results are replaced (same key), not added.
    assert main(["refit-all", "--db", fleet_db, "--model", "p12", "--out", str(out), "--no-progress",
                 "--workers", "1"]) == 0
    with psycopg.connect(fleet_db) as conn:
        assert conn.execute("SELECT count(*) FROM magrig.refit_results").fetchone()[0] == 5


def test_refit_all_needs_a_source(capsys, tmp_path):
    code = main(["refit-all", "--model", "t24", "--out", str(tmp_path / "r.parquet")])
    assert code == 2 and "give SESSIONS_DIR, or --db URL" in capsys.readouterr().err
    code = main(["refit-all", str(tmp_path), "--out", str(tmp_path / "r.parquet")])
    assert code == 2 and "no sessions in" in capsys.readouterr().err
    assert not (tmp_path / "r.parquet").exists()


def test_refit_all_on_an_existing_cluster(sessions, tmp_path, capsys):
    from distributed import LocalCluster

    folder = tmp_path / "two"
    folder.mkdir()
    for key in ("g2", "notes"):
        shutil.copy(sessions[key], folder / sessions[key].name)
    out = tmp_path / "r.parquet"
    cluster = LocalCluster(n_workers=1, processes=False, protocol="tcp://", host="127.0.0.1",
                           dashboard_address="127.0.0.1:0")
    with cluster:
        code = main(["refit-all", str(folder), "--scheduler", cluster.scheduler_address, "--out", str(out),
                     "--no-progress"])
    assert code == 0 and "re-fitted 1 DUT(s) of 2 session(s) with t24; 1 failed" in capsys.readouterr().out
    rows = rows_by_key(out)
    assert_same_fit(rows[("g2", "dut1")], one_by_one(sessions["g2"], "dut1", "t24", tmp_path))
