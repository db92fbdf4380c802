"""`rig push`: copy session files into the fleet database, one PostgreSQL transaction per session.

A session already there with the same content hash is left alone (pushing twice changes nothing). A
session whose content changed (a campaign still running, a re-fit recorded) is replaced whole in the same
transaction, so a reader sees the old copy or the new one, and a push killed half-way leaves the old copy
(or nothing) and is simply run again.
"""

from __future__ import annotations

import datetime as dt
import json
import weakref
from dataclasses import dataclass
from typing import Literal

import psycopg
from psycopg import sql

from rig.fleet import FleetError
from rig.fleet.schema import OWN_TABLES, SCHEMA, copied_tables, ensure_copy_table
from rig.fleet.source import SessionSnapshot, Table

Outcome = Literal["added", "replaced", "unchanged"]
# {connection: {copied table: columns}}: the catalogue read once per connection, not once per session
_KNOWN: weakref.WeakKeyDictionary[psycopg.Connection, dict[str, set[str]]] = weakref.WeakKeyDictionary()
VERDICT_COLUMNS = ("verdict", "result", "status", "outcome")  # in a table named acceptance*


@dataclass(frozen=True)
class PushResult:
    uid: str
    outcome: Outcome
    samples: int


def push_snapshot(conn: psycopg.Connection, snap: SessionSnapshot) -> PushResult:
    """Copy one session in one transaction; FleetError (naming the file) if the database refuses it."""
    uid, digest = snap.uid, snap.content_hash()
    clash = sorted(set(snap.tables) & set(OWN_TABLES))
    if clash:
        raise FleetError(f"{snap.path}: session table {clash[0]!r} has the name of a fleet table")
    try:
        with conn.transaction():
            # Two pushers of the same session queue here instead of both deleting and inserting.
            conn.execute("SELECT pg_advisory_xact_lock(hashtextextended(%s, 0))", (uid,))
            row = conn.execute(sql.SQL("SELECT content_hash FROM {} WHERE uid = %s").format(
                sql.Identifier(SCHEMA, "fleet_sessions")), (uid,)).fetchone()
            if row is not None and row[0] == digest:
                return PushResult(uid, "unchanged", len(snap.tables["samples"].rows))
            if row is not None:  # the copies go with it (ON DELETE CASCADE)
                conn.execute(sql.SQL("DELETE FROM {} WHERE uid = %s").format(
                    sql.Identifier(SCHEMA, "fleet_sessions")), (uid,))
            _insert_session_row(conn, snap, uid, digest)
            known = _KNOWN.get(conn)
            if known is None:
                known = _KNOWN[conn] = copied_tables(conn)
            for table in snap.tables.values():
                ensure_copy_table(conn, table, known)
                copy_rows(conn, uid, table)
            _insert_duts(conn, snap, uid)
    except BaseException as exc:
        _KNOWN.pop(conn, None)  # tables made in the rolled-back transaction are gone again
        if not isinstance(exc, psycopg.Error):
            raise
        raise FleetError(f"{snap.path}: the fleet database refused the session: "
                         f"{str(exc).strip().splitlines()[0]}") from None
    return PushResult(uid, "added" if row is None else "replaced", len(snap.tables["samples"].rows))


def copy_rows(conn: psycopg.Connection, uid: str, table: Table) -> None:
    """All rows of one table with COPY (the samples are most of a session)."""
    if not table.rows:
        return
    statement = sql.SQL("COPY {} ({}) FROM STDIN").format(
        sql.Identifier(SCHEMA, table.name),
        sql.SQL(", ").join(map(sql.Identifier, ["session_uid", *table.column_names])),
    )
    with conn.cursor().copy(statement) as copy:
        for row in table.rows:
            copy.write_row((uid, *row))


def _insert_session_row(conn: psycopg.Connection, snap: SessionSnapshot, uid: str, digest: str) -> None:
    s = snap.session
    states = [p.get("state") for p in snap.tables["points"].dicts()]
    conn.execute(
        sql.SQL(
            "INSERT INTO {} (uid, content_hash, source_path, plan_name, station_name, started_utc, "
            "ended_utc, exit_status, completed, points_done, points_planned, n_samples, verdict) "
            "VALUES (%s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s, %s)"
        ).format(sql.Identifier(SCHEMA, "fleet_sessions")),
        (uid, digest, str(snap.path.resolve()), s.get("plan_name"), s.get("station_name"),
         _utc(s.get("wall_started")), _utc(s.get("wall_ended")), s.get("exit_status"),
         None if s.get("completed") is None else bool(s["completed"]),
         states.count("done"), len(snap.tables["points"].rows), len(snap.tables["samples"].rows),
         verdict(snap)),
    )


def _insert_duts(conn: psycopg.Connection, snap: SessionSnapshot, uid: str) -> None:
    samples = snap.tables["samples"]
    at = samples.column_names.index("dut")
    duts = sorted({row[at] for row in samples.rows})
    serials = dut_serials(snap)
    with conn.cursor().copy(sql.SQL("COPY {} (session_uid, dut, serial) FROM STDIN").format(
            sql.Identifier(SCHEMA, "fleet_duts"))) as copy:
        for dut in duts:
            copy.write_row((uid, dut, serials.get(dut)))


def dut_serials(snap: SessionSnapshot) -> dict[str, str]:
    """{device name: serial number} from the device snapshots that report one (the serial
    magnetometer's `serial_number`; I2C chips report only a product id, which is not a serial)."""
    out: dict[str, str] = {}
    table = snap.tables.get("snapshots")
    for row in table.dicts() if table else []:
        try:
            describe = json.loads(row.get("describe_json") or "{}")
        except ValueError:
            continue
        serial = describe.get("serial_number") if isinstance(describe, dict) else None
        if serial:
            out[str(row["device"])] = str(serial)
    return out


def verdict(snap: SessionSnapshot) -> str | None:
    """PASS or FAIL from the session's acceptance table(s) when it has one: FAIL if any row fails,
    PASS if every row passes; None when there is no such table or no row says either."""
    said: list[str] = []
    for name, table in snap.tables.items():
        if not name.lower().startswith("acceptance"):
            continue
        for row in table.dicts():
            lower = {k.lower(): v for k, v in row.items()}
            if "passed" in lower and lower["passed"] is not None:
                said.append("PASS" if lower["passed"] in (1, True, "1", "true", "TRUE") else "FAIL")
                continue
            for key in VERDICT_COLUMNS:
                value = str(lower.get(key) or "").strip().upper()
                if value in ("PASS", "FAIL"):
                    said.append(value)
                    break
    if not said:
        return None
    return "FAIL" if "FAIL" in said else "PASS"


def _utc(seconds: float | None) -> dt.datetime | None:
    return None if seconds is None else dt.datetime.fromtimestamp(float(seconds), dt.UTC)
