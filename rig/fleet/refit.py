"""One session's re-fit, as run on a worker: its rows (from a file or the fleet database) become one
Dataset per DUT, each DUT is fitted, and every DUT gives one results row, failed fits included.

The rows become a Dataset exactly as rig.session.reader.read_dataset makes one (done points in collection
order, flagged samples left out, the DUT's temperature or else the reference sensor's, a group per temperature
step), and each DUT is fitted through rig/analysis/sessionfit.py, as `rig refit` and the run's own fit do
(the run's best ambient, a moving schedule's lag, the plan's robust option), from the session's other
tables (`SessionTables`); so a batch re-fit gives the parameters `rig refit` gives; the tests hold them to
it. The uncertainty budget (a Monte Carlo per DUT) is left out: the results table has no place for it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import calib
from calib.dataset import Dataset
from rig.core.errors import ERRORS, DataError
from rig.fleet.source import session_snapshot

RESULT_COLUMNS = ("session_uid", "source", "station", "dut", "model", "software_version", "status", "reason",
                  "n", "n_used", "rms_before_nt", "rms_after_nt", "temp_ref_c", "params", "std_errors")


def failed_row(*, session_uid: str, source: str, station: str | None, dut: str, model: str,
               software_version: str, reason: str) -> dict:
    row = dict.fromkeys(RESULT_COLUMNS)
    row.update(session_uid=session_uid, source=source, station=station, dut=dut, model=model,
               software_version=software_version, status="failed", reason=reason)
    return row


class SessionTables:
    """A session's tables as rows (a file's snapshot, or the fleet database's copies), read as the fit
    reads a session (rig/analysis/sessionfit.py: the SessionReader methods it uses)."""

    def __init__(self, path: str, tables: dict[str, list[dict]]):
        self.path = Path(path)
        self.tables = tables

    def info(self) -> dict:
        out = dict(self.tables["session"][0])
        for missing in ("plan_sha256", "station_sha256", "exit_code"):
            out.setdefault(missing, None)
        out["simulated"] = json.loads(out.get("simulated_json") or "{}")
        return out

    def points(self) -> list[dict]:
        return sorted(self.tables.get("points", []), key=lambda p: p["idx"])

    def events(self) -> list:
        from rig.session.events import event_from_row

        return [event_from_row(r) for r in sorted(self.tables.get("events", []), key=lambda r: r["id"])]

    def snapshot(self, device: str) -> dict | None:
        rows = [r for r in self.tables.get("snapshots", []) if r["device"] == device]
        return json.loads(max(rows, key=lambda r: r["id"])["describe_json"]) if rows else None

    def temperatures(self) -> list[dict]:
        """The run's temperature log as SessionReader.temperatures gives it ([] in a copy without one)."""
        rows = sorted(self.tables.get("temperatures", []), key=lambda r: r["id"])
        return [{"row": r["id"], "t": r["t"], "setpoint_c": r.get("setpoint_c"),
                 "closed_loop_c": r.get("closed_loop_c"), "air_c": r.get("air_c"),
                 "duts": json.loads(r.get("duts_json") or "{}")} for r in rows]

    def point_references(self) -> dict[str, dict]:
        out = {}
        for p in self.points():
            stats = json.loads(p.get("settle_json") or "{}") if p["state"] == "done" else {}
            if "reference" in stats:
                out[p["id"]] = stats["reference"]
        return out


def refit_file(path: str, model: str, software_version: str) -> list[dict]:
    """Worker task: every DUT of the session file at `path`. A file that cannot be read is one failed
    row (dut "") naming the problem."""
    uid, station = f"file:{Path(path).resolve()}", None  # until the session row is read
    try:
        snap = session_snapshot(path)
        uid, station = snap.uid, snap.session.get("station_name")
        tables = {name: table.dicts() for name, table in snap.tables.items()}
        return fit_session(uid, path, station, SessionTables(path, tables), model, software_version)
    except Exception as exc:  # noqa: BLE001 - a bad session is a results row, never a lost batch
        return [failed_row(session_uid=uid, source=path, station=station, dut="", model=model,
                           software_version=software_version, reason=_reason(exc))]


_CONNECTIONS: dict[str, object] = {}  # per worker process: one connection per database, kept between tasks


def refit_db(url: str, uid: str, model: str, software_version: str) -> list[dict]:
    """Worker task: every DUT of one session in the fleet database."""
    from rig.fleet.query import session_rows, session_tables
    from rig.fleet.schema import connect

    try:
        conn = _CONNECTIONS.get(url)
        if conn is None or conn.closed:
            conn = _CONNECTIONS[url] = connect(url, create=False)
        try:
            meta, points, samples = session_rows(conn, uid)
            tables = {"points": points, "samples": samples,
                      **session_tables(conn, uid, ("session", "events", "snapshots", "temperatures"))}
        except Exception:
            _CONNECTIONS.pop(url, None).close()  # a broken connection is not reused
            raise
        return fit_session(uid, meta["source_path"], meta["station_name"],
                           SessionTables(meta["source_path"], tables), model, software_version)
    except Exception as exc:  # noqa: BLE001 - as in refit_file
        return [failed_row(session_uid=uid, source=url, station=None, dut="", model=model,
                           software_version=software_version, reason=_reason(exc))]


def fit_session(uid: str, source: str, station: str | None, tables: SessionTables, model: str,
                software_version: str) -> list[dict]:
    from rig.analysis.sessionfit import SessionFitter

    datasets = dut_datasets(tables.tables["points"], tables.tables["samples"], source)
    fitter = SessionFitter.of(tables) if "session" in tables.tables else SessionFitter(None)
    if not datasets:
        return [failed_row(session_uid=uid, source=source, station=station, dut="", model=model,
                           software_version=software_version, reason=f"{source}: no samples yet")]
    rows = []
    for dut, ds in datasets.items():
        base = dict(session_uid=uid, source=source, station=station, dut=dut, model=model,
                    software_version=software_version)
        try:
            if isinstance(ds, Exception):
                raise ds
            cal = fitter.calibrate(fitter.prepare(ds), model, software_version=software_version, budget=False)
        except Exception as exc:  # noqa: BLE001 - one DUT's failure does not stop the others
            rows.append(failed_row(**base, reason=_reason(exc)))
            continue
        rows.append({**base, **calibration_fields(cal)})
    return rows


def calibration_fields(cal: calib.Calibration) -> dict:
    st = cal.stats
    return {
        "status": "ok", "reason": "",
        "n": int(st.get("n", 0)), "n_used": int(st.get("n_used", 0)),
        "rms_before_nt": _opt_float(st.get("rms_before_nt")),
        "rms_after_nt": _opt_float(st.get("rms_after_nt")),
        "temp_ref_c": _opt_float(cal.temp_ref_c),
        "params": json.dumps({k: np.asarray(v, float).tolist() for k, v in cal.params.items()}),
        "std_errors": json.dumps({k: np.asarray(v, float).tolist() for k, v in cal.std_errors.items()}),
    }


def dut_datasets(points: list[dict], samples: list[dict], where: str) -> dict[str, Dataset | Exception]:
    """{dut: Dataset} built as rig.session.reader.read_dataset builds it; a DUT whose rows cannot make a
    dataset
    maps to the DataError saying why."""
    by_id = {p["id"]: p for p in points}
    per_dut: dict[str, list[tuple[int, int, dict]]] = {}
    for s in samples:
        p = by_id.get(s["point_id"])
        if p is None:
            raise DataError(f"{where}: sample {s['id']} belongs to point {s['point_id']!r}, not in the plan")
        per_dut.setdefault(s["dut"], [])
        if p["state"] == "done":
            per_dut[s["dut"]].append((p["idx"], s["id"], s))
    out: dict[str, Dataset | Exception] = {}
    for dut in sorted(per_dut):
        rows = [s for _, _, s in sorted(per_dut[dut], key=lambda r: r[:2])]
        try:
            out[dut] = _dataset(rows, by_id, where, dut)
        except DataError as exc:
            out[dut] = exc
    return out


def _dataset(rows: list[dict], by_id: dict, where: str, dut: str) -> Dataset:
    good = [r for r in rows if not r["flags"]]
    temps = [r["temp_c"] if r["temp_c"] is not None else r["ref_temp_c"] for r in good]
    for r, temp in zip(good, temps, strict=True):
        if temp is None:
            raise DataError(f"{where}: DUT {dut}: point {r['point_id']} has samples without a temperature")

    def col(name: str) -> np.ndarray:
        return np.array([r[name] for r in good], dtype=float)

    def vec(*names: str) -> np.ndarray:
        return np.column_stack([col(n) for n in names]) if good else np.zeros((0, 3))

    points = [by_id[r["point_id"]] for r in good]
    return Dataset(
        h_nt=vec("hx", "hy", "hz"),
        temp_c=np.array(temps, dtype=float),
        ref_nt=vec("bx", "by", "bz"),
        group=np.array([f"T{p['temp_index']:02d} {p['setpoint_c']:.1f}C" for p in points], dtype=object),
        columns={"point": np.array([r["point_id"] for r in good], dtype=object), "t": col("t"),
                 "setpoint_c": np.array([p["setpoint_c"] for p in points], dtype=float)},
        source={"path": where, "kind": "session", "dut": dut, "rows_total": len(rows),
                "rows_used": len(good), "rows_rejected": len(rows) - len(good)},
    )


def _reason(exc: BaseException) -> str:
    if isinstance(exc, ERRORS):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


def _opt_float(value) -> float | None:
    return None if value is None else float(value)
