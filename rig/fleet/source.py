"""The one place the fleet code reads a session file: a read-only copy of every table.

Tables and columns are introspected, not listed, so a column or table added to the session schema
(events' reason codes, an acceptance results table) is carried to the fleet database without a change
here. When rig.session.writer grows its read-only SessionReader, this is the function to port.
"""

from __future__ import annotations

import hashlib
import sqlite3
from dataclasses import dataclass
from pathlib import Path

from calib.io.digest import sha256_text
from rig.core.errors import SessionError
from rig.session.reader import open_read_only
from rig.session.schema import APPLICATION_ID, SESSION_SUFFIXES, is_session_file

# Suffixes `rig sessions` lists; a file of another name that starts like an SQLite file is taken too.


@dataclass(frozen=True)
class Column:
    name: str
    decl_type: str  # as declared in the SQLite schema ("TEXT", "REAL", "INTEGER", "" ...)
    pk_index: int  # 0 = not part of the primary key, else its position in it


@dataclass
class Table:
    name: str
    columns: list[Column]
    rows: list[tuple]

    @property
    def column_names(self) -> list[str]:
        return [c.name for c in self.columns]

    def dicts(self) -> list[dict]:
        names = self.column_names
        return [dict(zip(names, row, strict=True)) for row in self.rows]


@dataclass
class SessionSnapshot:
    """Every table of one session file, read in one read transaction (a consistent view of a running
    campaign), plus its stable identity and a hash of its content."""

    path: Path
    tables: dict[str, Table]

    @property
    def session(self) -> dict:
        return self.tables["session"].dicts()[0]

    @property
    def uid(self) -> str:
        return session_uid(self.session)

    def content_hash(self) -> str:
        """sha256 of every table's name, columns and rows: equal hashes, equal sessions."""
        digest = hashlib.sha256()
        for name in sorted(self.tables):
            table = self.tables[name]
            digest.update(repr((name, [(c.name, c.decl_type) for c in table.columns])).encode())
            for row in table.rows:
                digest.update(repr(row).encode())
        return digest.hexdigest()


def session_uid(session_row: dict) -> str:
    """The session's stable identity: its recorded `uid` where the schema has one, else derived from
    what a session never changes once created (plan, station, clock and wall-clock start)."""
    if session_row.get("uid"):
        return str(session_row["uid"])
    key = "\x00".join(
        repr(session_row.get(k))
        for k in ("plan_text", "station_name", "station_text", "started", "wall_started")
    )
    return sha256_text(key)[:32]


def session_snapshot(path: str | Path) -> SessionSnapshot:
    """Read every table of the session file at `path`, read-only. SessionError names the file when it
    is missing, not a magrig session, or damaged."""
    path = Path(path)
    if not path.is_file():
        raise SessionError(f"{path}: no such session file")
    if not is_session_file(path):
        raise SessionError(f"{path}: not a session file (not an SQLite database)")
    try:
        conn, private_copy = open_read_only(path)  # never writes beside the session, even for a live WAL
    except sqlite3.Error as exc:
        raise SessionError(f"{path}: cannot open: {exc}") from None
    try:
        conn.execute("BEGIN")  # one read transaction: all tables from the same moment
        if conn.execute("PRAGMA application_id").fetchone()[0] != APPLICATION_ID:
            raise SessionError(f"{path}: not a magrig session file")
        names = [r[0] for r in conn.execute(
            "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%' ORDER BY name")]
        tables = {name: _read_table(conn, name) for name in names}
        conn.execute("COMMIT")
    except sqlite3.DatabaseError as exc:
        raise SessionError(f"{path}: damaged session file: {exc}") from None
    finally:
        conn.close()
        if private_copy is not None:
            private_copy.cleanup()
    if "session" not in tables or len(tables["session"].rows) != 1:
        raise SessionError(f"{path}: damaged session file (no session record)")
    for needed in ("points", "samples"):
        if needed not in tables:
            raise SessionError(f"{path}: damaged session file (no {needed} table)")
    return SessionSnapshot(path, tables)


def _read_table(conn: sqlite3.Connection, name: str) -> Table:
    quoted = '"' + name.replace('"', '""') + '"'
    columns = [Column(r[1], r[2] or "", r[5]) for r in conn.execute(f"PRAGMA table_info({quoted})")]
    order = ", ".join(f'"{c.name}"' for c in sorted(columns, key=lambda c: c.pk_index) if c.pk_index)
    query = f"SELECT * FROM {quoted}" + (f" ORDER BY {order}" if order else "")
    rows = [tuple(r) for r in conn.execute(query)]
    return Table(name, columns, rows)


def session_files(folder: Path) -> list[Path]:
    """The session files of a folder, sorted by name: by suffix, or by content for other names."""
    return sorted(
        p for p in folder.iterdir()
        if p.is_file() and (p.suffix.lower() in SESSION_SUFFIXES or is_session_file(p))
    )
