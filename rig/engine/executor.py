"""The run engine: executes campaign tasks written as plain generators, and alone decides pause, resume,
abort, holds and the final safe state.

A task is one point of the plan (`Task(point_id, make)`); `make(retake)` returns a generator that yields
small commands (rig/engine/commands.py) and receives each command's result. The engine runs the ones that
concern the run itself (AddTasks, Event, RequestStop) and looks any other command's type up in its
`handlers` (the rig-aware code in rig/run/). Tasks never catch Ctrl-C, never call safe_state() and never
record exit status: that is the engine's job, so every exit path is the same.

- Ctrl-C (SIGINT) asks for a pause; the engine takes it at the next safe point (a command boundary, or a
  poll inside a long wait), puts every device in its safe state, and asks `prompt` whether to resume or
  abort (no prompt: abort). A resumed point starts again from its first command (nothing of it was
  recorded: a point is stored in one transaction). A second Ctrl-C, or SIGTERM, aborts.
- Requests from outside the process (the cockpit's pause and abort, rig/session/inbox.py) are read at the same
  checks and take the same path; each is recorded as an event naming where it came from. A requested
  pause with nobody at a prompt ends the run there, to be continued with `rig run --resume`.
- A `Hold` (chamber alarm, DUT temperature out of band) or a `DeviceError` (a fault that survived the
  transport's retries) holds the run: the engine logs it, waits `hold_wait_s`, and retakes the point with
  `retake=True` (the task then re-settles). After `max_retakes` retakes of one point it aborts with the
  reason.
- Whatever happens (completion, abort, an unexpected exception), every device gets safe_state() and the
  session records the exit status and reason.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from drivers.base import make_all_safe
from drivers.clock import Clock
from rig.core.errors import ERRORS, DeviceError, MagrigError
from rig.core.signals import TERMINATE, handled, name_of
from rig.engine.commands import (
    ABORTED,
    COMPLETED,
    FAILED,
    AddTasks,
    CollectPoint,
    Event,
    Hold,
    RequestStop,
    Task,
)
from rig.session.events import Kind, Reason, code_of, device_of

log = logging.getLogger("magrig.engine")



class SessionLike(Protocol):
    def log_event(self, kind: str, message: str, **data: Any) -> None: ...

    def finish(self, status: str, reason: str, *, code: Reason | None = None) -> None: ...


@dataclass
class RunResult:
    status: str
    reason: str
    points_done: int
    code: Reason = Reason.UNKNOWN  # why the run ended (Reason.COMPLETED when it did)


@dataclass
class RunStatus:
    """What the live display shows; the handlers update it as they go."""

    point_id: str = ""
    command: str = ""  # the command being run, or "paused" / "hold: ..."
    points_done: int = 0
    points_total: int = 0
    chamber_c: float | None = None
    dut_temps_c: dict[str, float] = field(default_factory=dict)
    thermal: str = ""  # what the chamber and the DUT temperatures are doing
    events: deque = field(default_factory=lambda: deque(maxlen=8))
    started_t: float | None = None
    point_durations_s: deque = field(default_factory=lambda: deque(maxlen=20))


class _Pause(Exception):
    pass


class _Abort(Exception):
    def __init__(self, message: str, code: Reason):
        super().__init__(message)
        self.code = code


class Engine:
    """Runs tasks; see the module docstring for the rules it enforces."""

    def __init__(
        self,
        handlers: Mapping[type, Callable[[Any], Any]],
        *,
        devices: Iterable[Any],
        clock: Clock,
        session: SessionLike,
        prompt: Callable[[str], str] | None = None,
        max_retakes: int = 3,
        hold_wait_s: float = 60.0,
        status: RunStatus | None = None,
        inbox: Any = None,
    ):
        self.handlers = dict(handlers)
        self.devices = list(devices)
        self.clock = clock
        self.session = session
        self.prompt = prompt
        self.max_retakes = max_retakes
        self.hold_wait_s = hold_wait_s
        self.status = status or RunStatus()
        self.log_handler: SessionLogHandler | None = None
        self._pause_requested = threading.Event()
        self._abort_reason: str | None = None
        self._abort_code = Reason.OPERATOR_ABORT
        self._prompting = False
        self._events_lost = 0
        self._stop: tuple[str, Reason] | None = None  # end early as completed (stop_when targets met)
        self.inbox = inbox  # rig.session.inbox.Inbox: requests from outside the process, or None
        self._pause_source: str | None = None  # who asked for the pending pause, when not Ctrl-C
        self._todo: list[Task] = []
        # the commands that concern the run itself; every other command goes to the rig's handlers
        self.own = {AddTasks: self.add_tasks, Event: self.record_event, RequestStop: self.request_stop}

    # --- requests (signal handlers and tests call these) -----------------------------------------
    def request_pause(self) -> None:
        if self._prompting:
            raise KeyboardInterrupt  # Ctrl-C at the pause prompt means abort
        if self._pause_requested.is_set():
            self.request_abort("second Ctrl-C")
        else:
            self._pause_requested.set()

    def request_abort(self, reason: str, code: Reason = Reason.OPERATOR_ABORT) -> None:
        if self._abort_reason is None:
            self._abort_reason = reason
            self._abort_code = code
        if self._prompting:
            raise KeyboardInterrupt  # stop waiting for the operator's answer

    def add_tasks(self, cmd: AddTasks) -> None:
        """Append tasks to the running list (a schedule decided during the run,
        rig/schedules/sequential_run.py)."""
        self._todo.extend(cmd.tasks)
        self.status.points_total += len(cmd.tasks)

    def request_stop(self, cmd: RequestStop) -> None:
        """End the run after the current task as completed although points remain (good enough)."""
        self._stop = (cmd.message, cmd.code)

    def record_event(self, cmd: Event) -> None:
        self.event(cmd.kind, cmd.message, code=cmd.code, point_id=cmd.point_id, **cmd.data)

    def check_interrupt(self) -> None:
        """Called between commands and by long handlers at every poll: raises to pause or abort."""
        if self.log_handler is not None:
            self.log_handler.flush_pending()
        if self.inbox is not None:
            self._take_request()
        if self._abort_reason is not None:
            raise _Abort(self._abort_reason, self._abort_code)
        if self._pause_requested.is_set():
            raise _Pause()

    def _take_request(self) -> None:
        """A pause or abort left by the cockpit: recorded with its source, then handled as Ctrl-C is."""
        request = self.inbox.take()
        if request is None:
            return
        abort = request.action == "abort"
        self.event(Kind.REQUEST, f"{'abort' if abort else 'pause at the next safe point'} requested by "
                   f"{request.source}", code=Reason.OPERATOR_ABORT if abort else Reason.OPERATOR_PAUSE,
                   point_id=self.status.point_id or None, source=request.source, request_id=request.id)
        if abort:
            self.request_abort(f"abort requested by {request.source}")
        elif not self._pause_requested.is_set():
            self._pause_source = request.source
            self._pause_requested.set()

    def wait(self, seconds: float, poll_s: float = 5.0) -> None:
        """Wait on the clock in slices, staying responsive to pause and abort."""
        end = self.clock.now() + seconds
        while (left := end - self.clock.now()) > 0:
            self.check_interrupt()
            self.clock.sleep(min(poll_s, left))
        self.check_interrupt()

    def event(self, kind: Kind, message: str, *, code: Reason, point_id: str | None = None,
              device: str | None = None, **data: Any) -> None:
        """Record an event (kind, reason code, point, device, message) in the session and the live status."""
        self.status.events.append(f"{kind}: {message}")
        try:
            self.session.log_event(kind, message, code=code, point_id=point_id, device=device, **data)
        except Exception as exc:  # the session must not take the run down with it
            self._events_lost += 1
            if self._events_lost == 1:  # a full disk fails every write: say it once
                log.warning("could not record events in the session: %s", exc)

    # --- running ----------------------------------------------------------------------------------
    def run(self, tasks: Iterable[Task], done_ids: Iterable[str] = ()) -> RunResult:
        """Run every task whose point is not in `done_ids`; always ends with safe_state() everywhere."""
        tasks = list(tasks)
        done = set(done_ids)
        todo = self._todo = [t for t in tasks if t.point_id not in done]  # add_tasks() may extend it
        self.status.points_total = len(tasks)
        self.status.points_done = len(tasks) - len(todo)
        self.status.started_t = self.clock.now()
        status, reason, code = FAILED, "not started", Reason.SOFTWARE_ERROR
        self.log_handler = SessionLogHandler(self.session)
        magrig_log = logging.getLogger("magrig")
        magrig_log.addHandler(self.log_handler)
        with _signals_to(self):
            try:
                self.event(Kind.RUN, f"{len(todo)} of {len(tasks)} points to take", code=Reason.STARTED)
                next_task = 0
                while next_task < len(todo) and self._stop is None:
                    self._run_point(todo[next_task])
                    next_task += 1
                status, reason = COMPLETED, f"all {self.status.points_total} points taken"
                code = Reason.COMPLETED
                if self._stop is not None:
                    reason, code = self._stop
            except _Abort as exc:
                status, reason, code = ABORTED, str(exc), exc.code
            except KeyboardInterrupt:
                status, reason, code = ABORTED, "interrupted", Reason.OPERATOR_ABORT
            except Exception as exc:
                reason = str(exc) if isinstance(exc, ERRORS) else f"{type(exc).__name__}: {exc}"
                status, code = FAILED, code_of(exc)
                log.error("run failed: %s", reason)
                self.event(Kind.FAULT, reason, code=code, point_id=self.status.point_id or None,
                           device=device_of(exc))
            finally:
                self.make_safe()
                self.event(Kind.EXIT, f"{status}: {reason}", code=code, status=status)
                magrig_log.removeHandler(self.log_handler)
                self.log_handler.flush_pending()
                self._finish(status, reason, code)
        return RunResult(status, reason, self.status.points_done, code)

    def _finish(self, status: str, reason: str, code: Reason) -> None:
        """Record the exit status where the disk allows; a failure here must not hide how the run ended."""
        try:
            if self._stop is not None and status == COMPLETED:  # the points left are not wanted
                self.session.finish(status, reason, code=code, completed=True)
            else:
                self.session.finish(status, reason, code=code)
        except Exception as exc:
            log.warning("could not record the exit status in the session: %s", exc)

    def make_safe(self) -> list[str]:
        """safe_state() on every device, each on its own (one failure must not skip the others).
        Returns the names of the devices that failed to go safe."""
        failed = make_all_safe(self.devices)
        self.event(Kind.SAFE_STATE, "all devices safe" if not failed else f"FAILED on {', '.join(failed)}",
                   code=Reason.SAFE_STATE_FAILED if failed else Reason.ALL_SAFE, failed=failed)
        return failed

    def _run_point(self, task: Task) -> None:
        retakes = 0
        retake = False
        while True:
            t0 = self.clock.now()
            try:
                self._run_generator(task, retake)
                self.status.points_done += 1
                self.status.point_durations_s.append(self.clock.now() - t0)
                return
            except _Pause:
                self._pause(task.point_id)
                retake = True  # the chamber was made safe: settle again
            except (Hold, DeviceError) as exc:
                retakes += 1
                if retakes > self.max_retakes:
                    reason = f"point {task.point_id}: {exc} (gave up after {self.max_retakes} retakes)"
                    self.event(Kind.FAULT, reason, code=Reason.RETAKES_EXHAUSTED, point_id=task.point_id,
                               device=device_of(exc), hold_code=code_of(exc).value)
                    raise _Abort(reason, Reason.RETAKES_EXHAUSTED) from exc
                self.event(Kind.HOLD, f"point {task.point_id}: {exc}; retake {retakes} of "
                           f"{self.max_retakes}", code=code_of(exc), point_id=task.point_id,
                           device=device_of(exc), retake=retakes)
                self.status.command = f"hold: {exc}"
                self.wait(self.hold_wait_s)
                retake = True

    def _run_generator(self, task: Task, retake: bool) -> None:
        self.status.point_id = task.point_id
        gen = task.make(retake)
        try:
            reply = None
            recorded = False  # after CollectPoint the point is stored: run to its end, never retake it
            while True:
                if not recorded:
                    self.check_interrupt()
                command = gen.send(reply)
                recorded = recorded or isinstance(command, CollectPoint)
                handler = self.own.get(type(command)) or self.handlers.get(type(command))
                if handler is None:
                    raise MagrigError(f"no handler for command {type(command).__name__}")
                self.status.command = type(command).__name__
                reply = handler(command)
        except StopIteration:
            return
        finally:
            gen.close()

    def _pause(self, point_id: str) -> None:
        source = self._pause_source
        self.event(Kind.PAUSE, f"paused at point {point_id} (not recorded yet)" +
                   (f" at the request of {source}" if source else ""), code=Reason.OPERATOR_PAUSE,
                   point_id=point_id, source=source or "Ctrl-C")
        self.status.command = "paused"
        self.make_safe()
        answer = "abort"
        if self.prompt is not None:
            self._prompting = True
            try:
                answer = self.prompt(f"paused at {point_id}: resume or abort?")
            except (KeyboardInterrupt, EOFError):
                answer = "abort"
            finally:
                self._prompting = False
        if answer != "resume" or self._abort_reason is not None:
            if self._abort_reason is None and self.prompt is None and source:
                raise _Abort(f"paused at {point_id} at the request of {source}; nobody here to answer "
                             "resume or abort, so the run ends here", Reason.OPERATOR_PAUSE)
            raise _Abort(self._abort_reason or f"operator aborted while paused at {point_id}",
                         self._abort_code)
        self._pause_requested.clear()
        self._pause_source = None
        self.event(Kind.RESUME, f"resuming at point {point_id}", code=Reason.OPERATOR_RESUME,
                   point_id=point_id)


class SessionLogHandler(logging.Handler):
    """Copies WARNING+ records of the "magrig" loggers (retries, faults) into the session's events; a
    retry's record is coded by its failure (Reason.DEVICE_TIMEOUT...), any other as Reason.LOGGED.

    SQLite connections belong to one thread: records from other threads (simulators, transports' helper
    threads) wait in a queue until the engine's thread flushes them at its next check."""

    def __init__(self, session: SessionLike):
        super().__init__(level=logging.WARNING)
        self.session = session
        self.owner = threading.get_ident()
        self.pending: deque[logging.LogRecord] = deque(maxlen=1000)

    def emit(self, record: logging.LogRecord) -> None:
        self.pending.append(record)
        if threading.get_ident() == self.owner:
            self.flush_pending()

    def flush_pending(self) -> None:
        if threading.get_ident() != self.owner:
            return
        while self.pending:
            record = self.pending.popleft()
            try:
                self.session.log_event(
                    record.levelname.lower(), record.getMessage(), code=_record_code(record),
                    logger=record.name, device=getattr(record, "device", None))
            except Exception:  # e.g. a full disk: the record still reached the console's handler
                pass


def _record_code(record: logging.LogRecord) -> Reason:
    """A transport's retry record carries the failure (`fault`): coded like a hold (device_timeout...)."""
    fault = getattr(record, "fault", None)
    return code_of(fault) if isinstance(fault, BaseException) else Reason.LOGGED


def _signals_to(engine: Engine):
    """While running: SIGINT asks for a pause, SIGTERM (Windows: SIGBREAK) for an abort; only where the
    platform has the signal and this is the main thread (rig/core/signals.py), elsewhere nothing."""
    def abort(signum, _frame):
        engine.request_abort(name_of(signum), Reason.TERMINATED)

    return handled({"SIGINT": lambda *_: engine.request_pause(), **dict.fromkeys(TERMINATE, abort)})


def prompt_from_tty(message: str) -> str:
    """Interactive pause prompt: 'r' resumes, anything else aborts."""
    answer = input(f"{message} [r/a] ").strip().lower()
    return "resume" if answer in ("r", "resume") else "abort"
