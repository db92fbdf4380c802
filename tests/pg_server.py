"""A throwaway PostgreSQL server for the fleet tests and bench: initdb in a temporary folder, listening
only on 127.0.0.1 (and a unix socket in that folder) on a free port, trust authentication, no fsync.

PostgreSQL refuses to run as root: as root the server runs as the `postgres` system user (runuser),
otherwise as the current user. `start()` raises PgUnavailable with the reason when it cannot start.
"""

from __future__ import annotations

import contextlib
import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path


class PgUnavailable(RuntimeError):
    """No PostgreSQL server can be started here (the reason says why)."""


def _bin_dir() -> Path:
    candidates = [os.environ.get("MAGRIG_PG_BIN", "")] + sorted(
        glob.glob("/usr/lib/postgresql/*/bin"), key=lambda p: int(Path(p).parent.name), reverse=True)
    for c in candidates:
        if c and (Path(c) / "initdb").is_file() and (Path(c) / "pg_ctl").is_file():
            return Path(c)
    found = shutil.which("initdb")
    if found and shutil.which("pg_ctl"):
        return Path(found).parent
    raise PgUnavailable("no PostgreSQL server binaries (initdb, pg_ctl) in /usr/lib/postgresql/*/bin or PATH")


def _run_as() -> tuple[list[str], int | None, int | None]:
    """(command prefix, uid, gid) for running the server's programs."""
    if os.geteuid() != 0:
        return [], None, None
    try:
        user = pwd.getpwnam("postgres")
    except KeyError:
        raise PgUnavailable("running as root and no `postgres` system user to run the server") from None
    runuser = shutil.which("runuser")
    if runuser is None:
        raise PgUnavailable("running as root and `runuser` is missing (needed to run as `postgres`)")
    return [runuser, "-u", "postgres", "--"], user.pw_uid, user.pw_gid


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class PgServer:
    root: Path
    port: int
    bin_dir: Path
    prefix: list[str]

    def url(self, dbname: str = "postgres") -> str:
        return f"postgresql://postgres@127.0.0.1:{self.port}/{dbname}"

    def stop(self) -> None:
        subprocess.run([*self.prefix, str(self.bin_dir / "pg_ctl"), "-D", str(self.root / "data"),
                        "-m", "immediate", "-w", "stop"], capture_output=True, timeout=60)
        shutil.rmtree(self.root, ignore_errors=True)


def start() -> PgServer:
    bin_dir = _bin_dir()
    prefix, uid, gid = _run_as()
    root = Path(tempfile.mkdtemp(prefix="magrig-pg-"))
    if uid is not None:
        os.chown(root, uid, gid)
    data, port = root / "data", _free_port()

    def run(*args: str) -> None:
        done = subprocess.run([*prefix, *args], capture_output=True, text=True, timeout=120, cwd=root)
        if done.returncode != 0:
            log = (root / "log").read_text() if (root / "log").exists() else ""
            shutil.rmtree(root, ignore_errors=True)
            raise PgUnavailable(f"{Path(args[0]).name} failed: {(done.stderr or done.stdout).strip()} {log}")

    run(str(bin_dir / "initdb"), "-D", str(data), "-U", "postgres", "--auth=trust", "-E", "UTF8", "--no-sync")
    options = f"-h 127.0.0.1 -p {port} -k {root} -c fsync=off -c synchronous_commit=off " \
              "-c full_page_writes=off -c max_connections=50"
    run(str(bin_dir / "pg_ctl"), "-D", str(data), "-l", str(root / "log"), "-o", options, "-w", "-t", "60",
        "start")
    return PgServer(root, port, bin_dir, prefix)


@contextlib.contextmanager
def running() -> Iterator[PgServer]:
    server = start()
    try:
        yield server
    finally:
        server.stop()


def create_database(server: PgServer, name: str) -> str:
    """A fresh, empty database on the server; returns its URL."""
    import psycopg

    with psycopg.connect(server.url(), autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}"')
        conn.execute(f'CREATE DATABASE "{name}"')
    return server.url(name)


def create_database_like(url: str, name: str) -> str:
    """A fresh database beside the one at `url` (same server); returns its URL."""
    import psycopg

    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}"')
        conn.execute(f'CREATE DATABASE "{name}"')
    return url.rsplit("/", 1)[0] + "/" + name
