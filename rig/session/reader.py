"""The one read-only view of a session file: report, `rig sessions`, `rig export`, `rig refit` and the
cockpit (`rig serve`) use it.

    with SessionReader(path) as r:
        r.info(), r.points(), r.events() -> [rig.session.events.Event], r.fits(), r.snapshots(), r.duts()
        r.temperatures(), r.samples_of(point_ids), r.events(after_id)   # the cockpit's live view
        r.sample_rows(dut) -> (dut, rows keyed by EXPORT_COLUMNS)
        r.dataset(dut) -> calib.dataset.Dataset
        r.summary() -> dict (for `rig sessions`)

Reading never writes beside the session (no -wal, -shm or journal file appears) and works in a folder
one cannot write to:
- no write-ahead log content: the main file is complete; open it `immutable` (no locks, no files);
- a log and its shared-memory index (a live run, or a killed one): open `mode=ro`, as one more reader
  beside the writer, using the index that is there;
- a log without its index (a killed run in a folder we cannot write to): read a private copy of the
  file and its log in a temporary folder, where SQLite may rebuild the index.

A calibration cites its session by path and sha256 (`source_sha256`): the hash of the file as it is once
nothing more is written to it. While a log holds part of the session (a run still writing, or one killed
before it closed) the file on disk is not the session, and no hash is given: a run's calibrations are
given the session's hash once it has closed the session (rig/analysis/postrun.py seal_sources), and the
fits the session records of them cite it through `recorded_calibration`.
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import tempfile
import urllib.parse
from pathlib import Path

import numpy as np
import yaml

from calib.io.digest import sha256_file, sha256_text
from rig.core.errors import SessionError
from rig.session.events import Event, event_from_row
from rig.session.schema import check_file, read_decisions, verify

# The CSV contract of calib.io.csvio (hx,hy,hz raw nT; temp degC; bx,by,bz reference nT; group) plus context.
EXPORT_COLUMNS = ["point", "group", "t", "hx", "hy", "hz", "temp", "bx", "by", "bz", "setpoint_c",
                  "dut_temp", "ref_temp", "ox", "oy", "oz", "flags"]


def _uri(path: Path, query: str) -> sqlite3.Connection:
    uri = f"file:{urllib.parse.quote(str(path.resolve()))}?{query}"
    conn = sqlite3.connect(uri, uri=True, isolation_level=None, check_same_thread=False)
    conn.row_factory = sqlite3.Row
    conn.execute("SELECT count(*) FROM sqlite_master").fetchone()  # fails now rather than later
    return conn


def wal_bytes(path: Path) -> int:
    """The size of a session's write-ahead log (0: none; the main file holds the whole session)."""
    try:
        return Path(f"{path}-wal").stat().st_size
    except FileNotFoundError:
        return 0


def open_read_only(path: Path) -> tuple[sqlite3.Connection, tempfile.TemporaryDirectory | None]:
    """A read-only connection (and the temporary folder of a private copy, if one was needed)."""
    wal, shm = Path(f"{path}-wal"), Path(f"{path}-shm")
    if wal_bytes(path) == 0:
        return _uri(path, "mode=ro&immutable=1"), None
    if shm.exists():
        try:
            return _uri(path, "mode=ro"), None
        except sqlite3.OperationalError:
            pass  # an index we may not use: read a copy
    tmp = tempfile.TemporaryDirectory(prefix="magrig-read-")
    try:
        copy = Path(tmp.name) / "copy.session"
        shutil.copyfile(path, copy)
        shutil.copyfile(wal, f"{copy}-wal")
        conn = _uri(copy, "mode=rw")
        conn.execute("PRAGMA query_only = ON")
    except BaseException:
        tmp.cleanup()
        raise
    return conn, tmp


# One DUT's samples of the done points in collection order (sample_rows, dataset)
SAMPLE_ROWS_COLUMNS = ("point", "temp_index", "t", "hx", "hy", "hz", "temp", "bx", "by", "bz", "setpoint_c",
                       "dut_temp", "ref_temp", "ox", "oy", "oz", "flags")
SAMPLE_ROWS_SQL = (
    "SELECT s.point_id AS point, p.temp_index, s.t, s.hx, s.hy, s.hz, "
    "coalesce(s.temp_c, s.ref_temp_c) AS temp, s.bx, s.by, s.bz, p.setpoint_c, "
    "s.temp_c AS dut_temp, s.ref_temp_c AS ref_temp, s.ox, s.oy, s.oz, s.flags "
    "FROM samples s JOIN points p ON p.id = s.point_id "
    "WHERE s.dut = ? AND p.state = 'done' ORDER BY p.idx, s.id"
)


def _group(temp_index: int, setpoint_c: float) -> str:
    """A sample's temperature step as a label, e.g. "T03 25.0C"."""
    return f"T{temp_index:02d} {setpoint_c:.1f}C"


class SessionReader:
    """A session file opened read-only (see the module docstring)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        check_file(self.path)
        self.whole = wal_bytes(self.path) == 0  # no write-ahead log holds part of it (module doc)
        try:
            self._conn, self._tmp = open_read_only(self.path)
        except (sqlite3.Error, OSError) as exc:
            raise SessionError(f"{self.path}: cannot open: {exc}") from None
        try:
            self.version = verify(self._conn, self.path)
        except BaseException:
            self.close()
            raise
        self._sha256: str | None = None

    def close(self) -> None:
        self._conn.close()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> SessionReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _rows(self, sql: str, *params) -> list[dict]:
        return [dict(r) for r in self._fetch(sql, params)]

    def _fetch(self, sql: str, params: tuple, *, plain: bool = False) -> list:
        """The rows of `sql`, as sqlite3.Row or, with `plain`, tuples (cheaper for a long recording); a
        damaged file raises SessionError."""
        try:
            cursor = self._conn.cursor()
            if plain:
                cursor.row_factory = None
            return cursor.execute(sql, params).fetchall()
        except sqlite3.DatabaseError as exc:
            raise SessionError(f"{self.path}: damaged session file: {exc}") from None

    # --- tables -----------------------------------------------------------------------------------------
    def info(self) -> dict:
        """The session record; `simulated` parsed; hashes and exit code None in a version 1 file."""
        out = self._rows("SELECT * FROM session")[0]
        for missing in ("plan_sha256", "station_sha256", "exit_code"):
            out.setdefault(missing, None)
        out["simulated"] = json.loads(out["simulated_json"])
        return out

    def points(self) -> list[dict]:
        return self._rows("SELECT * FROM points ORDER BY idx")

    def events(self, after_id: int = 0) -> list[Event]:
        """The events in order; with `after_id`, only those recorded after that one (a live view)."""
        return [event_from_row(r) for r in self._rows("SELECT * FROM events WHERE id > ? ORDER BY id",
                                                      after_id)]

    def fits(self) -> list[dict]:
        return self._rows("SELECT * FROM fits ORDER BY id")

    def recorded_calibration(self, fit: dict) -> dict:
        """A recorded fit's calibration (a row of `fits`), citing this session as its file does: the run
        recorded it before it closed the session, when the session's hash was not yet known (module doc)."""
        cal = json.loads(fit["calibration_json"])
        source = cal.get("source") if isinstance(cal, dict) else None
        if isinstance(source, dict) and source.get("kind") == "session" and source.get("sha256") is None:
            source["sha256"] = self.source_sha256
        return cal

    def snapshots(self) -> list[dict]:
        return self._rows("SELECT * FROM snapshots ORDER BY id")

    def temperatures(self, after_row: int = 0) -> list[dict]:
        """The chamber's set point and air and the DUT temperatures the run logged
        (rig/session/temperature_log.py), in the order written, `duts` parsed, `row` numbering them; with
        `after_row`, only the rows after that
        one (a live view); [] in a session without."""
        if not self._has_table("temperatures"):
            return []
        rows = self._rows("SELECT id AS row, t, setpoint_c, closed_loop_c, air_c, duts_json "
                          "FROM temperatures WHERE id > ? ORDER BY id", after_row)
        for r in rows:
            r["duts"] = json.loads(r.pop("duts_json") or "{}")
        return rows

    def samples_of(self, point_ids: list[str]) -> list[dict]:
        """Every DUT's samples of these points in collection order (a live view adds points as they
        come): point, dut, t, hx..hz, temp (as in `sample_rows`), bx..bz, flags."""
        out: list[dict] = []
        for i in range(0, len(point_ids), 500):  # well below SQLite's limit on bound parameters
            chunk = point_ids[i:i + 500]
            out += self._rows(
                "SELECT point_id AS point, dut, t, hx, hy, hz, coalesce(temp_c, ref_temp_c) AS temp, "
                f"bx, by, bz, flags FROM samples WHERE point_id IN ({','.join('?' * len(chunk))}) "
                "ORDER BY id", *chunk)
        return out

    def snapshot(self, device: str) -> dict | None:
        """The latest snapshot recorded under `device` (e.g. "reference chain"), or None."""
        rows = self._rows("SELECT describe_json FROM snapshots WHERE device = ? ORDER BY id DESC LIMIT 1",
                          device)
        return json.loads(rows[0]["describe_json"]) if rows else None

    def point_references(self) -> dict[str, dict]:
        """{point id: the reference it was taken with} of the done points (rig/fieldsources/fieldmaths.py
        `record`)."""
        out = {}
        for r in self._rows("SELECT id, settle_json FROM points WHERE state = 'done'"):
            stats = json.loads(r["settle_json"] or "{}")
            if "reference" in stats:
                out[r["id"]] = stats["reference"]
        return out

    def duts(self) -> list[str]:
        return [r["dut"] for r in self._rows("SELECT DISTINCT dut FROM samples ORDER BY dut")]

    @property
    def sha256(self) -> str:
        if self._sha256 is None:
            self._sha256 = sha256_file(self.path)
        return self._sha256

    @property
    def source_sha256(self) -> str | None:
        """The hash a calibration cites this session by: the file's, once it holds the whole session; None
        while a write-ahead log holds part of it (module doc)."""
        return self.sha256 if self.whole else None

    # --- samples ----------------------------------------------------------------------------------------
    def pick_dut(self, dut: str | None) -> str:
        if dut is not None and self._rows("SELECT 1 FROM samples WHERE dut = ? LIMIT 1", dut):
            return dut  # one look in the index, not the list of every DUT (a fit reads 64 in turn)
        duts = self.duts()
        if not duts:
            raise SessionError(f"{self.path}: the session holds no samples yet")
        if dut is None:
            if len(duts) > 1:
                raise SessionError(f"{self.path}: several DUTs ({', '.join(duts)}): choose one with --dut")
            return duts[0]
        if dut not in duts:
            raise SessionError(f"{self.path}: no DUT named {dut!r} (DUTs: {', '.join(duts)})")
        return dut

    def sample_rows(self, dut: str | None = None) -> tuple[str, list[dict]]:
        """(dut, rows) of the done points of one DUT in collection order, keyed by EXPORT_COLUMNS.

        `temp` is the DUT's own temperature, or the reference sensor's where that is missing (`dut_temp`
        and `ref_temp` keep both); `group` labels the temperature step, e.g. "T03 25.0C"."""
        dut = self.pick_dut(dut)
        rows = self._rows(SAMPLE_ROWS_SQL, dut)
        for r in rows:
            r["group"] = _group(r["temp_index"], r["setpoint_c"])
        return dut, rows

    def dataset(self, dut: str | None = None):
        """The samples of one DUT as a calib Dataset (rows as in `sample_rows`). Flagged samples are left
        out and counted in source["rows_rejected"]."""
        from calib.dataset import Dataset

        dut = self.pick_dut(dut)
        # the rows as tuples, one column at a time (a long recording's dicts cost more than its fit)
        rows = self._fetch(SAMPLE_ROWS_SQL, (dut,), plain=True)
        at = {name: k for k, name in enumerate(SAMPLE_ROWS_COLUMNS)}
        good = [r for r in rows if not r[at["flags"]]]
        missing_temp = [r[at["point"]] for r in good if r[at["temp"]] is None]
        if missing_temp:
            raise SessionError(f"{self.path}: DUT {dut}: point {missing_temp[0]} has samples without a "
                               "temperature")
        cols = list(zip(*good, strict=True)) if good else [()] * len(SAMPLE_ROWS_COLUMNS)

        def col(name: str, dtype=float) -> np.ndarray:
            return np.array(cols[at[name]], dtype=dtype)

        def vector(*names: str) -> np.ndarray:
            return np.column_stack([col(n) for n in names]) if good else np.zeros((0, 3))

        steps = list(zip(cols[at["temp_index"]], cols[at["setpoint_c"]], strict=True))
        labels = {step: _group(*step) for step in set(steps)}  # each step's label made once
        return Dataset(
            h_nt=vector("hx", "hy", "hz"),
            temp_c=col("temp"),
            ref_nt=vector("bx", "by", "bz"),
            group=np.array([labels[step] for step in steps], dtype=object),
            columns={"point": col("point", object), "t": col("t"), "setpoint_c": col("setpoint_c")},
            source={
                "path": str(self.path), "sha256": self.source_sha256, "kind": "session", "dut": dut,
                "rows_total": len(rows), "rows_used": len(good), "rows_rejected": len(rows) - len(good),
            },
        )

    # --- at a glance ------------------------------------------------------------------------------------
    def decisions(self) -> list[dict]:
        """A sequential schedule's recorded decisions, in order ([] for any other session)."""
        try:
            return read_decisions(self._conn)
        except (sqlite3.DatabaseError, ValueError) as exc:
            raise SessionError(f"{self.path}: damaged session file: {exc}") from None

    def acceptance(self) -> list[dict]:
        """The per-DUT verdicts (rig/analysis/acceptance.py); [] when the plan set no acceptance limits."""
        return self._rows("SELECT * FROM acceptance ORDER BY rowid") if self._has_table("acceptance") else []

    def _has_table(self, name: str) -> bool:
        """Tables made when first needed (acceptance, temperatures) are missing from older sessions."""
        return bool(self._rows("SELECT name FROM sqlite_master WHERE type = 'table' AND name = ?", name))

    def summary(self) -> dict:
        """One session at a glance (for `rig sessions` and the report)."""
        s = self.info()
        by_state = self._rows("SELECT state, count(*) AS n FROM points GROUP BY state")
        counts = {r["state"]: r["n"] for r in by_state}
        fits = self._rows("SELECT dut, model, residual_rms_nt, t FROM fits ORDER BY id DESC LIMIT 1")
        return {
            "path": str(self.path),
            "plan": s["plan_name"],
            "station": s["station_name"],
            "started": s["started"],
            "ended": s["ended"],
            "wall_started": s["wall_started"],
            "wall_ended": s["wall_ended"],
            "operator": s["operator"],
            "simulated": s["simulated"],
            "duts": self.duts(),
            "points_done": counts.get("done", 0),
            "points_failed": counts.get("failed", 0),
            "points_planned": sum(counts.values()),
            "exit_status": s["exit_status"],
            "exit_reason": s["exit_reason"],
            "exit_code": s["exit_code"],
            "completed": bool(s["completed"]),
            "last_fit": fits[0] if fits else None,
        }


def runs_on_simulated_clock(simulated: dict[str, bool]) -> bool:
    """A station whose every device is simulated runs on a simulated clock (rig/devices/build.py
    station_clock): its run-clock times are not wall-clock times."""
    return bool(simulated) and all(simulated.values())


def simulated_text(simulated: dict[str, bool]) -> str:
    """`every device simulated (a, b)`, `simulated: a; real: b`, or `every device real (a, b)`."""
    sim = [name for name, v in simulated.items() if v]
    real = [name for name, v in simulated.items() if not v]
    if not real:
        return f"every device simulated ({', '.join(sim)})" if sim else "no devices recorded"
    if not sim:
        return f"every device real ({', '.join(real)})"
    return f"simulated: {', '.join(sim)}; real: {', '.join(real)}"


def read_dataset(path: str | Path, dut: str | None = None):
    """One DUT's samples of a session file as a calib Dataset (opens and closes the reader)."""
    with SessionReader(path) as reader:
        return reader.dataset(dut)



# --- a resume runs the recorded plan: was the file edited since? ---------------------------------------
def recorded_files_changed(info: dict) -> list[str]:
    """For the plan and the station: a line naming the file and the keys that changed, when the file at
    its recorded path no longer matches the recorded text (sha256). A file that is gone is no change:
    the recorded text is all there is."""
    out = []
    for what in ("plan", "station"):
        recorded_path, text = info.get(f"{what}_path"), info[f"{what}_text"]
        if not recorded_path:
            continue
        try:
            current = Path(recorded_path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            continue
        if sha256_text(current) == (info.get(f"{what}_sha256") or sha256_text(text)):
            continue
        out.append(f"{what} file {recorded_path} changed since the session was recorded "
                   f"({changed_keys(text, current)})")
    return out


def changed_keys(old_text: str, new_text: str, limit: int = 8) -> str:
    """'keys changed: a.b, c[2]' between two YAML texts; or what else differs."""
    try:
        old, new = yaml.safe_load(old_text), yaml.safe_load(new_text)
    except yaml.YAMLError:
        return "it is no longer valid YAML"
    keys = _differences(old, new, "")
    if not keys:
        return "comments or layout only"
    shown = ", ".join(keys[:limit]) + (f" and {len(keys) - limit} more" if len(keys) > limit else "")
    return f"keys changed: {shown}"


def _differences(old, new, where: str) -> list[str]:
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in list(old) + [k for k in new if k not in old]:
            path = f"{where}.{key}" if where else str(key)
            if key not in old or key not in new:
                out.append(path)
            else:
                out += _differences(old[key], new[key], path)
        return out
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        pairs = enumerate(zip(old, new, strict=True))
        return [d for i, (a, b) in pairs for d in _differences(a, b, f"{where}[{i}]")]
    return [] if old == new else [where or "(the whole file)"]
