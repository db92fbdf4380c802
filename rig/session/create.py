"""Making and opening a session file: it appears whole or not at all (built under a temporary name beside
it, then given its name, never over an existing file), and an opening checks what it opens and migrates
an older schema (rig/session/schema.py) before anything writes to it."""

from __future__ import annotations

import contextlib
import glob
import json
import os
import sqlite3
import time
from collections.abc import Iterable
from pathlib import Path

from calib.io.digest import sha256_text
from rig.core.errors import SessionError
from rig.session.events import legacy_event
from rig.session.rows import insert_points
from rig.session.schema import (
    APPLICATION_ID,
    MIGRATE_V1,
    SCHEMA,
    SCHEMA_VERSION,
    check_file,
    pid_alive,
    verify,
)


def create_file(path: Path, record: tuple, points: Iterable) -> None:
    """A new session file at `path` (which must not exist) holding the session `record` and its points."""
    if path.exists():
        raise SessionError(f"{path}: already exists; resume it or choose another name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionError(f"{path.parent}: cannot create the session folder ({os_message(exc)})") from None
    _remove_dead_builds(path)
    build = _build_name(path)
    try:
        _build(build, record, points)
        _publish(build, path)
    except (sqlite3.Error, OSError) as exc:
        raise SessionError(f"{path}: cannot create the session ({os_message(exc)})") from None
    finally:
        _remove(build)


def open_for_writing(path: Path) -> sqlite3.Connection:
    """An existing session, checked, in WAL mode, migrated to the current schema, its texts verified."""
    check_file(path)
    try:
        conn = _connect(path)
    except sqlite3.Error as exc:
        raise SessionError(f"{path}: cannot open ({exc})") from None
    try:
        version = verify(conn, path)
        conn.execute("PRAGMA journal_mode = WAL")
        conn.execute("PRAGMA synchronous = FULL")
        if version == 1:
            _migrate_v1(conn)
        _check_recorded_texts(conn, path)
    except sqlite3.Error as exc:
        conn.close()
        raise SessionError(f"{path}: cannot open for writing ({exc})") from None
    except BaseException:
        conn.close()
        raise
    _remove_dead_builds(path)
    return conn


def session_record(*, plan_name, station_name, plan_text, station_text, plan_path, station_path,
                   software_version, operator, simulated, started) -> tuple:
    """The session row's values, in the order _build inserts them."""
    return (plan_name, station_name, plan_text, station_text, sha256_text(plan_text),
            sha256_text(station_text),
            plan_path and str(plan_path), station_path and str(station_path), software_version, operator,
            json.dumps(simulated), started, time.time())


def _connect(path: Path) -> sqlite3.Connection:
    conn = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False)
    conn.row_factory = sqlite3.Row
    conn.execute("PRAGMA foreign_keys = ON")
    return conn


def _build_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.creating")


def _remove(path: Path) -> None:
    for leftover in (path, *(Path(f"{path}{s}") for s in ("-wal", "-shm", "-journal"))):
        with contextlib.suppress(OSError):
            leftover.unlink()


def _remove_dead_builds(path: Path) -> None:
    """What a creation killed half-way left beside `path` (its process is gone)."""
    pattern = os.path.join(glob.escape(str(path.parent)), f".{glob.escape(path.name)}.*.creating")
    for build in glob.glob(pattern):
        pid = Path(build).name.removeprefix(f".{path.name}.").removesuffix(".creating")
        if not pid.isdigit() or not pid_alive(int(pid)):
            _remove(Path(build))


def _fsync_folder(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _publish(build: Path, path: Path) -> None:
    """Give the finished file its name, never over an existing file."""
    try:
        os.link(build, path)
    except FileExistsError:
        raise SessionError(f"{path}: already exists; resume it or choose another name") from None
    except OSError:  # a file system without hard links
        if path.exists():
            raise SessionError(f"{path}: already exists; resume it or choose another name") from None
        os.rename(build, path)
    else:
        os.unlink(build)
    _fsync_folder(path.parent)


def os_message(exc: BaseException) -> str:
    return getattr(exc, "strerror", None) or str(exc)


def _build(build: Path, record: tuple, points: Iterable) -> None:
    """Write a complete new session file at `build` (a temporary name) and close it."""
    _remove(build)
    conn = _connect(build)
    try:
        mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
        if mode.lower() != "wal":
            raise SessionError(f"{build.parent}: the file system does not support a WAL journal")
        conn.execute("PRAGMA synchronous = FULL")
        conn.execute("BEGIN IMMEDIATE")
        for statement in SCHEMA.split(";"):
            if statement.strip():
                conn.execute(statement)
        conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
        conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
        conn.execute(
            "INSERT INTO session (id, plan_name, station_name, plan_text, station_text, plan_sha256, "
            "station_sha256, plan_path, station_path, software_version, operator, simulated_json, started, "
            "wall_started) VALUES (1, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", record)
        insert_points(conn, points)
        conn.execute("COMMIT")
        conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")  # everything in the main file before it is renamed
    finally:
        conn.close()


def _migrate_v1(conn: sqlite3.Connection) -> None:
    """Version 1 to 2 in one transaction: typed event columns filled from the old wording, text hashes."""
    conn.execute("BEGIN IMMEDIATE")
    try:
        for statement in MIGRATE_V1.split(";"):
            conn.execute(statement)
        plan_text, station_text = conn.execute("SELECT plan_text, station_text FROM session").fetchone()
        conn.execute("UPDATE session SET plan_sha256 = ?, station_sha256 = ?",
                     (sha256_text(plan_text), sha256_text(station_text)))
        for row in conn.execute("SELECT * FROM events").fetchall():
            event = legacy_event(dict(row), json.loads(row["data_json"] or "{}"))
            conn.execute("UPDATE events SET code = ?, point_id = ? WHERE id = ?",
                         (event.code.value, event.point_id, event.id))
        conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
        conn.execute("COMMIT")
    except BaseException:
        conn.execute("ROLLBACK")
        raise


def _check_recorded_texts(conn: sqlite3.Connection, path: Path) -> None:
    """The plan and station texts must still be those recorded at the start (their sha256)."""
    row = conn.execute("SELECT plan_text, station_text, plan_sha256, station_sha256 FROM session").fetchone()
    for what, text, digest in (("plan", row[0], row[2]), ("station", row[1], row[3])):
        if digest is not None and sha256_text(text) != digest:
            raise SessionError(f"{path}: the recorded {what} text no longer matches its recorded sha256 "
                               "(the session file was edited); refusing to continue it")
