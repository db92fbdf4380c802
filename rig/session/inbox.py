"""Operator requests from outside the run (the cockpit's "pause" and "abort" buttons): a small file beside
the session that the run's engine reads wherever it checks for Ctrl-C. Only the run writes the session;
the engine alone decides when a request is safe to act on (rig/engine/executor.py), exactly as for Ctrl-C.

    post(session_path, "pause", source="web client 127.0.0.1")  # the cockpit; refused with no live run
    inbox = Inbox(session_path)                                  # the run (rig/run/campaign.py)
    inbox.take() -> Request | None                               # the engine, at every check for Ctrl-C

The file `<session>.request` holds one JSON request {action, source, pid, id, wall_t}, written under a
temporary name and renamed, so the engine never reads half of one. `pid` is the run it is meant for (the
holder of the run lock, rig/session/lock.py): a request that arrives after its run ended is dropped by the
next run instead of pausing it. The engine removes the file when it takes the request. An abort is never
replaced by a later pause. With no request pending, a check costs one failed rename().
"""

from __future__ import annotations

import contextlib
import json
import os
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from rig.core.errors import SessionError
from rig.session.lock import holder_pid
from rig.session.schema import pid_alive

ACTIONS = ("pause", "abort")


@dataclass(frozen=True)
class Request:
    action: str  # one of ACTIONS
    source: str  # who asked, for the session's events ("web client 192.0.2.7")
    id: str


def request_path(session_path: str | Path) -> Path:
    return Path(f"{session_path}.request")


def running_pid(session_path: str | Path) -> int | None:
    """The pid of the live run holding the session's lock; None when no run holds it (no lock file, or
    its holder died: a kill -9 leaves the file with a dead pid)."""
    pid = holder_pid(session_path)
    return pid if pid is not None and pid_alive(pid) else None


def post(session_path: str | Path, action: str, source: str) -> Request:
    """Leave a request for the live run of `session_path`; SessionError when there is none or the
    folder cannot be written to."""
    if action not in ACTIONS:
        raise SessionError(f"unknown request {action!r} (known: {', '.join(ACTIONS)})")
    pid = running_pid(session_path)
    if pid is None:
        raise SessionError(f"{Path(session_path).name}: no run is running this session; a stopped run "
                           "is continued with rig run --resume")
    path = request_path(session_path)
    if action == "pause" and _read(path).get("action") == "abort":
        raise SessionError(f"{Path(session_path).name}: an abort is already requested")
    request = Request(action, source, uuid.uuid4().hex)
    body = json.dumps({"action": action, "source": source, "pid": pid, "id": request.id,
                       "wall_t": time.time()})
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{request.id}")
    try:
        tmp.write_text(body, encoding="utf-8")
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise SessionError(f"{path}: cannot leave the request ({exc.strerror or exc})") from None
    return request


def _read(path: Path) -> dict:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


class Inbox:
    """The run's side: requests meant for this process, each taken once."""

    def __init__(self, session_path: str | Path, pid: int | None = None):
        self.path = request_path(session_path)
        self.pid = os.getpid() if pid is None else pid

    def take(self) -> Request | None:
        claimed = self.path.with_name(f".{self.path.name}.taken.{self.pid}")
        try:
            os.rename(self.path, claimed)  # claimed whole: a request posted meanwhile waits for next time
        except OSError:
            return None
        data = _read(claimed)
        with contextlib.suppress(OSError):
            claimed.unlink()
        if data.get("pid") != self.pid or data.get("action") not in ACTIONS:
            return None  # left for an earlier run, or not a request at all
        return Request(str(data["action"]), str(data.get("source") or "unknown"), str(data.get("id") or ""))
