"""The fleet database's tables (PostgreSQL schema `magrig`).

Three tables of our own:
    fleet_sessions   one row per session: uid, content hash, where it came from, what `fleet list` filters on
    fleet_duts       the DUTs of each session with their serial numbers (from the device snapshots)
    refit_results    one row per (session, DUT, model, software version) from `rig refit-all`
and one copy of each table of the session files (session, points, samples, events, fits, snapshots,
and any other such as acceptance results), named as in the file, with `session_uid` in front of its
columns. Those copies are created and widened on demand from the file's own columns, so a column added
to the session schema arrives as a column here without a code change. Deleting a fleet_sessions row
deletes its copies (ON DELETE CASCADE).
"""

from __future__ import annotations

import re

import psycopg
from psycopg import sql

from rig.fleet import FleetError
from rig.fleet.source import Column, Table

SCHEMA = "magrig"
OWN_TABLES = ("fleet_sessions", "fleet_duts", "refit_results")
_SCHEMA_LOCK = 0x4D475247  # advisory lock key: one process at a time creates or widens tables

FLEET_DDL = """
CREATE SCHEMA IF NOT EXISTS magrig;
CREATE TABLE IF NOT EXISTS magrig.fleet_sessions (
    uid TEXT PRIMARY KEY,
    content_hash TEXT NOT NULL,
    source_path TEXT NOT NULL,
    pushed_at TIMESTAMPTZ NOT NULL DEFAULT now(),
    plan_name TEXT, station_name TEXT,
    started_utc TIMESTAMPTZ, ended_utc TIMESTAMPTZ,
    exit_status TEXT, completed BOOLEAN,
    points_done INTEGER, points_planned INTEGER, n_samples BIGINT,
    verdict TEXT CHECK (verdict IN ('PASS', 'FAIL'))   -- from an acceptance table, when there is one
);
CREATE INDEX IF NOT EXISTS fleet_sessions_by_station ON magrig.fleet_sessions (station_name, started_utc);
CREATE TABLE IF NOT EXISTS magrig.fleet_duts (
    session_uid TEXT NOT NULL REFERENCES magrig.fleet_sessions (uid) ON DELETE CASCADE,
    dut TEXT NOT NULL, serial TEXT,
    PRIMARY KEY (session_uid, dut)
);
CREATE INDEX IF NOT EXISTS fleet_duts_by_name ON magrig.fleet_duts (dut);
CREATE INDEX IF NOT EXISTS fleet_duts_by_serial ON magrig.fleet_duts (serial);
CREATE TABLE IF NOT EXISTS magrig.refit_results (
    session_uid TEXT NOT NULL, dut TEXT NOT NULL, model TEXT NOT NULL, software_version TEXT NOT NULL,
    source TEXT, station TEXT, status TEXT NOT NULL, reason TEXT,
    n INTEGER, n_used INTEGER, rms_before_nt DOUBLE PRECISION, rms_after_nt DOUBLE PRECISION,
    temp_ref_c DOUBLE PRECISION, params JSONB, std_errors JSONB,
    fitted_at TIMESTAMPTZ NOT NULL DEFAULT now(),
    PRIMARY KEY (session_uid, dut, model, software_version)
);
"""


def redact(url: str) -> str:
    """The URL without its password, for messages."""
    return re.sub(r"(://[^:/@]+):[^@]*@", r"\1:***@", re.sub(r"password=\S+", "password=***", url))


def connect(url: str, *, create: bool = True) -> psycopg.Connection:
    """An autocommit connection (each session push opens its own transaction) with our tables in place
    (create=False: a reader that expects them there)."""
    try:
        conn = psycopg.connect(url, autocommit=True, connect_timeout=10)
    except psycopg.Error as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise FleetError(f"{redact(url)}: cannot connect to the fleet database: {first}") from None
    if not create:
        return conn
    try:
        with conn.transaction():
            conn.execute("SELECT pg_advisory_xact_lock(%s)", (_SCHEMA_LOCK,))
            conn.execute(FLEET_DDL)
    except psycopg.Error as exc:
        conn.close()
        raise FleetError(f"{redact(url)}: cannot create the fleet tables: {exc}") from None
    return conn


def pg_type(column: Column) -> str:
    """PostgreSQL type for an SQLite declared type, by SQLite's own affinity rules."""
    decl = column.decl_type.upper()
    if "INT" in decl:
        return "BIGINT"
    if any(word in decl for word in ("CHAR", "CLOB", "TEXT")):
        return "TEXT"
    if "BLOB" in decl:
        return "BYTEA"
    if any(word in decl for word in ("REAL", "FLOA", "DOUB")):
        return "DOUBLE PRECISION"
    return "TEXT"  # no or another declared type: kept as its text


def copied_tables(conn: psycopg.Connection) -> dict[str, set[str]]:
    """{table: columns} of the session-table copies that exist in the database."""
    rows = conn.execute(
        "SELECT table_name, column_name FROM information_schema.columns WHERE table_schema = %s",
        (SCHEMA,),
    ).fetchall()
    out: dict[str, set[str]] = {}
    for table, column in rows:
        if table not in OWN_TABLES:
            out.setdefault(table, set()).add(column)
    return out


def ensure_copy_table(conn: psycopg.Connection, table: Table, known: dict[str, set[str]]) -> None:
    """Create the copy of `table`, or add the columns it lacks. `known` (from copied_tables) is updated.
    Runs inside the caller's transaction, so a failed push leaves no half-made table either."""
    have = known.get(table.name)
    if have is not None and set(table.column_names) <= have:
        return
    conn.execute("SELECT pg_advisory_xact_lock(%s)", (_SCHEMA_LOCK,))
    known.clear()
    known.update(copied_tables(conn))  # another process may have made it meanwhile
    name = sql.Identifier(SCHEMA, table.name)
    if table.name not in known:
        columns = [sql.SQL("session_uid TEXT NOT NULL REFERENCES {} (uid) ON DELETE CASCADE").format(
            sql.Identifier(SCHEMA, "fleet_sessions"))]
        columns += [sql.SQL("{} {}").format(sql.Identifier(c.name), sql.SQL(pg_type(c)))
                    for c in table.columns]
        key = [c.name for c in sorted(table.columns, key=lambda c: c.pk_index) if c.pk_index]
        if key:  # a table without a key of its own (acceptance) holds many rows per session: no key here
            columns.append(sql.SQL("PRIMARY KEY ({})").format(
                sql.SQL(", ").join(map(sql.Identifier, ["session_uid", *key]))))
        conn.execute(sql.SQL("CREATE TABLE {} ({})").format(name, sql.SQL(", ").join(columns)))
        known[table.name] = {"session_uid"}
    for column in table.columns:
        if column.name not in known[table.name]:
            conn.execute(sql.SQL("ALTER TABLE {} ADD COLUMN IF NOT EXISTS {} {}").format(
                name, sql.Identifier(column.name), sql.SQL(pg_type(column))))
            known[table.name].add(column.name)
