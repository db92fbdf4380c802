"""Signal handlers that degrade where a signal does not exist or cannot be handled here: Windows has no
SIGHUP and never delivers SIGTERM from another process (it has SIGBREAK, Ctrl-Break, instead), and only
the main thread of the main interpreter may set a handler. Where a handler cannot be set, nothing is
set and the run goes on: Ctrl-C, the cockpit's requests and the session still stop it cleanly.

    with handled({"SIGINT": on_pause, **dict.fromkeys(TERMINATE, on_abort)}): ...   # restored after
    set_handler("SIGTERM", handler)                                                   # for good
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable, Iterator
from typing import Any

TERMINATE = ("SIGTERM", "SIGBREAK")  # a service manager's stop (POSIX); Ctrl-Break in a Windows console


def set_handler(name: str, handler: Callable[[int, Any], Any]) -> tuple[int, Any] | None:
    """Handle signal `name` with `handler`; (signal, previous handler), or None where this platform has
    no such signal or this thread may not set one."""
    number = getattr(signal, name, None)
    if number is None:
        return None
    try:
        return number, signal.signal(number, handler)
    except (ValueError, OSError, RuntimeError):  # not the main thread, or a signal the OS will not hand over
        return None


def name_of(signum: int) -> str:
    """"SIGTERM" for its number (a handler is handed a plain int)."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def set_terminate_handler(handler: Callable[[int, Any], Any]) -> None:
    """`handler` for every termination signal this platform has."""
    for name in TERMINATE:
        set_handler(name, handler)


@contextlib.contextmanager
def handled(handlers: dict[str, Callable[[int, Any], Any]]) -> Iterator[list[str]]:
    """Set the handlers that can be set, yield their names, and put the previous ones back."""
    saved = [(name, got) for name, handler in handlers.items() if (got := set_handler(name, handler))]
    try:
        yield [name for name, _ in saved]
    finally:
        for _, (number, previous) in reversed(saved):
            with contextlib.suppress(ValueError, OSError, RuntimeError, TypeError):
                # a handler set outside Python reads as None: the default is the nearest we can restore
                signal.signal(number, signal.SIG_DFL if previous is None else previous)
