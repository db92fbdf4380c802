"""The run lock: `<session>.lock`, an OS file lock held for the life of the run.

Only one process can hold it; the OS releases it when its holder dies, so a dead run's lock never needs
guessing from a pid. The file holds the holder's pid (for the message a second run gets, and to tell that
the previous holder died without releasing it: a clean release removes the file, or at least empties it).

The lock is filelock's, chosen over portalocker: `lock_descriptor` locks a descriptor we own with the
platform's own call (flock on POSIX, LockFileEx on Windows), so the pid note and the path check below
stay ours; it is pure Python without dependencies; and where the OS has no file lock at all (a POSIX
without fcntl) its SoftFileLock records pid, host and start time and takes over a dead holder's marker,
where portalocker cannot even be imported.

Windows locks byte 0 only, and nobody else may read a locked byte: the pid note starts on the second
line ("\\n1234\\n"). Windows removes no file that is open, so there the file goes after it is closed.
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from pathlib import Path

from rig.core.errors import SessionError

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # "only soft file lock is available": _marker_lock says it plainly
    import filelock

NATIVE_LOCKS = sys.platform == "win32" or filelock.has_fcntl
_OPEN_FLAGS = (os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOINHERIT", 0)
               | getattr(os, "O_BINARY", 0))


class SessionLock:
    """`with SessionLock(session_path) as lock: ...`; `lock.stale_pid` names a dead previous holder."""

    def __init__(self, session_path: str | Path):
        self.path = Path(f"{session_path}.lock")
        self.stale_pid: int | None = None
        self._fd: int | None = None
        self._marker = None  # the SoftFileLock, where the OS has no file lock

    def acquire(self) -> None:
        """Take the lock, or SessionError (one line) when another process holds it or the folder
        cannot be written to."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SessionError(f"{self.path.parent}: cannot create the session folder "
                               f"({exc.strerror or exc})") from None
        if not NATIVE_LOCKS:
            self._marker_lock()
            return
        for _ in range(20):  # a holder releasing meanwhile removes the file: lock the new one
            fd = self._open()
            try:
                got = filelock.lock_descriptor(fd, blocking=False)
            except OSError as exc:
                os.close(fd)
                raise SessionError(f"{self.path}: the file system refuses a file lock "
                                   f"({exc.strerror or exc}); keep sessions on a local disk") from None
            if not got:
                holder = _read_pid(fd)
                os.close(fd)
                raise self._busy(holder)
            if not self._still_at_path(fd):
                os.close(fd)
                continue
            previous = _read_pid(fd)
            if previous is not None and previous != os.getpid():
                self.stale_pid = previous
            try:
                os.ftruncate(fd, 0)
                os.lseek(fd, 0, os.SEEK_SET)
                os.write(fd, f"\n{os.getpid()}\n".encode())
            except OSError:
                pass  # a full disk: the lock holds all the same, only the pid note is missing
            self._fd = fd
            return
        raise SessionError(f"{self.path}: could not take the run lock")

    def _marker_lock(self) -> None:
        """No OS file lock here: a marker file with pid, host and start time; a marker whose process is
        gone is taken over (filelock checks the process). The dead holder is read before taking over."""
        marker = filelock.SoftFileLock(str(self.path), timeout=0)
        previous = marker.pid
        try:
            marker.acquire()
        except filelock.Timeout:
            raise self._busy(marker.pid) from None
        except OSError as exc:
            raise SessionError(f"{self.path}: cannot create the run lock ({exc.strerror or exc}); "
                               "is the folder writable?") from None
        if previous is not None and previous != os.getpid():
            self.stale_pid = previous
        self._marker = marker

    def _busy(self, holder: int | None) -> SessionError:
        who = f"running process {holder}" if holder else "another running process"
        return SessionError(f"{self.path}: session is in use by {who}; stop it first (Ctrl-C) or "
                            "wait for it to finish")

    def _open(self) -> int:
        try:
            return os.open(self.path, _OPEN_FLAGS, 0o666)
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
        return self._fd is not None or self._marker is not None

    def release(self) -> None:
        """Empty and remove the file while still holding it (a waiting process then finds it gone and
        retries); where the OS removes no open file, remove it once closed."""
        if self._marker is not None:
            marker, self._marker = self._marker, None
            with contextlib.suppress(OSError):
                marker.release()
            return
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        removed = False
        try:
            with contextlib.suppress(OSError):  # no pid left that would read as a dead holder's
                os.ftruncate(fd, 0)
            with contextlib.suppress(OSError):
                self.path.unlink(missing_ok=True)
                removed = True
        finally:
            with contextlib.suppress(OSError):
                filelock.unlock_descriptor(fd)
            os.close(fd)
        if not removed and sys.platform == "win32":  # a contender holding it open keeps it: empty, harmless
            with contextlib.suppress(OSError):
                self.path.unlink(missing_ok=True)

    def __enter__(self) -> SessionLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def holder_pid(session_path: str | Path) -> int | None:
    """The pid the session's lock file names (its holder, live or dead); None without one."""
    try:
        fd = os.open(f"{session_path}.lock", os.O_RDONLY | getattr(os, "O_BINARY", 0))
    except OSError:
        return None
    try:
        return _read_pid(fd)
    finally:
        os.close(fd)


def _read_pid(fd: int) -> int | None:
    """The pid on the note's first non-empty line (ours: "\\n1234\\n"; the marker lock's: "1234\\nhost..."),
    read from byte 0, or from byte 1 where the holder's Windows lock keeps byte 0 from us."""
    for offset in (0, 1):
        try:
            os.lseek(fd, offset, os.SEEK_SET)
            text = os.read(fd, 64).decode("ascii", "replace")
        except OSError:
            continue
        first = next((line.strip() for line in text.splitlines() if line.strip()), "")
        return int(first) if first.isdigit() and int(first) > 0 else None
    return None
