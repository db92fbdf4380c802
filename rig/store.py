"""The session store, write side: one SQLite file per campaign (WAL journal, foreign keys on).

    s = Session.create_for(path, campaign, compile_plan(plan, station), operator=..., clock=clock)
        (or Session.create(path, plan_text=..., station_text=..., plan_name=..., station_name=...,
                           points=..., simulated={"chamber": True, ...}, ...))
    s = Session.open(path)                       # resume: checks the file, migrates an older schema
    s.done_point_ids() -> set[str]
    s.record_point(point_id, rows: list[SampleRow], settle_stats: dict)   # ONE transaction per point
    s.record_point(..., decision=Decision(data, points))   # a sequential schedule's next sweep, too
    s.decisions() -> list[dict]
    s.mark_point_failed(point_id, reason)
    s.log_event(kind, message, code=Reason.X, point_id=None, device=None, level=None, **data)
    s.record_snapshot(device, describe_dict)
    s.record_fit(dut, model, calibration: dict, residual_rms_nt=None)
    s.record_temperatures([TemperatureRow(t, setpoint_c, closed_loop_c, air_c, {dut: temp_c})])  # the cockpit
    s.finish(status, reason, code=Reason.X)      # ended, exit status, reason and code, completed flag
    s.close()

A session file appears whole or not at all: it is built under a temporary name beside it and renamed.
A kill -9 leaves each point either complete (all its samples) or absent. The commit of a point is
protected from Ctrl-C: SIGINT arriving during it is held and delivered right after. A write that fails
(full disk, read-only folder) raises SessionError naming the file; the transaction leaves nothing.

The read side (report, sessions, export, refit) is rig.reader.SessionReader; the run lock rig.lock.
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import signal
import sqlite3
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.digest import sha256_text
from drivers.clock import Clock, RealClock
from rig import __version__
from rig.errors import SessionError
from rig.events import Kind, Reason, legacy_event
from rig.sessionfile import (
    APPLICATION_ID,
    DECISIONS_TABLE,
    MIGRATE_V1,
    SCHEMA,
    SCHEMA_VERSION,
    check_file,
    pid_alive,
    read_decisions,
    verify,
)

_LEVELS = {"DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"}


@dataclass(frozen=True)
class SampleRow:
    """One recorded reading with the reference it is fitted against."""

    dut: str
    t: float
    field_nt: tuple[float, float, float]
    ref_field_nt: tuple[float, float, float]
    temp_c: float | None = None
    ref_temp_c: float | None = None
    counts: tuple[int, int, int] | None = None
    offset_nt: tuple[float, float, float] | None = None
    flags: frozenset[str] = field(default_factory=frozenset)

    @classmethod
    def from_field_sample(cls, dut: str, sample, ref_field_nt, *, temp_c: float | None = None,
                          ref_temp_c: float | None = None) -> SampleRow:
        """From a drivers.base.FieldSample; `temp_c` overrides the chip's own temperature."""
        return cls(
            dut=dut, t=sample.t, field_nt=tuple(map(float, sample.field_nt)),
            ref_field_nt=tuple(map(float, ref_field_nt)),
            temp_c=sample.temp_c if temp_c is None else temp_c, ref_temp_c=ref_temp_c,
            counts=None if sample.counts is None else tuple(map(int, sample.counts)),
            offset_nt=None if sample.offset_nt is None else tuple(map(float, sample.offset_nt)),
            flags=frozenset(sample.flags),
        )

    def as_params(self, point_id: str) -> tuple:
        """Values for _INSERT_SAMPLE, as plain Python numbers (numpy scalars in, SQLite types out)."""
        c = (None,) * 3 if self.counts is None else tuple(int(x) for x in self.counts)
        o = (None,) * 3 if self.offset_nt is None else tuple(float(x) for x in self.offset_nt)
        return (point_id, self.dut, float(self.t), *map(float, self.field_nt), *c, *o,
                _opt_float(self.temp_c), _opt_float(self.ref_temp_c), *map(float, self.ref_field_nt),
                ",".join(sorted(self.flags)))


def _opt_float(value) -> float | None:
    return None if value is None else float(value)


@dataclass(frozen=True)
class TemperatureRow:
    """One line of the cockpit's temperature plot (rig/telemetry.py): the chamber's set point (and its
    instantaneous one during a ramp), its air and each DUT's temperature."""

    t: float
    setpoint_c: float | None
    closed_loop_c: float | None
    air_c: float | None
    duts_c: dict[str, float | None]

    def as_params(self) -> tuple:
        return (float(self.t), _opt_float(self.setpoint_c), _opt_float(self.closed_loop_c),
                _opt_float(self.air_c), json.dumps({k: _opt_float(v) for k, v in self.duts_c.items()}))


TEMPERATURES_TABLE = ("CREATE TABLE IF NOT EXISTS temperatures (id INTEGER PRIMARY KEY, "
                      "t REAL NOT NULL, setpoint_c REAL, closed_loop_c REAL, air_c REAL, "
                      "duts_json TEXT NOT NULL DEFAULT '{}')")

_INSERT_SAMPLE = (
    "INSERT INTO samples (point_id, dut, t, hx, hy, hz, cx, cy, cz, ox, oy, oz, temp_c, ref_temp_c, "
    "bx, by, bz, flags) VALUES (" + ",".join("?" * 18) + ")"
)


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[None]:
    """Hold Ctrl-C while the block runs (main thread only) and deliver it afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[tuple] = []
    previous = signal.signal(signal.SIGINT, lambda *args: caught.append(args))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        if callable(previous):
            previous(*caught[0])
        elif previous != signal.SIG_IGN:
            raise KeyboardInterrupt


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


def _os_message(exc: BaseException) -> str:
    return getattr(exc, "strerror", None) or str(exc)


class Session:
    """An open session file for writing. Thread-safe (a lock around every write)."""

    def __init__(self, conn: sqlite3.Connection, path: Path, clock: Clock):
        self._conn = conn
        self.path = path
        self.clock = clock
        self._lock = threading.RLock()

    # --- create / open --------------------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path, *, plan_text: str, station_text: str, plan_name: str,
               station_name: str, points: Iterable, simulated: dict[str, bool],
               plan_path: str | None = None, station_path: str | None = None, operator: str | None = None,
               software_version: str = __version__, clock: Clock | None = None) -> Session:
        """A new session file (it must not exist) holding the plan, the station and every planned point
        (objects with id, index, temp_index, setpoint_c, field_index and target, e.g. rig.plan.Point).
        Built under a temporary name in the same folder and renamed once complete."""
        path = Path(path)
        if path.exists():
            raise SessionError(f"{path}: already exists; resume it or choose another name")
        clock = clock or RealClock()
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SessionError(f"{path.parent}: cannot create the session folder "
                               f"({_os_message(exc)})") from None
        _remove_dead_builds(path)
        build = _build_name(path)
        record = (plan_name, station_name, plan_text, station_text, sha256_text(plan_text),
                  sha256_text(station_text), plan_path and str(plan_path), station_path and str(station_path),
                  software_version, operator, json.dumps(simulated), clock.now(), time.time())
        try:
            _build(build, record, points)
            _publish(build, path)
        except (sqlite3.Error, OSError) as exc:
            raise SessionError(f"{path}: cannot create the session ({_os_message(exc)})") from None
        finally:
            _remove(build)
        return cls.open(path, clock)

    @classmethod
    def create_for(cls, path: str | Path, campaign, points: Iterable, *, operator: str | None = None,
                   clock: Clock | None = None) -> Session:
        """`create` from a rig.config.Campaign and its compiled points."""
        return cls.create(
            path, plan_text=campaign.plan_text, station_text=campaign.station_text,
            plan_name=campaign.plan.name, station_name=campaign.station.name, points=points,
            simulated=campaign.station.simulated_devices(), plan_path=str(campaign.plan_path),
            station_path=str(campaign.station_path), operator=operator, clock=clock,
        )

    @classmethod
    def open(cls, path: str | Path, clock: Clock | None = None) -> Session:
        """Open an existing session to write to it (resume); a version 1 session is migrated."""
        path = Path(path)
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
        return cls(conn, path, clock or RealClock())

    def close(self) -> None:
        with self._lock:
            self._conn.close()

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- reads used while running ---------------------------------------------------------------------
    def info(self) -> dict:
        row = self._conn.execute("SELECT * FROM session").fetchone()
        out = dict(row)
        out["simulated"] = json.loads(out.pop("simulated_json"))
        return out

    @property
    def plan_text(self) -> str:
        return self.info()["plan_text"]

    @property
    def station_text(self) -> str:
        return self.info()["station_text"]

    @property
    def completed(self) -> bool:
        return bool(self.info()["completed"])

    def planned_point_ids(self) -> list[str]:
        return [r[0] for r in self._conn.execute("SELECT id FROM points ORDER BY idx")]

    def done_point_ids(self) -> set[str]:
        return {r[0] for r in self._conn.execute("SELECT id FROM points WHERE state = 'done'")}

    # --- writes ---------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        """BEGIN IMMEDIATE .. COMMIT, rolled back on any exception; Ctrl-C is held meanwhile. A write the
        file system refuses (full disk, read-only) is a SessionError naming the file."""
        with self._lock, _sigint_deferred():
            try:
                self._conn.execute("BEGIN IMMEDIATE")
                try:
                    yield self._conn
                    self._conn.execute("COMMIT")
                except BaseException:
                    if self._conn.in_transaction:
                        with contextlib.suppress(sqlite3.Error):
                            self._conn.execute("ROLLBACK")
                    raise
            except sqlite3.OperationalError as exc:
                raise SessionError(f"{self.path}: cannot write to the session ({exc})") from None

    def record_point(self, point_id: str, rows: Iterable[SampleRow], settle_stats: dict | None = None, *,
                     started: float | None = None, finished: float | None = None,
                     temperatures: list[TemperatureRow] = (), decision: Decision | None = None) -> None:
        """Mark the point done and store all its samples, atomically (with the temperature rows noted
        since the last write: they ride along instead of taking a transaction of their own); with a
        `decision` (a sequential schedule's next sweep, made from this point's data) in the same
        transaction."""
        finished = self.clock.now() if finished is None else finished
        with self._transaction() as conn:
            if decision is not None:
                _record_decision(conn, point_id, decision, finished)
            state = conn.execute("SELECT state FROM points WHERE id = ?", (point_id,)).fetchone()
            if state is None:
                raise SessionError(f"{self.path}: point {point_id} is not in the plan")
            if state[0] == "done":
                raise SessionError(f"{self.path}: point {point_id} is already recorded")
            conn.executemany(_INSERT_SAMPLE, (row.as_params(point_id) for row in rows))
            _insert_temperatures(conn, temperatures)
            conn.execute(
                "UPDATE points SET state = 'done', settle_json = ?, started = ?, finished = ?, reason = NULL "
                "WHERE id = ?",
                (json.dumps(settle_stats or {}, default=float), started, finished, point_id),
            )

    def decisions(self) -> list[dict]:
        """The recorded decisions of a sequential schedule, in order ([] for any other session)."""
        return read_decisions(self._conn)

    def mark_point_failed(self, point_id: str, reason: str) -> None:
        with self._transaction() as conn:
            conn.execute("UPDATE points SET state = 'failed', reason = ?, finished = ? WHERE id = ? "
                         "AND state != 'done'", (reason, self.clock.now(), point_id))

    def log_event(self, kind: str, message: str, *, code: Reason | None = None, point_id: str | None = None,
                  level: str | None = None, device: str | None = None, t: float | None = None,
                  **data) -> None:
        """An event: its kind (rig.events.Kind), its reason code (rig.events.Reason), the point and the
        device it concerns and a message for people. `level` defaults to `kind` when that is a logging
        level name ("warning"), else INFO. Extra keyword data is stored as JSON."""
        kind = str(kind)
        if level is None:
            level = kind.upper() if kind.upper() in _LEVELS else "INFO"
        if code is None:
            code = Reason.LOGGED if kind in (Kind.WARNING, Kind.ERROR) else Reason.UNKNOWN
        with self._transaction() as conn:
            conn.execute(
                "INSERT INTO events (t, level, device, kind, message, data_json, point_id, code) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (self.clock.now() if t is None else t, level.upper(), device, kind, message,
                 json.dumps(data, default=_json_default), point_id, Reason(code).value),
            )

    def record_snapshot(self, device: str, describe: dict) -> None:
        with self._transaction() as conn:
            conn.execute("INSERT INTO snapshots (t, device, describe_json) VALUES (?, ?, ?)",
                         (self.clock.now(), device, json.dumps(describe, default=str)))

    def record_fit(self, dut: str, model: str, calibration: dict,
                   residual_rms_nt: float | None = None) -> None:
        calibration_json = json.dumps(calibration, default=_json_default)
        with self._transaction() as conn:
            conn.execute(
                "INSERT INTO fits (t, dut, model, calibration_json, residual_rms_nt) VALUES (?, ?, ?, ?, ?)",
                (self.clock.now(), dut, model, calibration_json, residual_rms_nt),
            )

    def record_acceptance(self, rows: list[dict]) -> None:
        """The per-DUT verdicts (rig/acceptance.py) in table `acceptance`, made when first needed."""
        with self._transaction() as conn:
            conn.execute("CREATE TABLE IF NOT EXISTS acceptance (t REAL, dut TEXT, model TEXT, "
                         "passed INTEGER, verdict TEXT, failed TEXT, heldout_rms_nt REAL, fit_rms_nt REAL, "
                         "lag_s REAL, notes TEXT)")
            conn.execute("DELETE FROM acceptance")  # a resumed run judges again: the last verdict stands
            conn.executemany(
                "INSERT INTO acceptance (t, dut, model, passed, verdict, failed, heldout_rms_nt, fit_rms_nt, "
                "lag_s, notes) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(self.clock.now(), r["dut"], r["model"], r["passed"], r["verdict"], r["failed"],
                  r["heldout_rms_nt"], r["fit_rms_nt"], r["lag_s"], r["notes"]) for r in rows])

    def record_temperatures(self, rows: list[TemperatureRow]) -> None:
        """Rows of table `temperatures` (made when first needed), for the cockpit's plot."""
        with self._transaction() as conn:
            _insert_temperatures(conn, rows)

    def finish(self, status: str, reason: str = "", completed: bool | None = None,
               code: Reason | None = None) -> None:
        """Record how the run ended. `completed` defaults to: every planned point is done. On a full disk
        the write-ahead log is folded into the file first (freeing the log's space) and it is tried once
        more: how a run ended is the one record that must not be lost."""
        try:
            self._finish(status, reason, completed, code)
        except SessionError:
            with self._lock, contextlib.suppress(sqlite3.Error):
                self._conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            self._finish(status, reason, completed, code)

    def _finish(self, status: str, reason: str, completed: bool | None, code: Reason | None) -> None:
        with self._transaction() as conn:
            if completed is None:
                left = conn.execute("SELECT count(*) FROM points WHERE state != 'done'").fetchone()[0]
                completed = left == 0
            conn.execute(
                "UPDATE session SET ended = ?, wall_ended = ?, exit_status = ?, exit_reason = ?, "
                "exit_code = ?, completed = ?",
                (self.clock.now(), time.time(), status, reason, code and Reason(code).value, int(completed)),
            )


def _insert_temperatures(conn: sqlite3.Connection, rows: list[TemperatureRow]) -> None:
    if rows:
        conn.execute(TEMPERATURES_TABLE)
        conn.executemany("INSERT INTO temperatures (t, setpoint_c, closed_loop_c, air_c, duts_json) "
                         "VALUES (?, ?, ?, ?, ?)", [r.as_params() for r in rows])


@dataclass(frozen=True)
class Decision:
    """What a sequential schedule decided after a point: its data (JSON-ready) and the points it adds
    (objects with id, index, temp_index, setpoint_c, field_index and target, like rig.points.Point)."""

    data: dict
    points: tuple = ()


def _insert_points(conn: sqlite3.Connection, points: Iterable) -> None:
    conn.executemany(
        "INSERT INTO points (id, idx, temp_index, setpoint_c, field_index, target_json) "
        "VALUES (?, ?, ?, ?, ?, ?)",
        ((p.id, p.index, p.temp_index, p.setpoint_c, p.field_index, json.dumps(p.target)) for p in points),
    )


def _record_decision(conn: sqlite3.Connection, point_id: str, decision: Decision, t: float) -> None:
    """The decision and its points, inside the caller's transaction (the table is made when first needed)."""
    conn.execute(DECISIONS_TABLE)
    conn.execute("INSERT INTO decisions (t, after_point, decision_json) VALUES (?, ?, ?)",
                 (t, point_id, json.dumps(decision.data, default=_json_default)))
    _insert_points(conn, decision.points)


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
        _insert_points(conn, points)
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


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


