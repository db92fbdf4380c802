"""Word to the operator (`notify:` of the plan, else of the station: rig/config/notify.py): a subscriber to
the session's writes (Session.subscribe), like the live display and the cockpit, that sends a message

    on a hold, a fault (a run given up, a device that would not go safe), a pause, an abort or a failed run,
    on completion (with each DUT's acceptance verdict when the plan has `acceptance:`),
    and when no point has been recorded for `stalled_after_min` minutes of the run's clock.

    with watching(session, plan, station): ...    # rig/run/campaign.py, around the run

Never in the engine's way: messages wait in a bounded queue for a background thread (rig/run/notify_send.py);
a failure to send is logged and recorded, never raised. At most one message of each kind per
`repeat_after_min` (the run's clock); those held back are counted in the next one. A completion or an abort
is never held back.

What was told is recorded in the session: one `notify` event per event told of (`event_id`; sent, held
back or failed). A resumed run first tells what the run before it recorded but never got to tell (it was
killed first), and never what it told: the records are checked, so nothing is sent twice.
"""

from __future__ import annotations

import contextlib
import threading
from typing import Any

from rig.run.notify_send import AppriseSend, Message, Outbox, log
from rig.session.events import Event, Kind, Reason

NEVER_HELD_BACK = ("completed", "abort")
CLOSE_TIMEOUT_S = 60.0  # the last messages of a run (its completion) get this long to go out
_TITLES = {"hold": "hold", "fault": "fault", "pause": "paused", "abort": "run stopped", "stalled": "stalled",
           "completed": "completed"}
_KINDS = {"hold": "warning", "fault": "failure", "pause": "info", "abort": "failure", "stalled": "warning",
          "completed": "success"}


def topic_of(event: Event) -> str | None:
    """What an event is worth telling the operator as (None: nothing)."""
    if event.kind == Kind.HOLD:
        return "hold"
    if event.kind == Kind.FAULT or (event.kind == Kind.SAFE_STATE and event.code == Reason.SAFE_STATE_FAILED):
        return "fault"
    if event.kind == Kind.PAUSE:
        return "pause"
    if event.kind == Kind.EXIT:
        return "completed" if event.data.get("status") == "completed" else "abort"
    return None


def notify_config(plan, station):
    """The plan's `notify:` when it has one, else the station's (None: no word to anyone)."""
    return plan.notify if plan.notify is not None else station.notify


@contextlib.contextmanager
def watching(session, plan, station, send=None):
    """A Notifier on `session` for the run inside the block (nothing without a `notify:`)."""
    config = notify_config(plan, station)
    if config is None:
        yield None
        return
    notifier = Notifier(session, config, station_name=station.name, plan_name=plan.name,
                        send=send or AppriseSend(config.urls))
    notifier.start()
    try:
        yield notifier
    finally:
        notifier.close()


class Notifier:
    def __init__(self, session, config, *, station_name: str = "", plan_name: str = "", send=None,
                 queue_size: int | None = None, poll_s: float = 5.0):
        self.session = session
        self.clock = session.clock
        self.config = config
        self.where = f"station {station_name}, plan {plan_name}, session {session.path.name}"
        self.send = send or AppriseSend(config.urls)
        self.queue_size = queue_size
        self.poll_s = poll_s
        self.outbox: Outbox | None = None
        self._lock = threading.RLock()
        self._told: set[int] = set()  # event ids with a record
        self._last_sent_t: dict[str, float] = {}
        self._held_back: dict[str, int] = {}
        self._completion: Event | None = None
        self._verdicts: list[str] = []
        self._progress_t = self.clock.now()
        self._last_point: str | None = None
        self._stall_told = False
        self._latest = ""  # the latest event's message, for a stall's word
        self._closed = False

    # --- life -------------------------------------------------------------------------------------
    def start(self) -> None:
        """Read what earlier runs told, tell what the last one never got to, then follow the session."""
        kw: dict[str, Any] = {} if self.queue_size is None else {"size": self.queue_size}
        self.outbox = Outbox(self.send, self._done, idle=self._check_stall, poll_s=self.poll_s, **kw)
        for event in self._untold_of_the_last_run():
            self._consider(event, earlier=True)
        self.session.subscribe(self)

    def close(self) -> None:
        """Tell the completion (with the verdicts recorded since), then let the queue go out."""
        self.session.unsubscribe(self)
        with self._lock:
            self._closed = True  # no stall is noticed any more: the run is over
            if self._completion is not None:
                self._queue(self._message("completed", self._completion, self._completion_body()))
                self._completion = None
        if self.outbox is not None and not self.outbox.close(CLOSE_TIMEOUT_S):
            log.warning("notify: the last messages did not go out within %.0f s", CLOSE_TIMEOUT_S)

    def _untold_of_the_last_run(self) -> list[Event]:
        from rig.session.reader import SessionReader

        with SessionReader(self.session.path) as reader:
            events = reader.events()
        for e in events:
            if e.kind == Kind.NOTIFY and isinstance(e.data.get("event_id"), int):
                self._told.add(e.data["event_id"])
        starts = [i for i, e in enumerate(events) if e.kind == Kind.START]
        last_run = events[starts[-1]:] if starts else []
        return [e for e in last_run if e.id not in self._told and topic_of(e) is not None]

    # --- the session's writes (Session.subscribe) ---------------------------------------------------
    def session_wrote(self, what: str, item) -> None:
        with self._lock:
            if what == "point":
                self._progress_t, self._last_point, self._stall_told = self.clock.now(), item, False
            elif what == "event" and item.kind != Kind.NOTIFY:
                self._latest = item.message
                if item.kind == Kind.ACCEPTANCE:
                    self._verdicts.append(item.message)
                else:
                    self._consider(item)
            self._check_stall()

    def _consider(self, event: Event, earlier: bool = False) -> None:
        topic = topic_of(event)
        if topic is None or event.id in self._told:
            return
        self._told.add(event.id)
        if topic == "completed" and not earlier:
            self._completion = event  # told at close(): the fits and verdicts come after the engine ends
            return
        body = event.message + (" (recorded by the run before this one)" if earlier else "")
        self._queue(self._message(topic, event, body))

    def _check_stall(self) -> None:
        minutes = self.config.stalled_after_min
        with self._lock:
            idle_s = self.clock.now() - self._progress_t
            if minutes is None or self._closed or self._stall_told or idle_s < minutes * 60.0:
                return
            self._stall_told = True
            since = f"since point {self._last_point}" if self._last_point else "since the run started"
            body = (f"no point recorded for {idle_s / 60.0:.0f} min of the run's clock ({since}); latest: "
                    f"{self._latest or 'nothing'}")
            self._queue(Message("stalled", self._title("stalled"), self._footer(body, None),
                                _KINDS["stalled"]))

    # --- messages ----------------------------------------------------------------------------------
    def _message(self, topic: str, event: Event, body: str) -> Message:
        kind = _KINDS[topic]
        if topic == "completed" and any(" FAIL" in v for v in self._verdicts):
            kind = "warning"
        return Message(topic, self._title(topic, event), self._footer(body, event.id), kind, event.id)

    def _title(self, topic: str, event: Event | None = None) -> str:
        what = _TITLES[topic]
        if topic == "abort" and event is not None:
            what = f"run {event.data.get('status') or 'stopped'}"
        return f"magrig {self.session.path.stem}: {what}"

    def _footer(self, body: str, event_id: int | None) -> str:
        return body + f"\n\n{self.where}" + (f", event {event_id}" if event_id is not None else "")

    def _completion_body(self) -> str:
        event = self._completion
        lines = [event.message]
        if self._verdicts:
            lines += ["", "acceptance:"] + [f"  {v}" for v in self._verdicts]
        return "\n".join(lines)

    def _queue(self, message: Message) -> None:
        """Into the outbox, or held back (recorded as such) when one of its topic went out lately."""
        now = self.clock.now()
        last = self._last_sent_t.get(message.topic)
        if (message.topic not in NEVER_HELD_BACK and last is not None
                and now - last < self.config.repeat_after_min * 60.0):
            self._held_back[message.topic] = self._held_back.get(message.topic, 0) + 1
            self._record(message, Reason.NOTIFY_HELD_BACK, "INFO",
                         f"not sent ({message.topic}: one went out {(now - last) / 60.0:.1f} min ago): "
                         f"{message.title}")
            return
        held = self._held_back.pop(message.topic, 0)
        if held:
            note = f"\n({held} more {message.topic} message(s) held back since the last one)"
            message = Message(message.topic, message.title, message.body + note, message.kind,
                              message.event_id, held)
        self._last_sent_t[message.topic] = now
        if not self.outbox.put(message):
            self._record(message, Reason.NOTIFY_FAILED, "WARNING", f"not sent (queue full): {message.title}")

    def _done(self, message: Message, results: list[tuple[str, str | None]]) -> None:
        """In the outbox's thread: the outcome, recorded in the session and logged when it failed."""
        failed = [(url, error) for url, error in results if error]
        for url, error in failed:
            log.warning("notify: could not send %s to %s: %s", message.topic, url, error)
        sent = len(results) - len(failed)
        if failed:
            text = (f"{message.title}: sent to {sent} of {len(results)}; failed: "
                    + "; ".join(f"{url}: {error}" for url, error in failed))
            self._record(message, Reason.NOTIFY_FAILED, "WARNING", text, failed=dict(failed))
        else:
            self._record(message, Reason.NOTIFIED, "INFO", f"told the operator ({sent} address(es)): "
                         f"{message.title}")

    def _record(self, message: Message, code: Reason, level: str, text: str, **data) -> None:
        try:
            self.session.log_event(Kind.NOTIFY, text, code=code, level=level, topic=message.topic,
                                   event_id=message.event_id, held_back=message.held_back, **data)
        except Exception as exc:  # a full disk: the message went (or not) all the same
            log.warning("notify: could not record %s in the session: %s", message.topic, exc)
