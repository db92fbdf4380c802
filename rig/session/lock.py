"""The run lock: `<session>.lock`, an OS file lock (flock) held for the life of the run.

Only one process can hold it; the kernel releases it when its holder dies, so a dead run's lock never
needs guessing from a pid. The file holds the holder's pid (for the message a second run gets, and to
tell that the previous holder died without releasing it: a clean release removes the file).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path

from rig.core.errors import SessionError


class SessionLock:
    """`with SessionLock(session_path) as lock: ...`; `lock.stale_pid` names a dead previous holder."""

    def __init__(self, session_path: str | Path):
        self.path = Path(f"{session_path}.lock")
        self.stale_pid: int | None = None
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock, or SessionError (one line) when another process holds it or the folder
        cannot be written to."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SessionError(f"{self.path.parent}: cannot create the session folder "
                               f"({exc.strerror or exc})") from None
        for _ in range(20):  # a holder releasing meanwhile removes the file: lock the new one
            fd = self._open()
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _read_pid(fd)
                os.close(fd)
                who = f"running process {holder}" if holder else "another running process"
                raise SessionError(f"{self.path}: session is in use by {who}; stop it first (Ctrl-C) or "
                                   "wait for it to finish") from None
            if not self._still_at_path(fd):
                os.close(fd)
                continue
            previous = _read_pid(fd)
            if previous is not None and previous != os.getpid():
                self.stale_pid = previous
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            except OSError:
                pass  # a full disk: the lock holds all the same, only the pid note is missing
            self._fd = fd
            return
        raise SessionError(f"{self.path}: could not take the run lock")

    def _open(self) -> int:
        try:
            return os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError as exc:
            raise SessionError(f"{self.path}: cannot create the run lock ({exc.strerror or exc}); "
                               "is the folder writable?") from None

    def _still_at_path(self, fd: int) -> bool:
        try:
            here, there = os.fstat(fd), os.stat(self.path)
        except FileNotFoundError:
            return False
        return (here.st_dev, here.st_ino) == (there.st_dev, there.st_ino)

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """Remove the file while still holding it (a waiting process then finds it gone and retries)."""
        if self._fd is None:
            return
        try:
            self.path.unlink(missing_ok=True)
        except OSError:  # cannot remove it: at least no pid that would read as a dead holder's
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, 0)
        finally:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> SessionLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() and int(text) > 0 else None
