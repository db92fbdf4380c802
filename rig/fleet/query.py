"""Reads from the fleet database: the session listing with its filters, and one session's rows for a
re-fit (the same rows a session file gives, so both go through one dataset builder)."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

import psycopg
from psycopg import sql
from psycopg.rows import dict_row

from rig.fleet import DATE_FORMATS, FleetError
from rig.fleet.schema import SCHEMA

LISTING_COLUMNS = ("session", "started (UTC)", "station", "DUTs", "points", "exit", "verdict", "file")


def parse_date(text: str, what: str) -> dt.datetime:
    """A --since / --until value (one of DATE_FORMATS) as a UTC time; FleetError naming `what`."""
    for fmt in DATE_FORMATS:
        try:
            return dt.datetime.strptime(text.strip(), fmt).replace(tzinfo=dt.UTC)
        except ValueError:
            continue
    raise FleetError(f"{what}: {text!r} is not a date ({', '.join(DATE_FORMATS)})")


@dataclass(frozen=True)
class Filters:
    station: str | None = None
    dut: str | None = None  # a DUT name or a serial number
    since: dt.datetime | None = None  # started at or after (UTC)
    until: dt.datetime | None = None  # started before (UTC)
    verdict: str | None = None  # PASS or FAIL (sessions without an acceptance result never match)


def list_sessions(conn: psycopg.Connection, filters: Filters = Filters()) -> list[dict]:
    """Sessions across rigs, oldest first, each with its DUTs ("dut1,dut2") and serials."""
    where, params = [], []
    if filters.station:
        where.append("s.station_name = %s")
        params.append(filters.station)
    if filters.dut:
        where.append("EXISTS (SELECT 1 FROM magrig.fleet_duts d WHERE d.session_uid = s.uid "
                     "AND (d.dut = %s OR d.serial = %s))")
        params += [filters.dut, filters.dut]
    if filters.since:
        where.append("s.started_utc >= %s")
        params.append(filters.since)
    if filters.until:
        where.append("s.started_utc < %s")
        params.append(filters.until)
    if filters.verdict:
        where.append("s.verdict = %s")
        params.append(filters.verdict.upper())
    query = (
        "SELECT s.*, coalesce(string_agg(d.dut, ',' ORDER BY d.dut), '') AS duts, "
        "coalesce(string_agg(d.serial, ',' ORDER BY d.dut), '') AS serials "
        "FROM magrig.fleet_sessions s LEFT JOIN magrig.fleet_duts d ON d.session_uid = s.uid"
        + (" WHERE " + " AND ".join(where) if where else "")
        + " GROUP BY s.uid ORDER BY s.started_utc, s.uid"
    )
    with conn.cursor(row_factory=dict_row) as cur:
        return cur.execute(query, params).fetchall()


def listing_cells(row: dict) -> list[str]:
    """One row of `list_sessions` as the LISTING_COLUMNS (`rig fleet list` and the cockpit's fleet page)."""
    started = row["started_utc"].strftime("%Y-%m-%d %H:%M") if row["started_utc"] else "-"
    duts = row["duts"] + (f" ({row['serials']})" if row["serials"] else "")
    return [row["uid"][:12], started, row["station_name"] or "-", duts or "-",
            f"{row['points_done']}/{row['points_planned']}", row["exit_status"] or "not finished",
            row["verdict"] or "-", row["source_path"]]


def session_rows(conn: psycopg.Connection, uid: str) -> tuple[dict, list[dict], list[dict]]:
    """(session summary, points, samples) of one pushed session; FleetError if it is not there."""
    with conn.cursor(row_factory=dict_row) as cur:
        meta = cur.execute("SELECT * FROM magrig.fleet_sessions WHERE uid = %s", (uid,)).fetchone()
        if meta is None:
            raise FleetError(f"session {uid}: not in the fleet database")
        points = cur.execute(sql.SQL("SELECT * FROM {} WHERE session_uid = %s").format(
            sql.Identifier(SCHEMA, "points")), (uid,)).fetchall()
        samples = cur.execute(sql.SQL("SELECT * FROM {} WHERE session_uid = %s ORDER BY id").format(
            sql.Identifier(SCHEMA, "samples")), (uid,)).fetchall()
    return meta, points, samples


def session_tables(conn: psycopg.Connection, uid: str, names: tuple[str, ...]) -> dict[str, list[dict]]:
    """{table: rows} of one pushed session's copies of these session tables (a table the database has
    no copy of is left out), each without the `session_uid` column the fleet adds."""
    out = {}
    with conn.cursor(row_factory=dict_row) as cur:
        for name in names:
            found = cur.execute("SELECT to_regclass(%s) AS t", (f"{SCHEMA}.{name}",)).fetchone()
            if found["t"] is None:
                continue
            rows = cur.execute(sql.SQL("SELECT * FROM {} WHERE session_uid = %s").format(
                sql.Identifier(SCHEMA, name)), (uid,)).fetchall()
            out[name] = [{k: v for k, v in r.items() if k != "session_uid"} for r in rows]
    return out


def session_uids(conn: psycopg.Connection, filters: Filters = Filters()) -> list[str]:
    return [row["uid"] for row in list_sessions(conn, filters)]
