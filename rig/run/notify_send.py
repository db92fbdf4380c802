"""Sending word to the operator, off the engine's thread: a bounded queue and one background thread that
hands each message to Apprise, one URL at a time, so one dead address neither hides nor delays the others'
outcome.

    outbox = Outbox(send=AppriseSend(urls), done=on_done)   # done(message, [(url_shown, error | None)])
    outbox.put(message) -> bool       # False: the queue is full (the message is dropped, never waited for)
    outbox.close(timeout_s)           # what is queued goes out (within timeout_s), then the thread ends

Apprise is imported when the first message goes out. A URL is shown only in Apprise's privacy form
(passwords and tokens masked): the outcome is recorded in the session and read in the cockpit.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass

QUEUE_SIZE = 64  # messages waiting; a run that produces more than this at once has bigger news
ERROR_CHARS = 300  # of Apprise's own account of a failure, kept in the record

# Outside "magrig": the session records each failure as its own notify event; the engine's log handler
# would copy a "magrig" record a second time.
log = logging.getLogger("rig.notify")


@dataclass(frozen=True)
class Message:
    topic: str  # hold, fault, pause, abort, completed, stalled
    title: str
    body: str
    kind: str = "info"  # Apprise's notify type: info, success, warning, failure
    event_id: int | None = None  # the session event it tells of (None: a stall)
    held_back: int = 0  # messages of its topic not sent since the last one


class AppriseSend:
    """`send(message)` -> [(url as shown, error or None)] for each URL."""

    def __init__(self, urls: list[str]):
        self.urls = list(urls)
        self._servers = None

    def _load(self) -> list:
        if self._servers is None:
            import apprise

            servers = []
            for url in self.urls:
                one = apprise.Apprise()
                one.add(url)  # checked when the plan or station was read (rig/config/notify.py)
                servers.append(one)
            self._servers = servers
        return self._servers

    def __call__(self, message: Message) -> list[tuple[str, str | None]]:
        import apprise

        out = []
        for server in self._load():
            # privacy form (secrets masked), without the query: Apprise's own defaults, noise in a record
            shown = server[0].url(privacy=True).split("?", 1)[0] if len(server) else "(a refused address)"
            try:
                with apprise.LogCapture(level=logging.WARNING) as said:
                    ok = bool(server.notify(title=message.title, body=message.body, notify_type=message.kind,
                                            body_format=apprise.NotifyFormat.TEXT))
                error = None if ok else _one_line(said.getvalue()) or "not sent"
            except Exception as exc:  # a plugin's own bug: an outcome like any other
                error = _one_line(f"{type(exc).__name__}: {exc}")
            out.append((shown, error))
        return out


def _one_line(text: str) -> str:
    lines = [line.split(" - ", 2)[-1].strip() for line in text.splitlines() if line.strip()]
    return "; ".join(lines)[:ERROR_CHARS]


class Outbox:
    """One thread sending queued messages; `idle()` runs between them (and every `poll_s` of wall time
    without one), for what must be noticed even when nothing is written (a hung run's stall)."""

    def __init__(self, send: Callable[[Message], list[tuple[str, str | None]]],
                 done: Callable[[Message, list[tuple[str, str | None]]], None],
                 idle: Callable[[], None] | None = None, size: int = QUEUE_SIZE, poll_s: float = 5.0):
        self.send, self.done, self.idle = send, done, idle
        self.poll_s = poll_s
        self.dropped = 0
        self._queue: queue.Queue = queue.Queue(maxsize=size)
        self._thread = threading.Thread(target=self._work, name="notify", daemon=True)
        self._thread.start()

    def put(self, message: Message) -> bool:
        try:
            self._queue.put_nowait(message)
            return True
        except queue.Full:
            self.dropped += 1
            log.warning("notify: queue full, %s message dropped: %s", message.topic, message.title)
            return False

    def _work(self) -> None:
        while True:
            try:
                message = self._queue.get(timeout=self.poll_s)
            except queue.Empty:
                message = ...
            if message is None:
                return
            try:
                if message is not ...:
                    self.done(message, self.send(message))
                if self.idle is not None:
                    self.idle()
            except Exception:  # a failure here must not end the thread: the next message still goes
                log.exception("notify: could not handle a message")

    def close(self, timeout_s: float = 60.0) -> bool:
        """Send what is queued, then stop; False when that took longer than `timeout_s` (the thread is a
        daemon: the process can end regardless)."""
        try:
            self._queue.put(None, timeout=timeout_s)
        except queue.Full:
            return False
        self._thread.join(timeout_s)
        return not self._thread.is_alive()
