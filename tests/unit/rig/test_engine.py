"""The engine with tiny fake devices and steps: every exit path ends safe, holds retake, events recorded."""

from __future__ import annotations

import logging
import os
import signal
from types import SimpleNamespace

import pytest

from drivers.clock import SimClock
from rig.core.errors import DeviceTimeout
from rig.engine.commands import (
    ABORTED,
    COMPLETED,
    FAILED,
    AddTasks,
    Checkpoint,
    CollectPoint,
    Event,
    Hold,
    MoveField,
    RequestStop,
    SetChamber,
    Task,
)
from rig.engine.executor import Engine
from rig.session.events import Kind, Reason
from rig.session.reader import SessionReader
from rig.session.writer import Session


def session_tables(path) -> dict:
    with SessionReader(path) as r:
        return {"session": r.info(), "points": r.points(), "events": r.events()}


class FakeDevice:
    def __init__(self, name: str, fail_safe: bool = False):
        self.name = name
        self.safe_calls = 0
        self.fail_safe = fail_safe

    def safe_state(self) -> None:
        self.safe_calls += 1
        if self.fail_safe:
            raise OSError("bus gone")


class RecordingSession:
    """A real session file (rig.session.writer) with helpers to read back what the engine recorded."""

    def __init__(self, path, ids):
        points = [SimpleNamespace(id=pid, index=i, temp_index=1, setpoint_c=25.0, field_index=i + 1,
                                  target={"field_nt": [1.0, 0.0, 0.0]}) for i, pid in enumerate(ids)]
        self.path = path
        self.store = Session.create(path, plan_text="p", station_text="s", plan_name="p", station_name="s",
                                    points=points, simulated={"coils": True}, clock=SimClock())

    def __getattr__(self, name):
        return getattr(self.store, name)

    @property
    def events(self) -> list[tuple[str, str, dict]]:
        return [(e.kind, e.message, {**e.data, "device": e.device})
                for e in session_tables(self.path)["events"]]

    @property
    def points(self) -> list[str]:
        """Done points, in plan order."""
        return [r["id"] for r in session_tables(self.path)["points"] if r["state"] == "done"]

    @property
    def finished(self) -> tuple[str, str] | None:
        s = session_tables(self.path)["session"]
        return None if s["exit_status"] is None else (s["exit_status"], s["exit_reason"])

    def kinds(self) -> list[str]:
        return [k for k, _, _ in self.events]


class Rig:
    """Handlers over fake devices; `faults` maps point id -> exceptions to raise on successive takes."""

    def __init__(self, session: RecordingSession, faults=None, on_collect=None):
        self.session = session
        self.coils = FakeDevice("coils")
        self.chamber = FakeDevice("chamber")
        self.devices = [self.coils, self.chamber]
        self.faults = {k: list(v) for k, v in (faults or {}).items()}
        self.on_collect = on_collect
        self.commands: list[object] = []
        self.takes: list[tuple[str, bool]] = []

    def handle(self, command):
        self.commands.append(command)
        if isinstance(command, CollectPoint):
            pending = self.faults.get(command.point)
            if pending:
                raise pending.pop(0)
            self.session.record_point(command.point, [])
            if self.on_collect:
                self.on_collect(command.point)
        return None

    def handlers(self):
        return {c: self.handle for c in (SetChamber, MoveField, CollectPoint, Checkpoint)}

    def steps(self, ids):
        def make(pid):
            def gen(retake):
                self.takes.append((pid, retake))
                yield SetChamber(25.0)
                yield MoveField((1.0, 0.0, 0.0))
                yield CollectPoint(pid)
                yield Checkpoint(pid)
            return gen
        return [Task(pid, make(pid)) for pid in ids]


def make_engine(rig: Rig, session: RecordingSession, **kw) -> Engine:
    kw.setdefault("hold_wait_s", 30.0)
    return Engine(rig.handlers(), devices=rig.devices, clock=SimClock(), session=session, **kw)


IDS = ["T01-F01", "T01-F02", "T02-F01", "T02-F02"]


@pytest.fixture
def new_session(tmp_path):
    made = []

    def make():
        session = RecordingSession(tmp_path / f"s{len(made)}.session", IDS)
        made.append(session)
        return session

    yield make
    for session in made:
        session.close()


def test_completed_run_takes_every_point_once_and_ends_safe(new_session):
    session = new_session()
    rig = Rig(session)
    result = make_engine(rig, session).run(rig.steps(IDS))
    assert result.status == COMPLETED and result.points_done == 4
    assert session.points == IDS
    assert session.finished[0] == COMPLETED
    assert rig.coils.safe_calls == 1 and rig.chamber.safe_calls == 1
    assert session.kinds()[-2:] == ["safe_state", "exit"]


def test_resume_skips_done_points(new_session):
    session = new_session()
    rig = Rig(session)
    result = make_engine(rig, session).run(rig.steps(IDS), done_ids={"T01-F01", "T01-F02"})
    assert session.points == ["T02-F01", "T02-F02"]
    assert result.points_done == 4


def test_hold_retakes_the_point_with_resettle_then_continues(new_session):
    session = new_session()
    rig = Rig(session, faults={"T01-F02": [Hold("chamber alarm"), DeviceTimeout("dut1", "read", "no reply")]})
    engine = make_engine(rig, session, max_retakes=3)
    clock = engine.clock
    t0 = clock.now()
    result = engine.run(rig.steps(IDS))
    assert result.status == COMPLETED
    assert session.points == IDS  # retaken point recorded once
    assert rig.takes.count(("T01-F02", True)) == 2
    holds = [m for k, m, _ in session.events if k == "hold"]
    assert len(holds) == 2 and "chamber alarm" in holds[0] and "dut1: read" in holds[1]
    assert clock.now() - t0 >= 2 * 30.0  # held on the clock before each retake


def test_too_many_retakes_abort_with_the_reason_and_end_safe(new_session):
    session = new_session()
    rig = Rig(session, faults={"T02-F01": [Hold("DUT temperature out of band")] * 5})
    result = make_engine(rig, session, max_retakes=2).run(rig.steps(IDS))
    assert result.status == ABORTED
    assert "T02-F01" in result.reason and "out of band" in result.reason
    assert session.points == ["T01-F01", "T01-F02"]
    assert session.finished == (ABORTED, result.reason)
    assert rig.coils.safe_calls == 1 and rig.chamber.safe_calls == 1


def test_pause_makes_safe_then_resume_retakes_the_interrupted_point(new_session):
    session = new_session()
    answers = []
    engine_box = {}

    def ctrl_c_after_first(pid):
        if pid == "T01-F01":
            engine_box["engine"].request_pause()  # what the SIGINT handler calls

    rig = Rig(session, on_collect=ctrl_c_after_first)

    def prompt(message):
        answers.append(message)
        return "resume"

    engine = make_engine(rig, session, prompt=prompt)
    engine_box["engine"] = engine
    result = engine.run(rig.steps(IDS))
    assert result.status == COMPLETED
    assert session.points == IDS  # the point before the pause is kept, nothing twice
    assert len(answers) == 1 and "T01-F02" in answers[0]
    # safe on pause, and again at the end
    assert rig.coils.safe_calls == 2 and rig.chamber.safe_calls == 2
    assert ["pause", "safe_state", "resume"] == [k for k in session.kinds() if k in
                                                  ("pause", "resume", "safe_state")][:3]
    assert ("T01-F02", True) in rig.takes  # resumed with a re-settle


def test_pause_without_prompt_aborts_cleanly(new_session):
    session = new_session()
    engine_box = {}
    rig = Rig(session, on_collect=lambda pid: engine_box["engine"].request_pause())
    engine = make_engine(rig, session, prompt=None)
    engine_box["engine"] = engine
    result = engine.run(rig.steps(IDS))
    assert result.status == ABORTED
    assert session.points == ["T01-F01"]
    assert session.finished[0] == ABORTED
    assert rig.coils.safe_calls >= 1 and rig.chamber.safe_calls >= 1


def test_sigterm_style_abort_stops_before_the_next_command(new_session):
    session = new_session()
    engine_box = {}
    rig = Rig(session, on_collect=lambda pid: engine_box["engine"].request_abort("SIGTERM"))
    engine = make_engine(rig, session)
    engine_box["engine"] = engine
    result = engine.run(rig.steps(IDS))
    assert (result.status, result.reason) == (ABORTED, "SIGTERM")
    assert session.points == ["T01-F01"]
    assert not any(isinstance(c, SetChamber) for c in rig.commands[4:])


def test_unexpected_error_fails_the_run_and_one_failing_device_does_not_skip_the_others(new_session):
    session = new_session()
    rig = Rig(session, faults={"T01-F01": [ZeroDivisionError("bug")]})
    rig.coils.fail_safe = True
    result = make_engine(rig, session).run(rig.steps(IDS))
    assert result.status == FAILED and "ZeroDivisionError" in result.reason
    assert rig.chamber.safe_calls == 1
    safe_events = [m for k, m, _ in session.events if k == "safe_state"]
    assert "FAILED on coils" in safe_events[-1]


def test_magrig_warnings_become_session_events_during_the_run(new_session):
    session = new_session()

    def warn(pid):
        logging.getLogger("magrig.transport").warning("dut1: read: try 1 of 3 failed",
                                                      extra={"device": "dut1"})
        logging.getLogger("other").warning("not ours")

    rig = Rig(session, on_collect=warn)
    make_engine(rig, session).run(rig.steps(IDS[:1]))
    warnings = [(m, d) for k, m, d in session.events if k == "warning"]
    assert warnings == [("dut1: read: try 1 of 3 failed", {"logger": "magrig.transport", "device": "dut1"})]
    # the handler is detached after the run
    logging.getLogger("magrig.transport").warning("after")
    assert len([k for k in session.kinds() if k == "warning"]) == 1


@pytest.mark.parametrize("answer", ["abort", "anything"])
def test_only_resume_resumes(new_session, answer):
    session = new_session()
    engine_box = {}
    rig = Rig(session, on_collect=lambda pid: engine_box["engine"].request_pause())
    engine = make_engine(rig, session, prompt=lambda m: answer)
    engine_box["engine"] = engine
    assert engine.run(rig.steps(IDS)).status == ABORTED


def test_a_real_sigint_pauses_at_the_next_safe_point_instead_of_raising(new_session, default_sigint):
    session = new_session()
    prompts = []

    def ctrl_c(pid):
        if pid == "T01-F01":
            os.kill(os.getpid(), signal.SIGINT)

    rig = Rig(session, on_collect=ctrl_c)
    engine = make_engine(rig, session, prompt=lambda m: prompts.append(m) or "resume")
    assert engine.run(rig.steps(IDS)).status == COMPLETED
    assert len(prompts) == 1 and session.points == IDS
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handlers restored


def test_holds_and_faults_are_stored_typed_and_the_report_reads_their_codes(new_session):
    from rig.core.errors import LimitError
    from rig.report.sources import from_session
    from rig.session.events import Kind, Reason
    from rig.session.rows import SampleRow

    session = new_session()
    rig = Rig(session, faults={
        "T01-F02": [Hold("whatever words", code=Reason.STABILITY_TIMEOUT, device="dut7"),
                    DeviceTimeout("coils", "read", "no reply")],
        "T02-F02": [LimitError("coils: 3.1 A exceeds max_current_a 2.0")],
    })
    row = SampleRow("dut7", 0.0, (1.0, 2.0, 3.0), (1.0, 2.0, 3.0), temp_c=25.0)
    rig.session.record_point = lambda pid, rows, *a, **k: session.store.record_point(pid, [row])
    result = make_engine(rig, session).run(rig.steps(IDS))
    assert (result.status, result.code) == (FAILED, Reason.LIMIT_REFUSED)
    with SessionReader(session.path) as r:
        typed = [(e.kind, e.code, e.point_id, e.device) for e in r.events()
                 if e.kind in (Kind.HOLD, Kind.FAULT)]
        assert r.info()["exit_code"] == "limit_refused"
    assert typed == [("hold", Reason.STABILITY_TIMEOUT, "T01-F02", "dut7"),
                     ("hold", Reason.DEVICE_TIMEOUT, "T01-F02", "coils"),
                     ("fault", Reason.LIMIT_REFUSED, "T02-F02", None)]
    inputs = from_session(session.path)
    assert inputs.steps[1].settle_timeouts == 1
    warnings = " | ".join(inputs.warnings)
    assert "1 settle timeout(s): T01-F02 (dut7: settle timeout)" in warnings
    assert "1 hold(s) during the run: T01-F02 (coils: device timeout)" in warnings
    assert "whatever words" not in warnings


def test_tasks_added_during_the_run_are_run_in_order_and_counted(new_session):
    """A schedule decided during the run (rig/schedules/sequential_run.py) yields its next points after a
    checkpoint (AddTasks), and its decision as an Event: the engine runs both itself."""
    session = new_session()
    extra = ["T03-F01", "T03-F02"]
    rig = Rig(session)
    engine = make_engine(rig, session)

    def deciding(pid):
        def gen(retake):
            yield from rig.steps([pid])[0].make(retake)
            if pid == IDS[-1]:
                # the planned rows the real schedule stores with its decision
                session.store._conn.executemany(
                    "INSERT INTO points (id, idx, temp_index, setpoint_c, field_index, target_json) "
                    "VALUES (?, ?, 3, 25.0, ?, '{}')", [(p, 4 + i, i + 1) for i, p in enumerate(extra)])
                yield AddTasks(tuple(rig.steps(extra)))
                yield Event(Kind.DECISION, "two more points", Reason.DECIDED, pid)
        return gen

    result = engine.run([Task(pid, deciding(pid)) for pid in IDS])
    assert result.status == COMPLETED and result.points_done == 6
    assert session.points == IDS + extra
    assert engine.status.points_total == 6 and "all 6 points taken" in result.reason
    assert any("two more points" in e for e in engine.status.events)


def test_a_stop_requested_by_a_task_ends_the_run_completed_after_its_point(new_session):
    session = new_session()
    rig = Rig(session)
    engine = make_engine(rig, session)

    def stopping(pid):
        def gen(retake):
            yield from rig.steps([pid])[0].make(retake)
            if pid == IDS[1]:
                yield RequestStop("targets met", Reason.TARGETS_MET)
        return gen

    result = engine.run([Task(pid, stopping(pid)) for pid in IDS])
    assert result.status == COMPLETED and result.code == Reason.TARGETS_MET
    assert session.points == IDS[:2] and result.reason == "targets met"
