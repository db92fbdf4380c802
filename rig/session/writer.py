"""The session writer: one SQLite file per campaign (WAL journal, foreign keys on), written by the run.

    s = Session.create_for(path, campaign, compile_plan(plan, station), operator=..., clock=clock)
        (or Session.create(path, plan_text=..., station_text=..., plan_name=..., station_name=...,
                           points=..., simulated={"chamber": True, ...}, ...))
    s = Session.open(path)                       # resume: checks the file, migrates an older schema
    s.done_point_ids() -> set[str]
    s.record_point(point_id, rows: list[SampleRow], stability_stats: dict)   # ONE transaction per point
    s.record_point(..., decision=Decision(data, points))   # a sequential schedule's next sweep, too
    s.decisions() -> list[dict]
    s.mark_point_failed(point_id, reason)
    s.log_event(kind, message, code=Reason.X, point_id=None, device=None, level=None, **data)
    s.record_snapshot(device, describe_dict)
    s.record_fit(dut, model, calibration: dict, residual_rms_nt=None)
    s.record_temperatures([TemperatureRow(t, setpoint_c, closed_loop_c, air_c, {dut: temp_c})])  # the cockpit
    s.finish(status, reason, code=Reason.X)      # ended, exit status, reason and code, completed flag
    s.subscribe(listener)                        # listener.session_wrote(what, item) after each write
    s.close()

A session file appears whole or not at all: it is built under a temporary name beside it and renamed.
A kill -9 leaves each point either complete (all its samples) or absent. The commit of a point is
protected from Ctrl-C: SIGINT arriving during it is held and delivered right after. A write that fails
(full disk, read-only folder) raises SessionError naming the file; the transaction leaves nothing.

Making and opening the file: rig/session/create.py; the rows and how they are inserted: rig/session/rows.py;
the schema and its migrations: rig/session/schema.py; the read side (report, sessions, export, refit, the
cockpit): rig/session/reader.py SessionReader; the run lock: rig/session/lock.py.
"""

from __future__ import annotations

import contextlib
import json
import logging
import signal
import sqlite3
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

from drivers.clock import Clock, RealClock
from rig import __version__
from rig.core.errors import SessionError
from rig.session.create import create_file, open_for_writing, session_record
from rig.session.events import Event, Kind, Reason
from rig.session.rows import (
    INSERT_SAMPLE,
    Decision,
    SampleRow,
    TemperatureRow,
    insert_temperatures,
    json_default,
    record_decision,
)
from rig.session.schema import read_decisions

_log = logging.getLogger("magrig.session")
_LEVELS = {"DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"}


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


class Session:
    """An open session file for writing. Thread-safe (a lock around every write)."""

    def __init__(self, conn: sqlite3.Connection, path: Path, clock: Clock):
        self._conn = conn
        self.path = path
        self.clock = clock
        self._lock = threading.RLock()
        self._listeners: list = []

    # --- create / open --------------------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path, *, plan_text: str, station_text: str, plan_name: str,
               station_name: str, points: Iterable, simulated: dict[str, bool],
               plan_path: str | None = None, station_path: str | None = None, operator: str | None = None,
               software_version: str = __version__, clock: Clock | None = None) -> Session:
        """A new session file (it must not exist) holding the plan, the station and every planned point
        (objects with id, index, temp_index, setpoint_c, field_index and target, e.g.
        rig.core.points.Point)."""
        path = Path(path)
        clock = clock or RealClock()
        record = session_record(plan_name=plan_name, station_name=station_name, plan_text=plan_text,
                                station_text=station_text, plan_path=plan_path, station_path=station_path,
                                software_version=software_version, operator=operator, simulated=simulated,
                                started=clock.now())
        create_file(path, record, points)
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
        """Open an existing session to write to it (resume); an older schema is migrated."""
        path = Path(path)
        return cls(open_for_writing(path), path, clock or RealClock())

    def close(self) -> None:
        """The write-ahead log folded into the file first, so that the file alone is the whole session (what
        a calibration's source.sha256 hashes: rig/session/reader.py), even while a reader holds it open."""
        with self._lock:
            with contextlib.suppress(sqlite3.Error):
                self._conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            self._conn.close()

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def subscribe(self, listener) -> None:
        """`listener.session_wrote(what, item)` after each committed write, in the writing thread:
        ("event", Event), ("point", point_id), ("temperatures", row count). The one place a run's events
        reach a subscriber (rig/run/notify.py). One that raises is dropped (it would fail every write,
        its own log record's too) and logged: never the writer's problem."""
        self._listeners.append(listener)

    def unsubscribe(self, listener) -> None:
        with contextlib.suppress(ValueError):
            self._listeners.remove(listener)

    def _tell(self, what: str, item) -> None:
        for listener in list(self._listeners):
            try:
                listener.session_wrote(what, item)
            except Exception:
                self.unsubscribe(listener)
                _log.exception("session listener %r failed on %s; dropped", listener, what)

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

    def record_point(self, point_id: str, rows: Iterable[SampleRow], stability_stats: dict | None = None, *,
                     started: float | None = None, finished: float | None = None,
                     temperatures: list[TemperatureRow] = (), decision: Decision | None = None) -> None:
        """Mark the point done and store all its samples, atomically (with the temperature rows noted
        since the last write: they ride along instead of taking a transaction of their own); with a
        `decision` (a sequential schedule's next sweep, made from this point's data) in the same
        transaction."""
        finished = self.clock.now() if finished is None else finished
        with self._transaction() as conn:
            if decision is not None:
                record_decision(conn, point_id, decision, finished)
            state = conn.execute("SELECT state FROM points WHERE id = ?", (point_id,)).fetchone()
            if state is None:
                raise SessionError(f"{self.path}: point {point_id} is not in the plan")
            if state[0] == "done":
                raise SessionError(f"{self.path}: point {point_id} is already recorded")
            conn.executemany(INSERT_SAMPLE, (row.as_params(point_id) for row in rows))
            insert_temperatures(conn, temperatures)
            conn.execute(
                "UPDATE points SET state = 'done', settle_json = ?, started = ?, finished = ?, reason = NULL "
                "WHERE id = ?",
                (json.dumps(stability_stats or {}, default=float), started, finished, point_id),
            )
        self._tell("point", point_id)

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
        """An event: its kind (rig.session.events.Kind), its reason code (rig.session.events.Reason), the
        point and the device it concerns and a message for people. `level` defaults to `kind` when that is a
        logging
        level name ("warning"), else INFO. Extra keyword data is stored as JSON."""
        kind = str(kind)
        if level is None:
            level = kind.upper() if kind.upper() in _LEVELS else "INFO"
        if code is None:
            code = Reason.LOGGED if kind in (Kind.WARNING, Kind.ERROR) else Reason.UNKNOWN
        t = self.clock.now() if t is None else t
        data_json = json.dumps(data, default=json_default)
        with self._transaction() as conn:
            row_id = conn.execute(
                "INSERT INTO events (t, level, device, kind, message, data_json, point_id, code) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (t, level.upper(), device, kind, message, data_json, point_id, Reason(code).value),
            ).lastrowid
        if self._listeners:
            self._tell("event", Event(row_id, t, level.upper(), kind, Reason(code), message, point_id, device,
                                      json.loads(data_json)))

    def record_snapshot(self, device: str, describe: dict) -> None:
        with self._transaction() as conn:
            conn.execute("INSERT INTO snapshots (t, device, describe_json) VALUES (?, ?, ?)",
                         (self.clock.now(), device, json.dumps(describe, default=str)))

    def record_fit(self, dut: str, model: str, calibration: dict,
                   residual_rms_nt: float | None = None) -> None:
        calibration_json = json.dumps(calibration, default=json_default)
        with self._transaction() as conn:
            conn.execute(
                "INSERT INTO fits (t, dut, model, calibration_json, residual_rms_nt) VALUES (?, ?, ?, ?, ?)",
                (self.clock.now(), dut, model, calibration_json, residual_rms_nt),
            )

    def record_acceptance(self, rows: list[dict]) -> None:
        """The per-DUT verdicts (rig/analysis/acceptance.py) in table `acceptance`, made when first needed."""
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
            insert_temperatures(conn, rows)
        self._tell("temperatures", len(rows))

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
