"""The run's word to the operator (rig/run/notify.py) on a real session and the run's simulated clock: what
is told, the rate limit and its count, the stall, what a resumed run tells and never tells again, a sender
that fails or hangs. The sender is a recorder here (Apprise itself: tests/system/test_notify_campaign.py)."""

from __future__ import annotations

import threading

import pytest

from drivers.clock import SimClock
from rig.config.notify import Notify
from rig.core.errors import ConfigError
from rig.core.yamlload import load_model
from rig.run.notify import Notifier, notify_config
from rig.session.events import Kind, Reason
from rig.session.reader import SessionReader
from rig.session.writer import Session

URL = "json://127.0.0.1:9/magrig"


class Recorder:
    """Stands where Apprise sends: keeps each message, answers `outcome` for each URL."""

    def __init__(self, outcome: str | None = None):
        self.messages = []
        self.outcome = outcome

    def __call__(self, message):
        self.messages.append(message)
        return [("json://127.0.0.1:9/magrig", self.outcome)]


@pytest.fixture
def session(tmp_path):
    s = Session.create(tmp_path / "run.session", plan_text="p", station_text="s", plan_name="p",
                       station_name="s", points=[], simulated={}, clock=SimClock())
    yield s
    s.close()


def notifier(session, send, **config) -> Notifier:
    n = Notifier(session, Notify(urls=[URL], **config), station_name="bench", plan_name="demo", send=send)
    n.start()
    return n


def hold(session, point="T01-F01"):
    session.log_event(Kind.HOLD, f"point {point}: chamber alarm; retake 1 of 3", code=Reason.CHAMBER_ALARM,
                      point_id=point)


def records(session) -> list:
    with SessionReader(session.path) as reader:
        return [e for e in reader.events() if e.kind == Kind.NOTIFY]


def test_notify_takes_a_plain_list_or_a_mapping_and_refuses_a_bad_url_naming_key_and_line(tmp_path):
    assert Notify.model_validate([URL]).urls == [URL]
    assert Notify.model_validate({"urls": [URL], "stalled_after_min": None}).stalled_after_min is None
    path = tmp_path / "n.yaml"
    path.write_text(f"urls:\n  - {URL}\n  - nosuchscheme://token@somewhere\n")
    with pytest.raises(ConfigError) as err:
        load_model(Notify, path)
    assert str(err.value).startswith(f"{path}: urls[1]: ") and str(err.value).endswith("(line 3)")
    assert "token" not in str(err.value)  # a URL may carry a secret: never repeated


def test_the_plans_notify_replaces_the_stations():
    class Holder:
        def __init__(self, notify):
            self.notify = notify

    plan_side, station_side = Notify(urls=[URL]), Notify(urls=["json://127.0.0.1:9/station"])
    assert notify_config(Holder(plan_side), Holder(station_side)) is plan_side
    assert notify_config(Holder(None), Holder(station_side)) is station_side
    assert notify_config(Holder(None), Holder(None)) is None


def test_holds_are_rate_limited_on_the_runs_clock_and_the_next_one_counts_those_held_back(session):
    send = Recorder()
    n = notifier(session, send, repeat_after_min=10)
    hold(session, "T01-F01")
    session.clock.sleep(60)
    hold(session, "T01-F02")  # a minute later: held back
    session.clock.sleep(60)
    hold(session, "T01-F03")  # held back too
    session.clock.sleep(600)
    hold(session, "T01-F04")  # 12 minutes after the first: told, with the count
    session.log_event(Kind.EXIT, "aborted: enough", code=Reason.OPERATOR_ABORT, status="aborted")
    n.close()
    assert [m.topic for m in send.messages] == ["hold", "hold", "abort"]
    assert "T01-F04" in send.messages[1].body and "2 more hold message(s) held back" in send.messages[1].body
    codes = [r.code for r in records(session)]
    assert codes.count(Reason.NOTIFY_HELD_BACK) == 2 and codes.count(Reason.NOTIFIED) == 3


def test_a_stall_is_told_once_per_point_it_follows(session):
    send = Recorder()
    n = notifier(session, send, stalled_after_min=30)
    session.clock.sleep(29 * 60)
    session.record_temperatures([])  # a write while waiting: not yet
    session.clock.sleep(2 * 60)
    session.record_temperatures([])  # 31 min without a point: told
    session.clock.sleep(60 * 60)
    session.record_temperatures([])  # still stalled: already told
    n.close()
    assert [m.topic for m in send.messages] == ["stalled"]
    assert "no point recorded for 31 min" in send.messages[0].body


def test_completion_is_told_at_the_end_with_the_verdicts(session):
    send = Recorder()
    n = notifier(session, send)
    session.log_event(Kind.EXIT, "completed: all 4 points taken", code=Reason.COMPLETED, status="completed")
    session.log_event(Kind.ACCEPTANCE, "mmc0 PASS", code=Reason.ACCEPTED, device="mmc0")
    session.log_event(Kind.ACCEPTANCE, "mmc1 FAIL (heldout_rms 212 nT > 150)", code=Reason.REJECTED,
                      device="mmc1")
    assert send.messages == []  # nothing before the verdicts are in
    n.close()
    (message,) = send.messages
    assert message.topic == "completed" and message.kind == "warning"  # a DUT failed
    assert "mmc0 PASS" in message.body and "mmc1 FAIL (heldout_rms 212 nT > 150)" in message.body


def test_a_resumed_run_tells_what_the_last_run_never_did_and_nothing_it_did(session):
    session.log_event(Kind.START, "started", code=Reason.STARTED)
    first = Recorder()
    n = notifier(session, first)
    hold(session, "T01-F01")
    n.close()
    session.log_event(Kind.PAUSE, "paused at point T01-F02", code=Reason.OPERATOR_PAUSE, point_id="T01-F02")
    # ... killed here before it could tell the pause: the resumed run's notifier starts
    second = Recorder()
    notifier(session, second).close()
    third = Recorder()
    notifier(session, third).close()
    assert [m.topic for m in first.messages] == ["hold"]
    assert [m.topic for m in second.messages] == ["pause"]
    assert "recorded by the run before this one" in second.messages[0].body
    assert third.messages == []  # everything is recorded as told: nothing twice
    assert sorted(r.data["event_id"] for r in records(session)) == [2, 4]


def test_a_failed_send_is_recorded_and_never_raised(session):
    n = notifier(session, Recorder(outcome="A Connection error occurred"))
    hold(session)
    n.close()
    (record,) = records(session)
    assert record.code == Reason.NOTIFY_FAILED and record.level == "WARNING"
    assert "json://127.0.0.1:9/magrig: A Connection error occurred" in record.message


def test_a_hung_address_never_holds_the_run_and_a_full_queue_drops(session):
    release = threading.Event()
    started = threading.Event()

    def hung(message):
        started.set()
        release.wait()
        return [(URL, None)]

    n = Notifier(session, Notify(urls=[URL], repeat_after_min=0), send=hung, queue_size=2)
    n.start()
    for i in range(4):  # the first is being sent (hung), two wait, the fourth finds the queue full
        hold(session, f"T01-F0{i}")
        if i == 0:
            assert started.wait(60)
    full = [r for r in records(session) if r.code == Reason.NOTIFY_FAILED]
    assert [r.data["event_id"] for r in full] == [4]  # every hold was recorded meanwhile: never blocked
    release.set()
    n.close()
    assert sorted(r.code for r in records(session)).count(Reason.NOTIFIED) == 3
