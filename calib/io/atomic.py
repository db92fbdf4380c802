"""Write a file all at once: into a temporary file beside it, then rename, so nothing is left half-written."""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import IO

# not handed to child processes; binary, so Windows never turns \n into \r\n behind io's back
_PLATFORM_FLAGS = (getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOINHERIT", 0) | getattr(os, "O_BINARY", 0))


def create_new(path: str | os.PathLike, mode: int = 0o666) -> int:
    """Create `path` (it must not exist) and return a writable descriptor. The mode goes through the
    umask like any file's (tempfile.mkstemp would force 0600 on what we write for others to read)."""
    return os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY | _PLATFORM_FLAGS, mode)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", newline: str | None = None) -> Iterator[IO]:
    """Yield a file object; on success it replaces `path`, on any error the target is untouched."""
    target = Path(path)
    tmp = target.with_name(f".{target.name}.{secrets.token_hex(4)}.tmp")
    fd = create_new(tmp)
    try:
        with os.fdopen(fd, mode, newline=newline, **({} if "b" in mode else {"encoding": "utf-8"})) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())  # the data is on disk before the name points at it
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
