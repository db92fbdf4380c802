"""A running session's own page (the one its name links to) moves: it carries the live view's parts and
follows the live view's stream. Over HTTP: what the page and the stream hold while a run writes the session
(this process holds its run lock and writes points); in the headless browser: the page of a real running
campaign changes its progress, DUTs and events without a reload, then shows the finished session."""

from __future__ import annotations

import http.client
import json
import re
import time
from types import SimpleNamespace

import pytest

from drivers.clock import SimClock
from rig.session.events import Kind, Reason
from rig.session.lock import SessionLock
from rig.session.rows import SampleRow, TemperatureRow
from rig.session.writer import Session
from rig.web.server import Cockpit
from tests.system import browser
from tests.system.campaign_helpers import SIM_STATION, popen_rig, small_plan
from tests.system.test_cockpit_http import HOSTILE, request, start

pytestmark = pytest.mark.system


def _points(n: int) -> list:
    return [SimpleNamespace(id=f"T01-F0{i + 1}", index=i, temp_index=1, setpoint_c=25.0, field_index=i + 1,
                            target={"field_nt": [50000.0, 0.0, 0.0]}) for i in range(n)]


def _record(session: Session, i: int, dut: str = "dut1") -> None:
    t = session.clock.now()
    session.record_point(f"T01-F0{i + 1}", [SampleRow(dut, t, (1.0, 2.0, 3.0), (1.0, 2.0, 3.0), 25.0)],
                         temperatures=[TemperatureRow(t, 25.0, None, 25.0 + i, {dut: 25.0 + i})])
    session.clock.sleep(30)


def _across_the_reload(page, expression: str, timeout_s: float = 60.0):
    """browser.wait_js through the page's own reload (an evaluation then finds no page to run in)."""
    from playwright.sync_api import Error

    end = time.monotonic() + timeout_s
    while True:
        try:
            return browser.wait_js(page, expression, timeout_s=max(end - time.monotonic(), 0.1))
        except Error:
            if time.monotonic() > end:
                raise
            page.wait_for_load_state()


class Stream:
    """The session's server-sent events, read message by message."""

    def __init__(self, server, path: str):
        self.conn = http.client.HTTPConnection("127.0.0.1", server.server_address[1], timeout=30)
        self.conn.request("GET", path, headers={"Host": f"127.0.0.1:{server.server_address[1]}"})
        self.resp = self.conn.getresponse()
        assert self.resp.status == 200 and self.resp.headers["Content-Type"] == "text/event-stream"

    def next(self) -> dict:
        data = None
        while True:
            line = self.resp.fp.readline().decode()
            if line.startswith("data: "):
                data = json.loads(line.removeprefix("data: "))
            elif line == "\n" and data is not None:
                return data

    def close(self):
        self.conn.close()


def test_a_running_sessions_page_carries_the_live_parts_and_its_stream_moves(tmp_path):
    folder = tmp_path / "sessions"
    folder.mkdir()
    path = folder / "run.session"
    session = Session.create(path, plan_text="name: x\n", station_text="name: y\n", plan_name=HOSTILE,
                             station_name="bench", points=_points(4), simulated={"chamber": True},
                             clock=SimClock())
    server = start(Cockpit(roots=[folder]))
    try:
        with SessionLock(path):  # this process is the run
            _record(session, 0)
            page = request(server, "GET", "/s/0/run.session")
            assert page.status == 200
            body = re.search(r"<body([^>]*)>", page.body).group(1)
            assert 'data-events="/s/0/run.session/events"' in body and 'data-page="session"' in body
            for element in ('id="run-state"', 'id="progress"', 'id="chart"', 'id="duts"',
                            '<span id="s-state">running</span>', '<span id="s-points">1 of 4</span>',
                            'id="event-table"', 'id="stream-note"'):
                assert element in page.body, element
            assert HOSTILE not in page.body  # escaped like every other string
            stream = Stream(server, "/s/0/run.session/events")
            try:
                first = stream.next()
                assert first["reset"] and first["summary"]["run"]["state"] == "running"
                assert first["summary"]["progress"]["done"] == 1
                _record(session, 1)
                session.log_event(Kind.HOLD, "point T01-F03: chamber alarm", code=Reason.CHAMBER_ALARM,
                                  point_id="T01-F03")
                moved = stream.next()
                while moved["summary"]["progress"]["done"] < 2 or not moved["events"]:
                    moved = stream.next()  # the point and the event may come in one message or two
                assert not moved["reset"] and [e["kind"] for e in moved["events"]] == ["hold"]
                assert moved["telemetry"] and moved["summary"]["duts"][0]["temp_c"] == 26.0
            finally:
                stream.close()
        session.finish("aborted", "stopped by the test", code=Reason.OPERATOR_ABORT)
        finished = request(server, "GET", "/s/0/run.session")
        assert "data-events" not in finished.body and 'id="progress"' not in finished.body
        assert '<span id="s-state">aborted (operator_abort)</span>' in finished.body
    finally:
        session.close()
        server.shutdown()


@pytest.mark.skipif(browser.missing() is not None, reason=f"no browser: {browser.missing()}")
def test_the_session_page_of_a_running_campaign_moves_in_the_browser(tmp_path):
    folder = tmp_path / "sessions"
    folder.mkdir()
    session = folder / "run.session"
    plan = small_plan(tmp_path, samples=100)  # long enough to be watched while it runs, on a fast machine too
    with browser.cockpit(str(folder)) as url, browser.headless_page() as (page, errors):
        run = popen_rig("run", str(plan), "--station", str(SIM_STATION), "--session", str(session),
                        "--no-live")
        try:
            end = time.monotonic() + 60
            while not session.exists() and time.monotonic() < end:  # a campaign's own process, real time
                time.sleep(0.05)
            page.goto(f"{url}/s/0/run.session")
            browser.wait_js(page, "document.getElementById('s-state') && "
                                  "document.getElementById('s-state').textContent === 'running'")
            page.evaluate("window.sameDocument = true")
            # the point being taken, looked for from the start (a fast run may be in its post-run fits by
            # the time the chart and the tables below have filled)
            browser.wait_js(page, "document.getElementById('current').textContent.startsWith('point T0')")
            first = browser.wait_js(page, "window.cockpit.state && window.cockpit.state.summary && "
                                          "window.cockpit.state.summary.progress.done")
            rows = page.locator("#event-table tbody tr").count()
            browser.wait_js(page, f"window.cockpit.state.summary.progress.done > {first}")
            browser.wait_js(page, f"parseInt(document.getElementById('progress-text').textContent) > {first} "
                                  f"&& parseInt(document.getElementById('s-points').textContent) > {first}")
            assert page.evaluate("window.sameDocument === true")  # moved by the stream, not reloaded
            browser.wait_js(page, "document.querySelectorAll('#chart path').length >= 4")
            browser.wait_js(page, "document.querySelectorAll('#duts tbody tr').length === 2")
            # new events may be the post-run fits' last ones, just before the page shows itself finished
            _across_the_reload(page, f"document.querySelectorAll('#event-table tbody tr').length > {rows}")
            _, err = run.communicate(timeout=300)
        finally:
            if run.poll() is None:
                run.kill()
                run.communicate()
        assert run.returncode == 0, err
        # the run ended: the page shows the finished session, with its calibrations
        _across_the_reload(page, "window.sameDocument === undefined && document.getElementById('s-state') "
                                 "&& document.getElementById('s-state').textContent === 'completed'")
        assert page.locator("#progress").count() == 0 and page.evaluate("!document.body.dataset.events")
        assert "mmc0" in page.inner_text("main") and page.locator("a[download]").count() > 0
        assert errors == []
