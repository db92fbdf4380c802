"""Word to the operator from a simulated campaign, received by a local SMTP server and a local HTTP receiver
(both on loopback): holds forced by the chamber's simulated alarm, a pause from outside that ends the run,
then a resume that completes with the acceptance verdicts. Every event is told once, to each address, also
across the resume; the run's own clock rate-limits the holds; a dead address is recorded, never fatal."""

from __future__ import annotations

import re
from collections import Counter

import pytest
import yaml

from rig.config.loading import load_campaign
from rig.run.campaign import run_campaign
from rig.session import inbox
from rig.session.reader import SessionReader
from tests.system.campaign_helpers import session_counts, small_plan
from tests.system.notify_receivers import http_receiver, smtp_receiver

pytestmark = pytest.mark.system

DEAD_URL = "json://127.0.0.1:9/nobody-listens"  # the discard port: refused at once on loopback
STATION = """
name: sim-notify
sim:
  seed: 7
  ambient_nt: [15000, 500, 42000]
  air_c: 22.0
  duts:
    mmc0: {truth: random, noise_nt: 30, thermal_lag_s: 200}
chamber:
  type: watlow_f4t
  transport: {kind: sim, faults: {alarm: {after_s: 200, for_s: 100}}}
  unit: 1
  limits: {min_setpoint_c: -40, max_setpoint_c: 85, max_ramp_c_per_min: 5, safe_setpoint_c: 25}
  alarm: {register: 60000, kind: nonzero, meaning: alarm summary}
field_source:
  kind: coils
  transport: {kind: sim}
  unit: 2
  max_current_a: 2.0
  coil_constants_nt_per_a: [[50000, 0, 0], [0, 50000, 0], [0, 0, 50000]]
  ambient_nt: [15000, 500, 42000]
duts:
  - name: mmc0
    type: mmc5983ma
    transport: {kind: sim}
    options: {bandwidth_hz: 100, set_reset: true}
    temp_source: tmp0
temperature_sensors:
  - name: tmp0
    type: tmp117
    transport: {kind: sim}
    beside: mmc0
notify: [json://127.0.0.1:9/the-stations-own-word]   # the plan's notify: replaces it
"""


def _event_id(body: str) -> int | None:
    found = re.search(r"event (\d+)\s*$", body)
    return int(found.group(1)) if found else None


def _plan(tmp_path, urls) -> str:
    path = small_plan(tmp_path, steps=(15, 35), name="notified")
    plan = yaml.safe_load(path.read_text())
    plan["station"] = str(tmp_path / "station.yaml")
    plan["acceptance"] = {"max_rms_nt": 5000}
    plan["notify"] = {"urls": urls, "stalled_after_min": 20, "repeat_after_min": 10}
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    (tmp_path / "station.yaml").write_text(STATION)
    return str(path)


def _pause_after(points: int, session_path):
    """A display that asks the run to pause (as the cockpit does) once `points` points are recorded."""
    def factory(status, runner):
        seen = []

        def point_done(point_id):
            seen.append(point_id)
            if len(seen) == points:
                inbox.post(session_path, "pause", source="test operator")

        runner.on_point.append(point_done)
        return None

    return factory


def test_word_to_the_operator_over_a_run_its_pause_and_its_resume(tmp_path):
    session_path = tmp_path / "run.session"
    with smtp_receiver() as mail, http_receiver() as hook:
        campaign = load_campaign(_plan(tmp_path, [mail.url, hook.url, DEAD_URL]))
        first = run_campaign(campaign=campaign, session_path=session_path,
                             display_factory=_pause_after(8, session_path))
        assert first.result.status == "aborted"
        told_first = list(hook.messages)
        second = run_campaign(session_path=session_path, resume=True)
        assert second.result.status == "completed"
        assert session_counts(session_path)["completed"]
    with SessionReader(session_path) as reader:
        events = reader.events()
    by_id = {e.id: e for e in events}
    records = [e for e in events if e.kind == "notify"]

    assert sorted(mail.messages) == sorted(hook.messages)  # every address got every message
    told = [_event_id(body) for _, body in hook.messages]
    stalls = [body for title, body in hook.messages if title.endswith(": stalled")]
    assert Counter(i for i in told if i is not None).most_common(1)[0][1] == 1  # each event told once
    assert len(stalls) == told.count(None)
    assert hook.messages[:len(told_first)] == told_first  # the resumed run re-sent nothing of the first's

    kinds = Counter(by_id[i].kind for i in told if i is not None)
    assert kinds["pause"] == 1 and kinds["hold"] >= 1
    exits = [by_id[i] for i in told if i is not None and by_id[i].kind == "exit"]
    assert [e.data["status"] for e in exits] == ["aborted", "completed"]
    title, body = next(m for m in hook.messages if m[0].endswith(": completed"))
    assert "acceptance:" in body and re.search(r"^\s+mmc0 (PASS|FAIL)", body, re.M)

    # every hold is accounted for: told, or held back (one of its kind went out within 10 min)
    holds = [e for e in events if e.kind == "hold"]
    held_back = [r for r in records if r.code == "notify_held_back"]
    assert len(holds) == kinds["hold"] + len([r for r in held_back if r.data["topic"] == "hold"])
    assert len(holds) >= 2 and held_back  # the alarm holds the run twice within a few minutes
    # the dead address: recorded for every message sent, masked, and the run went on
    failed = [r for r in records if r.code == "notify_failed"]
    assert len(failed) == len(hook.messages)
    assert all("127.0.0.1" in r.message and "nobody-listens" in r.message for r in failed)
    assert all(r.data["event_id"] in by_id or r.data["topic"] == "stalled" for r in records)
