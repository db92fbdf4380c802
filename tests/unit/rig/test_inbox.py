"""The request channel from the cockpit to a run: a request reaches only the live run it is meant for,
once; the engine records who asked and handles it as it handles Ctrl-C."""

from __future__ import annotations

import json
import os

import pytest

from rig.core.errors import SessionError
from rig.engine.commands import ABORTED
from rig.session.events import Reason
from rig.session.inbox import Inbox, post, request_path, running_pid
from tests.unit.rig.test_engine import IDS, RecordingSession, Rig, make_engine


@pytest.fixture
def new_session(tmp_path):
    made = []

    def make():
        made.append(RecordingSession(tmp_path / f"s{len(made)}.session", IDS))
        return made[-1]

    yield make
    for session in made:
        session.close()


def live_run(session_path, pid: int | None = None) -> None:
    """A lock file naming a live process, as a running `rig run` leaves it (rig/session/lock.py)."""
    session_path.parent.joinpath(f"{session_path.name}.lock").write_text(f"{pid or os.getpid()}\n")


def test_no_request_without_a_live_run(tmp_path):
    session = tmp_path / "run.session"
    with pytest.raises(SessionError, match="no run is running this session"):
        post(session, "pause", "web client 127.0.0.1")
    live_run(session, pid=2**22 + 12345)  # a dead run's pid (kill -9 leaves its lock file)
    assert running_pid(session) is None
    with pytest.raises(SessionError, match="no run is running"):
        post(session, "pause", "web client 127.0.0.1")
    assert not request_path(session).exists()


def test_a_request_is_taken_once_by_its_run(tmp_path):
    session = tmp_path / "run.session"
    live_run(session)
    sent = post(session, "pause", "web client 192.0.2.7")
    inbox = Inbox(session)
    got = inbox.take()
    assert (got.action, got.source, got.id) == ("pause", "web client 192.0.2.7", sent.id)
    assert inbox.take() is None and not request_path(session).exists()


def test_a_request_left_for_another_run_is_dropped(tmp_path):
    session = tmp_path / "run.session"
    live_run(session)
    post(session, "abort", "web client 127.0.0.1")
    assert Inbox(session, pid=os.getpid() + 1).take() is None  # the next run after this one ended
    assert not request_path(session).exists()


def test_an_abort_is_not_replaced_by_a_pause_and_junk_is_no_request(tmp_path):
    session = tmp_path / "run.session"
    live_run(session)
    post(session, "abort", "web client 127.0.0.1")
    with pytest.raises(SessionError, match="abort is already requested"):
        post(session, "pause", "web client 127.0.0.1")
    assert Inbox(session).take().action == "abort"
    with pytest.raises(SessionError, match="unknown request"):
        post(session, "shutdown", "web client 127.0.0.1")
    request_path(session).write_text(json.dumps({"action": "rm -rf", "pid": os.getpid()}))
    assert Inbox(session).take() is None


def _request_after_first_point(session, action):
    def on_collect(pid):
        if pid == IDS[0]:
            live_run(session.path)
            post(session.path, action, "web client 192.0.2.7")
    return on_collect


def test_a_requested_pause_with_nobody_to_ask_ends_the_run_safe_and_resumable(new_session):
    session = new_session()
    rig = Rig(session, on_collect=_request_after_first_point(session, "pause"))
    result = make_engine(rig, session, inbox=Inbox(session.path)).run(rig.steps(IDS))
    assert result.status == ABORTED and result.code == Reason.OPERATOR_PAUSE
    assert "web client 192.0.2.7" in result.reason
    assert session.points == IDS[:1]  # the next point was not taken: paused at its first command
    kinds = session.kinds()
    assert kinds.index("request") < kinds.index("pause") < kinds.index("exit")
    request = next(data for kind, _, data in session.events if kind == "request")
    assert request["source"] == "web client 192.0.2.7"
    assert rig.coils.safe_calls >= 1 and rig.chamber.safe_calls >= 1


def test_a_requested_pause_with_an_operator_at_the_prompt_can_be_resumed(new_session):
    session = new_session()
    asked = []
    rig = Rig(session, on_collect=_request_after_first_point(session, "pause"))
    engine = make_engine(rig, session, inbox=Inbox(session.path),
                         prompt=lambda m: asked.append(m) or "resume")
    assert engine.run(rig.steps(IDS)).status == "completed"
    assert len(asked) == 1 and session.points == IDS


def test_a_requested_abort_stops_before_the_next_command(new_session):
    session = new_session()
    rig = Rig(session, on_collect=_request_after_first_point(session, "abort"))
    result = make_engine(rig, session, inbox=Inbox(session.path)).run(rig.steps(IDS))
    assert result.status == ABORTED and result.code == Reason.OPERATOR_ABORT
    assert result.reason == "abort requested by web client 192.0.2.7"
    assert session.points == IDS[:1]
