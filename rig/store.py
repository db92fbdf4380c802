"""The session store: one SQLite file per campaign (WAL journal, foreign keys on).

Write side (the engine):
    s = Session.create_for(path, campaign, compile_plan(plan, station), operator=..., clock=clock)
        (or Session.create(path, plan_text=..., station_text=..., plan_name=..., station_name=...,
                           points=..., simulated={"chamber": True, ...}, ...))
    s = Session.open(path)                       # resume: checks the file and its schema version
    s.done_point_ids() -> set[str]
    s.record_point(point_id, rows: list[SampleRow], settle_stats: dict)   # ONE transaction per point
    s.mark_point_failed(point_id, reason)
    s.log_event(kind, message, level=None, device=None, **data)
    s.record_snapshot(device, describe_dict)
    s.record_fit(dut, model, calibration: dict, residual_rms_nt=None)
    s.finish(status, reason)                     # sets ended, exit status, reason, completed flag
    s.close()
A kill -9 leaves each point either complete (all its samples) or absent. The commit of a point is
protected from Ctrl-C: SIGINT arriving during it is held and delivered right after.

Read side (offline, read-only; needs only this module and calib/):
    read_dataset(path, dut=None) -> calib.dataset.Dataset
    summarize(path) -> dict
    session_tables(path) -> dict               (session record, points, events, fits, snapshots)
    sample_rows(path, dut=None) -> list[dict]   (what `rig export` writes)
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import signal
import sqlite3
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivers.clock import Clock, RealClock
from rig import __version__
from rig.errors import SessionError

SCHEMA_VERSION = 1
_LEVELS = {"DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"}
APPLICATION_ID = 0x4D475247  # "MGRG": marks the file as a magrig session

SCHEMA = """
CREATE TABLE session (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    plan_name TEXT NOT NULL, station_name TEXT NOT NULL,
    plan_text TEXT NOT NULL, station_text TEXT NOT NULL,
    plan_path TEXT, station_path TEXT,
    software_version TEXT NOT NULL, operator TEXT,
    simulated_json TEXT NOT NULL,          -- {device name: true if simulated}
    started REAL NOT NULL, ended REAL,     -- on the run's clock (simulated time in a simulation)
    wall_started REAL NOT NULL, wall_ended REAL,  -- wall-clock time, always
    exit_status TEXT, exit_reason TEXT,    -- e.g. completed / aborted / interrupted / failed
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
    message TEXT NOT NULL, data_json TEXT NOT NULL DEFAULT '{}'
);
CREATE TABLE fits (
    id INTEGER PRIMARY KEY, t REAL NOT NULL, dut TEXT NOT NULL, model TEXT NOT NULL,
    calibration_json TEXT NOT NULL, residual_rms_nt REAL
);
"""


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


SQLITE_MAGIC = b"SQLite format 3\x00"


def is_session_file(path: str | Path) -> bool:
    """True when the file starts as an SQLite database (what a session file is); False if unreadable."""
    try:
        with open(path, "rb") as f:
            return f.read(len(SQLITE_MAGIC)) == SQLITE_MAGIC
    except OSError:
        return False


def _connect(path: Path, read_only: bool) -> sqlite3.Connection:
    if read_only:
        uri = f"file:{path.resolve().as_posix()}?mode=ro"
        conn = sqlite3.connect(uri, uri=True, isolation_level=None)
    else:
        conn = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False)
    conn.row_factory = sqlite3.Row
    conn.execute("PRAGMA foreign_keys = ON")
    return conn


def _verify(conn: sqlite3.Connection, path: Path) -> None:
    """Raise SessionError unless `conn` is an intact magrig session of our schema version."""
    try:
        app_id = conn.execute("PRAGMA application_id").fetchone()[0]
        version = conn.execute("PRAGMA user_version").fetchone()[0]
        if app_id != APPLICATION_ID:
            raise SessionError(f"{path}: not a magrig session file")
        if version != SCHEMA_VERSION:
            raise SessionError(f"{path}: session schema version {version}, "
                               f"this software reads version {SCHEMA_VERSION}")
        if conn.execute("SELECT count(*) FROM session").fetchone()[0] != 1:
            raise SessionError(f"{path}: damaged session file (no session record)")
    except sqlite3.DatabaseError as exc:
        raise SessionError(f"{path}: not a session file or damaged: {exc}") from None


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
        (objects with id, index, temp_index, setpoint_c, field_index and target, e.g. rig.plan.Point)."""
        path = Path(path)
        if path.exists():
            raise SessionError(f"{path}: already exists; resume it or choose another name")
        path.parent.mkdir(parents=True, exist_ok=True)
        clock = clock or RealClock()
        conn = _connect(path, read_only=False)
        try:
            mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if mode.lower() != "wal":
                raise SessionError(f"{path}: the file system does not support a WAL journal")
            conn.execute("PRAGMA synchronous = FULL")
            conn.execute("BEGIN IMMEDIATE")
            for statement in SCHEMA.split(";"):
                if statement.strip():
                    conn.execute(statement)
            conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            conn.execute(
                "INSERT INTO session (id, plan_name, station_name, plan_text, station_text, plan_path, "
                "station_path, software_version, operator, simulated_json, started, wall_started) "
                "VALUES (1, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (plan_name, station_name, plan_text, station_text, plan_path and str(plan_path),
                 station_path and str(station_path), software_version, operator, json.dumps(simulated),
                 clock.now(), time.time()),
            )
            conn.executemany(
                "INSERT INTO points (id, idx, temp_index, setpoint_c, field_index, target_json) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                [(p.id, p.index, p.temp_index, p.setpoint_c, p.field_index, json.dumps(p.target))
                 for p in points],
            )
            conn.execute("COMMIT")
        except BaseException:
            conn.close()
            for leftover in (path, Path(f"{path}-wal"), Path(f"{path}-shm")):
                leftover.unlink(missing_ok=True)
            raise
        return cls(conn, path, clock)

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
        """Reopen an existing session to resume it."""
        path = Path(path)
        if not path.is_file():
            raise SessionError(f"{path}: no such session file")
        conn = _connect(path, read_only=False)
        try:
            _verify(conn, path)
            conn.execute("PRAGMA journal_mode = WAL")
            conn.execute("PRAGMA synchronous = FULL")
        except BaseException:
            conn.close()
            raise
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
        """BEGIN IMMEDIATE .. COMMIT, rolled back on any exception; Ctrl-C is held meanwhile."""
        with self._lock, _sigint_deferred():
            self._conn.execute("BEGIN IMMEDIATE")
            try:
                yield self._conn
            except BaseException:
                self._conn.execute("ROLLBACK")
                raise
            self._conn.execute("COMMIT")

    def record_point(self, point_id: str, rows: Iterable[SampleRow], settle_stats: dict | None = None, *,
                     started: float | None = None, finished: float | None = None) -> None:
        """Mark the point done and store all its samples, atomically."""
        finished = self.clock.now() if finished is None else finished
        with self._transaction() as conn:
            state = conn.execute("SELECT state FROM points WHERE id = ?", (point_id,)).fetchone()
            if state is None:
                raise SessionError(f"{self.path}: point {point_id} is not in the plan")
            if state[0] == "done":
                raise SessionError(f"{self.path}: point {point_id} is already recorded")
            conn.executemany(_INSERT_SAMPLE, (row.as_params(point_id) for row in rows))
            conn.execute(
                "UPDATE points SET state = 'done', settle_json = ?, started = ?, finished = ?, reason = NULL "
                "WHERE id = ?",
                (json.dumps(settle_stats or {}, default=float), started, finished, point_id),
            )

    def mark_point_failed(self, point_id: str, reason: str) -> None:
        with self._transaction() as conn:
            conn.execute("UPDATE points SET state = 'failed', reason = ?, finished = ? WHERE id = ? "
                         "AND state != 'done'", (reason, self.clock.now(), point_id))

    def log_event(self, kind: str, message: str, *, level: str | None = None, device: str | None = None,
                  t: float | None = None, **data) -> None:
        """An event (hold, resume, retry, fault...). `level` defaults to `kind` when that is a logging
        level name ("warning"), else INFO. Extra keyword data is stored as JSON."""
        if level is None:
            level = kind.upper() if kind.upper() in _LEVELS else "INFO"
        with self._transaction() as conn:
            conn.execute(
                "INSERT INTO events (t, level, device, kind, message, data_json) VALUES (?, ?, ?, ?, ?, ?)",
                (self.clock.now() if t is None else t, level.upper(), device, kind, message,
                 json.dumps(data, default=_json_default)),
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

    def finish(self, status: str, reason: str = "", completed: bool | None = None) -> None:
        """Record how the run ended. `completed` defaults to: every planned point is done."""
        with self._transaction() as conn:
            if completed is None:
                left = conn.execute("SELECT count(*) FROM points WHERE state != 'done'").fetchone()[0]
                completed = left == 0
            conn.execute(
                "UPDATE session SET ended = ?, wall_ended = ?, exit_status = ?, exit_reason = ?, "
                "completed = ?",
                (self.clock.now(), time.time(), status, reason, int(completed)),
            )


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


# --- read side ---------------------------------------------------------------------------------------------
@contextlib.contextmanager
def _read_only(path: str | Path) -> Iterator[sqlite3.Connection]:
    path = Path(path)
    if not path.is_file():
        raise SessionError(f"{path}: no such session file")
    try:
        conn = _connect(path, read_only=True)
    except sqlite3.Error as exc:
        raise SessionError(f"{path}: cannot open: {exc}") from None
    try:
        _verify(conn, path)
        yield conn
    except sqlite3.DatabaseError as exc:
        raise SessionError(f"{path}: damaged session file: {exc}") from None
    finally:
        conn.close()


def session_tables(path: str | Path) -> dict[str, list[dict] | dict]:
    """The raw tables except samples, read-only: {"session": {...}, "points": [...], "events": [...],
    "fits": [...], "snapshots": [...]}, each row a dict of the columns in SCHEMA."""
    path = Path(path)
    with _read_only(path) as conn:
        out: dict[str, list[dict] | dict] = {
            "session": dict(conn.execute("SELECT * FROM session").fetchone())
        }
        for table, order in (("points", "idx"), ("events", "id"), ("fits", "id"), ("snapshots", "id")):
            out[table] = [dict(r) for r in conn.execute(f"SELECT * FROM {table} ORDER BY {order}")]
    return out


def _pick_dut(conn: sqlite3.Connection, path: Path, dut: str | None) -> str:
    duts = [r[0] for r in conn.execute("SELECT DISTINCT dut FROM samples ORDER BY dut")]
    if not duts:
        raise SessionError(f"{path}: the session holds no samples yet")
    if dut is None:
        if len(duts) > 1:
            raise SessionError(f"{path}: several DUTs ({', '.join(duts)}): choose one with --dut")
        return duts[0]
    if dut not in duts:
        raise SessionError(f"{path}: no DUT named {dut!r} (DUTs: {', '.join(duts)})")
    return dut


# The CSV contract of calib.csvio (hx,hy,hz raw nT; temp degC; bx,by,bz reference nT; group) plus context.
EXPORT_COLUMNS = ["point", "group", "t", "hx", "hy", "hz", "temp", "bx", "by", "bz", "setpoint_c",
                  "dut_temp", "ref_temp", "ox", "oy", "oz", "flags"]


def sample_rows(path: str | Path, dut: str | None = None) -> tuple[str, list[dict]]:
    """(dut, rows) of the done points of one DUT in collection order, keyed by EXPORT_COLUMNS.

    `temp` is the DUT's own temperature, or the reference sensor's where that is missing (`dut_temp`
    and `ref_temp` keep both); `group` labels the temperature step, e.g. "T03 25.0C"."""
    path = Path(path)
    with _read_only(path) as conn:
        dut = _pick_dut(conn, path, dut)
        cur = conn.execute(
            "SELECT s.point_id AS point, p.temp_index, s.t, s.hx, s.hy, s.hz, "
            "coalesce(s.temp_c, s.ref_temp_c) AS temp, s.bx, s.by, s.bz, p.setpoint_c, "
            "s.temp_c AS dut_temp, s.ref_temp_c AS ref_temp, s.ox, s.oy, s.oz, s.flags "
            "FROM samples s JOIN points p ON p.id = s.point_id "
            "WHERE s.dut = ? AND p.state = 'done' ORDER BY p.idx, s.id",
            (dut,),
        )
        rows = [dict(r) for r in cur]
    for r in rows:
        r["group"] = f"T{r['temp_index']:02d} {r['setpoint_c']:.1f}C"
    return dut, rows


def read_dataset(path: str | Path, dut: str | None = None):
    """The samples of one DUT as a calib Dataset (rows as in `sample_rows`). Flagged samples are left
    out and counted in source["rows_rejected"]."""
    from calib.dataset import Dataset

    path = Path(path)
    dut, rows = sample_rows(path, dut)
    good = [r for r in rows if not r["flags"]]
    missing_temp = [r["point"] for r in good if r["temp"] is None]
    if missing_temp:
        raise SessionError(f"{path}: DUT {dut}: point {missing_temp[0]} has samples without a temperature")

    def col(name: str, dtype=float) -> np.ndarray:
        return np.array([r[name] for r in good], dtype=dtype)

    return Dataset(
        h_nt=np.column_stack([col("hx"), col("hy"), col("hz")]) if good else np.zeros((0, 3)),
        temp_c=col("temp"),
        ref_nt=np.column_stack([col("bx"), col("by"), col("bz")]) if good else np.zeros((0, 3)),
        group=col("group", object),
        columns={"point": col("point", object), "t": col("t"), "setpoint_c": col("setpoint_c")},
        source={
            "path": str(path), "sha256": _sha256(path), "kind": "session", "dut": dut,
            "rows_total": len(rows), "rows_used": len(good), "rows_rejected": len(rows) - len(good),
        },
    )


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def summarize(path: str | Path) -> dict:
    """One session at a glance (for `rig sessions`)."""
    path = Path(path)
    with _read_only(path) as conn:
        s = conn.execute("SELECT * FROM session").fetchone()
        counts = dict(conn.execute("SELECT state, count(*) FROM points GROUP BY state").fetchall())
        duts = [r[0] for r in conn.execute("SELECT DISTINCT dut FROM samples ORDER BY dut")]
        fit = conn.execute(
            "SELECT dut, model, residual_rms_nt, t FROM fits ORDER BY id DESC LIMIT 1"
        ).fetchone()
    return {
        "path": str(path),
        "plan": s["plan_name"],
        "station": s["station_name"],
        "started": s["started"],
        "ended": s["ended"],
        "wall_started": s["wall_started"],
        "wall_ended": s["wall_ended"],
        "operator": s["operator"],
        "simulated": json.loads(s["simulated_json"]),
        "duts": duts,
        "points_done": counts.get("done", 0),
        "points_failed": counts.get("failed", 0),
        "points_planned": sum(counts.values()),
        "exit_status": s["exit_status"],
        "exit_reason": s["exit_reason"],
        "completed": bool(s["completed"]),
        "last_fit": None if fit is None else dict(fit),
    }
