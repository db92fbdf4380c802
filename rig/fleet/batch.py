"""`rig refit-all`: every DUT of every session re-fitted in parallel on Dask, one results row per DUT.

By default a local cluster of worker processes on 127.0.0.1 (one thread each: the fits are numpy-bound
and the GIL would serialise threads), or an existing cluster given by its scheduler address. One task per
session; a task that fails, or whose worker dies, becomes a failed row with its reason, never a lost batch.
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import psycopg
from psycopg.types.json import Jsonb

from calib.io.atomic import atomic_write
from rig.fleet import FleetError
from rig.fleet.refit import RESULT_COLUMNS, failed_row, refit_db, refit_file


@dataclass(frozen=True)
class Task:
    """One session to re-fit: from a file (`path`) or from the fleet database (`url`, `uid`)."""

    label: str  # the file, or the session uid: named in a failed row
    func: Callable[..., list[dict]]
    args: tuple


def file_tasks(paths: list[Path], model: str, version: str) -> list[Task]:
    return [Task(str(p), refit_file, (str(p), model, version)) for p in paths]


def db_tasks(url: str, uids: list[str], model: str, version: str) -> list[Task]:
    return [Task(uid, refit_db, (url, uid, model, version)) for uid in uids]


@contextlib.contextmanager
def dask_client(scheduler: str | None, workers: int) -> Iterator:
    """A client of the cluster at `scheduler`, or of a local cluster of `workers` processes."""
    from distributed import Client, LocalCluster

    if logging.getLogger().level > logging.DEBUG:  # the cluster's INFO chatter only with --debug
        logging.getLogger("distributed").setLevel(logging.ERROR)
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise FleetError(f"{scheduler}: cannot reach the Dask scheduler: {exc}") from None
        with client:
            yield client
        return
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)  # any free port
    with cluster, Client(cluster) as client:
        yield client


def run_tasks(client, tasks: list[Task], model: str, version: str, progress: bool = True) -> list[dict]:
    """Submit every task, gather the rows as they complete (a rich progress bar meanwhile)."""
    from distributed import as_completed
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    futures = {client.submit(t.func, *t.args, pure=False): t for t in tasks}
    rows: list[dict] = []
    columns = (TextColumn("re-fitting"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, disable=not progress, transient=True) as bar:
        job = bar.add_task("sessions", total=len(tasks))
        for future in as_completed(futures):
            task = futures.pop(future)
            try:
                rows.extend(future.result())
            except Exception as exc:  # noqa: BLE001 - a worker lost mid-task: the session is a failed row
                rows.append(failed_row(session_uid=task.label, source=task.label, station=None, dut="",
                                       model=model, software_version=version,
                                       reason=f"task failed on the cluster: {type(exc).__name__}: {exc}"))
            future.release()
            bar.advance(job)
    return sorted(rows, key=lambda r: (r["session_uid"], r["dut"]))


def write_parquet(rows: list[dict], path: Path) -> None:
    """The results table as Parquet, written whole or not at all."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    schema = pa.schema([
        ("session_uid", pa.string()), ("source", pa.string()), ("station", pa.string()), ("dut", pa.string()),
        ("model", pa.string()), ("software_version", pa.string()), ("status", pa.string()),
        ("reason", pa.string()), ("n", pa.int64()), ("n_used", pa.int64()), ("rms_before_nt", pa.float64()),
        ("rms_after_nt", pa.float64()), ("temp_ref_c", pa.float64()),
        ("params", pa.string()), ("std_errors", pa.string()),  # JSON: {name: nested lists}, as in calfiles
    ])
    assert tuple(schema.names) == RESULT_COLUMNS
    table = pa.Table.from_pylist(rows, schema=schema)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "wb") as f:
        pq.write_table(table, f)


def write_results_db(conn: psycopg.Connection, rows: list[dict]) -> None:
    """Upsert the rows into magrig.refit_results (key: session, DUT, model, software version)."""
    columns = ", ".join(RESULT_COLUMNS)
    key = ("session_uid", "dut", "model", "software_version")
    updates = ", ".join(f"{c} = excluded.{c}" for c in RESULT_COLUMNS if c not in key)
    statement = (
        f"INSERT INTO magrig.refit_results ({columns}, fitted_at) VALUES "
        f"({', '.join(['%s'] * len(RESULT_COLUMNS))}, now()) "
        f"ON CONFLICT (session_uid, dut, model, software_version) DO UPDATE SET {updates}, fitted_at = now()"
    )
    params = [
        tuple(Jsonb(json.loads(r[c])) if c in ("params", "std_errors") and r[c] is not None else r[c]
              for c in RESULT_COLUMNS)
        for r in rows
    ]
    try:
        with conn.transaction(), conn.cursor() as cur:
            cur.executemany(statement, params)
    except psycopg.Error as exc:
        raise FleetError(f"cannot write the re-fit results to the fleet database: {exc}") from None

