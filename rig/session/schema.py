"""A session file as such: its schema, how to tell one from other files, and the checks every opening
(read or write) makes before trusting it."""

from __future__ import annotations

import json
import os
import sqlite3
import struct
import sys
from pathlib import Path

from rig.core.errors import SessionError

SCHEMA_VERSION = 2  # 2: typed events (point_id, code), recorded text hashes, exit code
READABLE_VERSIONS = (1, 2)
APPLICATION_ID = 0x4D475247  # "MGRG": marks the file as a magrig session
SESSION_SUFFIXES = (".session", ".sqlite", ".sqlite3", ".db")

# made by the first decision of a sequential schedule (rig/schedules/sequential_run.py): one row per decided
# sweep or stop
DECISIONS_TABLE = ("CREATE TABLE IF NOT EXISTS decisions (seq INTEGER PRIMARY KEY, t REAL, after_point TEXT, "
                   "decision_json TEXT)")


def read_decisions(conn: sqlite3.Connection) -> list[dict]:
    """Every recorded decision in order, `after_point` included; [] when the session has none."""
    found = conn.execute("SELECT name FROM sqlite_master WHERE type = 'table' AND name = 'decisions'"
                         ).fetchone()
    if found is None:
        return []
    rows = conn.execute("SELECT after_point, decision_json FROM decisions ORDER BY seq").fetchall()
    return [{**json.loads(r[1]), "after_point": r[0]} for r in rows]


SCHEMA = """
CREATE TABLE session (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    plan_name TEXT NOT NULL, station_name TEXT NOT NULL,
    plan_text TEXT NOT NULL, station_text TEXT NOT NULL,
    plan_sha256 TEXT, station_sha256 TEXT, -- of the texts as recorded: a resume checks them
    plan_path TEXT, station_path TEXT,
    software_version TEXT NOT NULL, operator TEXT,
    simulated_json TEXT NOT NULL,          -- {device name: true if simulated}
    started REAL NOT NULL, ended REAL,     -- on the run's clock (simulated time in a simulation)
    wall_started REAL NOT NULL, wall_ended REAL,  -- wall-clock time, always
    exit_status TEXT, exit_reason TEXT,    -- e.g. completed / aborted / interrupted / failed
    exit_code TEXT,                        -- rig.session.events.Reason value of why the run ended
    completed INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE points (
    id TEXT PRIMARY KEY,                   -- T03-F07
    idx INTEGER NOT NULL UNIQUE,
    temp_index INTEGER NOT NULL, setpoint_c REAL NOT NULL,
    field_index INTEGER NOT NULL, target_json TEXT NOT NULL,
    state TEXT NOT NULL DEFAULT 'planned' CHECK (state IN ('planned', 'done', 'failed')),
    settle_json TEXT, reason TEXT,
    started REAL, finished REAL
);
CREATE TABLE samples (
    id INTEGER PRIMARY KEY,
    point_id TEXT NOT NULL REFERENCES points(id),
    dut TEXT NOT NULL, t REAL NOT NULL,
    hx REAL NOT NULL, hy REAL NOT NULL, hz REAL NOT NULL,      -- raw reading, nT
    cx INTEGER, cy INTEGER, cz INTEGER,                       -- raw counts
    ox REAL, oy REAL, oz REAL,                                -- SET/RESET bridge offset, nT
    temp_c REAL, ref_temp_c REAL,                             -- DUT temperature, reference sensor
    bx REAL NOT NULL, by REAL NOT NULL, bz REAL NOT NULL,     -- reference field, nT
    flags TEXT NOT NULL DEFAULT ''                            -- comma-separated, flagged rows are not fitted
);
CREATE INDEX samples_by_dut ON samples(dut, point_id);
CREATE TABLE snapshots (
    id INTEGER PRIMARY KEY, t REAL NOT NULL, device TEXT NOT NULL, describe_json TEXT NOT NULL
);
CREATE TABLE events (
    id INTEGER PRIMARY KEY, t REAL NOT NULL, level TEXT NOT NULL, device TEXT, kind TEXT NOT NULL,
    message TEXT NOT NULL, data_json TEXT NOT NULL DEFAULT '{}',
    point_id TEXT,                         -- the point it concerns, if any
    code TEXT NOT NULL DEFAULT 'unknown'   -- rig.session.events.Reason value
);
CREATE TABLE fits (
    id INTEGER PRIMARY KEY, t REAL NOT NULL, dut TEXT NOT NULL, model TEXT NOT NULL,
    calibration_json TEXT NOT NULL, residual_rms_nt REAL
);
"""

MIGRATE_V1 = """
ALTER TABLE session ADD COLUMN plan_sha256 TEXT;
ALTER TABLE session ADD COLUMN station_sha256 TEXT;
ALTER TABLE session ADD COLUMN exit_code TEXT;
ALTER TABLE events ADD COLUMN point_id TEXT;
ALTER TABLE events ADD COLUMN code TEXT NOT NULL DEFAULT 'unknown'
"""


# --- the file itself -------------------------------------------------------------------------------
SQLITE_MAGIC = b"SQLite format 3\x00"


def is_session_file(path: str | Path) -> bool:
    """True when the file starts as an SQLite database (what a session file is); False if unreadable."""
    try:
        with open(path, "rb") as f:
            return f.read(len(SQLITE_MAGIC)) == SQLITE_MAGIC
    except OSError:
        return False


def looks_like_session(path: str | Path) -> bool:
    """A session by its name or by its content: such a file is read as a session or refused, never
    taken for a CSV or a calibration file."""
    return Path(path).suffix.lower() in SESSION_SUFFIXES or is_session_file(path)


def check_file(path: Path) -> None:
    """Refuse, in one line naming the file, what is missing, not SQLite, or cut short."""
    try:
        with open(path, "rb") as f:
            header = f.read(100)
            size = os.fstat(f.fileno()).st_size
    except FileNotFoundError:
        raise SessionError(f"{path}: no such session file") from None
    except IsADirectoryError:
        raise SessionError(f"{path}: is a folder, not a session file") from None
    except OSError as exc:
        raise SessionError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(header) < 100 or not header.startswith(SQLITE_MAGIC):
        raise SessionError(f"{path}: not a session file or damaged (not an SQLite database)")
    page_size = struct.unpack(">H", header[16:18])[0]
    page_size = 65536 if page_size == 1 else page_size
    pages, change_counter, valid_for = (struct.unpack(">I", header[i:i + 4])[0] for i in (28, 24, 92))
    if page_size < 512 or page_size & (page_size - 1):
        raise SessionError(f"{path}: not a session file or damaged (bad page size {page_size})")
    wal = Path(f"{path}-wal")
    pending_log = wal.exists() and wal.stat().st_size > 0  # a log being checkpointed may extend the file
    cut = pages and change_counter == valid_for and size < pages * page_size
    if size % page_size or (cut and not pending_log):
        raise SessionError(f"{path}: damaged session file: truncated ({size} bytes; its header records "
                           f"{pages} pages of {page_size} bytes)")


def verify(conn: sqlite3.Connection, path: Path) -> int:
    """The schema version of an intact magrig session; SessionError otherwise."""
    try:
        app_id = conn.execute("PRAGMA application_id").fetchone()[0]
        version = conn.execute("PRAGMA user_version").fetchone()[0]
        if app_id != APPLICATION_ID:
            raise SessionError(f"{path}: not a magrig session file")
        if version not in READABLE_VERSIONS:
            raise SessionError(f"{path}: session schema version {version}, "
                               f"this software reads versions {READABLE_VERSIONS[0]} to {SCHEMA_VERSION}")
        if conn.execute("SELECT count(*) FROM session").fetchone()[0] != 1:
            raise SessionError(f"{path}: damaged session file (no session record)")
    except sqlite3.DatabaseError as exc:
        raise SessionError(f"{path}: not a session file or damaged: {exc}") from None
    return version


def pid_alive(pid: int) -> bool:
    """Whether process `pid` runs. Never os.kill on Windows: there any signal terminates the process."""
    if sys.platform == "win32":
        return _windows_pid_alive(pid)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _windows_pid_alive(pid: int) -> bool:
    import ctypes

    kernel32 = ctypes.WinDLL("kernel32", use_last_error=True)
    handle = kernel32.OpenProcess(0x1000, False, pid)  # PROCESS_QUERY_LIMITED_INFORMATION
    if not handle:
        return ctypes.get_last_error() == 5  # ERROR_ACCESS_DENIED: it exists, it is someone else's
    try:
        code = ctypes.c_ulong()
        if not kernel32.GetExitCodeProcess(handle, ctypes.byref(code)):
            return True
        return code.value == 259  # STILL_ACTIVE
    finally:
        kernel32.CloseHandle(handle)
