"""Batch re-fit throughput: `rig refit-all`'s machinery on 1000 small synthetic sessions.

Sessions are written through rig.session.writer.Session (2 temperatures x 6 axis directions x 3 samples, one
DUT, T24 errors from calib.synthetic), not by running campaigns. Figures: sessions/s re-fitted (T24) with 1
and 2 local Dask workers, from the folder and from a throwaway PostgreSQL server (127.0.0.1) after `rig push`;
the push rate; peak memory of the client and of each worker. Cluster start-up is timed apart.

    python bench/batch_refit.py [--sessions 1000]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rig import __version__  # noqa: E402
from rig.fleet import batch  # noqa: E402
from rig.fleet.push import push_snapshot  # noqa: E402
from rig.fleet.query import session_uids  # noqa: E402
from rig.fleet.schema import connect  # noqa: E402
from rig.fleet.source import session_files, session_snapshot  # noqa: E402
from tests import pg_server  # noqa: E402
from tests.fleet_sessions import Spec, write_session  # noqa: E402

SMALL = {"temps_c": (0.0, 40.0), "directions": 6, "samples": 3}


def _write(args: tuple[Path, int]) -> None:
    folder, seed = args
    write_session(folder / f"s{seed:05d}.session", Spec(seed=seed, **SMALL))


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux


def refit(label: str, make_tasks, workers: int) -> None:
    t0 = time.perf_counter()
    with batch.dask_client(None, workers) as client:
        started = time.perf_counter() - t0
        tasks = make_tasks()
        t1 = time.perf_counter()
        rows = batch.run_tasks(client, tasks, "t24", __version__, progress=False)
        took = time.perf_counter() - t1
        worker_mb = sorted(client.run(_peak_rss_mb).values())
    ok = sum(r["status"] == "ok" for r in rows)
    print(f"{label:<12} {workers} worker(s): {len(tasks) / took:7.1f} sessions/s ({len(tasks)} sessions, "
          f"{ok} DUTs ok, {took:.1f} s; cluster start {started:.1f} s); peak RSS per worker "
          f"{', '.join(f'{m:.0f}' for m in worker_mb)} MB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=1000)
    n = parser.parse_args().sessions
    with tempfile.TemporaryDirectory(prefix="magrig-batch-") as tmp:
        folder = Path(tmp) / "sessions"
        folder.mkdir()
        t0 = time.perf_counter()
        with ProcessPoolExecutor(2) as pool:
            list(pool.map(_write, [(folder, seed) for seed in range(1, n + 1)], chunksize=25))
        paths = session_files(folder)
        print(f"wrote {len(paths)} sessions in {time.perf_counter() - t0:.1f} s "
              f"({sum(p.stat().st_size for p in paths) / len(paths) / 1024:.0f} kB each)")

        for workers in (1, 2):
            refit("folder", lambda: batch.file_tasks(paths, "t24", __version__), workers)

        try:
            server = pg_server.start()
        except pg_server.PgUnavailable as exc:
            print(f"PostgreSQL figures skipped: {exc}")
            return
        try:
            url = pg_server.create_database(server, "bench")
            t0 = time.perf_counter()
            with connect(url) as conn:
                for p in paths:
                    push_snapshot(conn, session_snapshot(p))
            took = time.perf_counter() - t0
            print(f"push         {len(paths) / took:7.1f} sessions/s ({took:.1f} s, one transaction each)")
            with connect(url) as conn:
                uids = session_uids(conn)
            for workers in (1, 2):
                refit("PostgreSQL", lambda: batch.db_tasks(url, uids, "t24", __version__), workers)
        finally:
            server.stop()
    print(f"client peak RSS {_peak_rss_mb():.0f} MB")


if __name__ == "__main__":
    main()
