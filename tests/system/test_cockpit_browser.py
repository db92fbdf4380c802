"""The cockpit in a real headless browser (the system's Chromium) against a running simulated campaign:
the live page updates without a reload, logs no console error, and its pause button pauses the campaign
at a safe point; `rig run --resume` then completes it with every point exactly once."""

from __future__ import annotations

import sqlite3
import time

import pytest

from tests.system import browser
from tests.system.campaign_helpers import SIM_STATION, events, popen_rig, run_rig, session_counts, small_plan
from tests.system.test_cockpit_http import HOSTILE, tiny_session

pytestmark = [pytest.mark.system,
              pytest.mark.skipif(browser.missing() is not None, reason=f"no browser: {browser.missing()}")]

SAMPLES = 100  # points long enough for the page to be watched and paused before the run ends


def summary(page, key: str) -> object:
    return page.evaluate(f"window.cockpit.state && window.cockpit.state.summary && "
                         f"window.cockpit.state.summary.{key}")


def test_the_live_page_follows_a_campaign_and_pauses_it_for_a_resume(tmp_path):
    folder = tmp_path / "sessions"
    folder.mkdir()
    session = folder / "run.session"
    plan = small_plan(tmp_path, samples=SAMPLES)
    with browser.cockpit(str(folder)) as url, browser.headless_page() as (page, errors):
        run = popen_rig("run", str(plan), "--station", str(SIM_STATION), "--session", str(session),
                        "--no-live")
        try:
            end = time.monotonic() + 60
            while not session.exists() and time.monotonic() < end:  # a campaign's own process, real time
                time.sleep(0.05)
            page.goto(f"{url}/s/0/run.session/live")
            page.evaluate("window.sameDocument = true")
            first = browser.wait_js(page, "window.cockpit.state.summary && "
                                          "window.cockpit.state.summary.progress.done")
            browser.wait_js(page, f"window.cockpit.state.summary.progress.done > {first}")
            assert page.evaluate("window.sameDocument === true")  # pushed, not reloaded
            assert page.evaluate("performance.getEntriesByType('navigation').length") == 1
            assert summary(page, "run.state") == "running"
            assert "of 12 points" in page.inner_text("#progress-text")
            assert page.inner_text("#current").startswith("point T0")
            assert "field" in page.inner_text("#target")
            # set point, chamber air and the two DUTs
            browser.wait_js(page, "document.querySelectorAll('#chart path').length >= 4")
            assert page.locator("#duts tbody tr").count() == 2
            assert page.locator("#events li").count() >= 2

            page.click("#ask-pause")
            assert page.is_visible("#confirm") and "Pause the campaign" in page.inner_text("#confirm-text")
            page.click("#confirm-yes")
            _, err = run.communicate(timeout=120)
        finally:
            if run.poll() is None:
                run.kill()
                run.communicate()
        assert run.returncode == 1, err
        assert "at the request of web client 127.0.0.1" in err and "--resume" in err
        browser.wait_js(page, "document.getElementById('run-state').textContent === 'paused'")
        assert "Continue it with: rig run --resume run.session" in page.inner_text("#stream-note")

        paused = session_counts(session)
        assert paused["status"] == "aborted" and 1 <= paused["done"] < paused["planned"]
        assert paused["orphan_samples"] == 0
        kinds = [k for k, _ in events(session)]
        assert kinds.index("request") < kinds.index("pause") < kinds.index("safe_state")
        request = next(m for k, m in events(session) if k == "request")
        assert request == "pause at the next safe point requested by web client 127.0.0.1"
        with sqlite3.connect(f"file:{session}?mode=ro", uri=True) as conn:
            assert conn.execute("SELECT exit_code FROM session").fetchone()[0] == "operator_pause"

        resumed = run_rig("run", "--resume", str(session), "--no-live")
        assert resumed.returncode == 0, resumed.stderr
        browser.wait_js(page, "document.getElementById('run-state').textContent === 'completed'")
        assert page.inner_text("#progress-text").startswith("12 of 12 points")
        assert errors == []

    done = session_counts(session)
    assert done["completed"] and done["status"] == "completed"
    assert done["planned"] == done["done"] == 12 and done["orphan_samples"] == 0
    assert set(done["per_point_dut"].values()) == {SAMPLES} and len(done["per_point_dut"]) == 12 * 2


def test_pages_show_hostile_text_as_text_and_fit_a_phone(tmp_path):
    folder = tmp_path / "sessions"
    folder.mkdir()
    tiny_session(folder / "hostile.session", plan_name=HOSTILE, station_name=HOSTILE, dut="<b>dut</b>",
                 message=HOSTILE)
    with browser.cockpit(str(folder)) as url, browser.headless_page((390, 844)) as (page, errors):
        for path in ("/", "/s/0/hostile.session", "/s/0/hostile.session/live"):
            page.goto(url + path)
            if path.endswith("/live"):
                browser.wait_js(page, "window.cockpit.messages > 0 && "
                                      "document.querySelectorAll('#events li').length > 0")
                assert HOSTILE in page.inner_text("#meta") and HOSTILE in page.inner_text("#events")
                assert page.inner_text("#duts tbody").startswith("<b>dut</b>")
            else:
                assert HOSTILE in page.inner_text("main") or path == "/"
            assert page.locator("main img, main script, main b").count() == 0, path
            assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth + 1"), path
        assert errors == []



def test_a_report_being_built_shows_its_progress_and_becomes_the_report(tmp_path):
    """The report's address, while the report is built: a page of its progress that reloads itself (its
    Refresh header) until the report comes, without a script or a console error."""
    from rig.web.server import Cockpit
    from tests.helpers.synthetic_session import SynthOptions, build_session
    from tests.system.test_cockpit_http import start

    folder = tmp_path / "sessions"
    folder.mkdir()
    build_session(folder / "run.session",
                  SynthOptions(temps_c=(-20.0, 40.0), directions=14, samples=3, seed=3))
    app = Cockpit(roots=[folder])
    app.reports.wait_s = 0.0  # every build outlasts the wait
    srv = start(app)
    try:
        with browser.headless_page() as (page, errors):
            page.goto(f"http://127.0.0.1:{srv.server_address[1]}/s/0/run.session/report")
            assert "Building the report: " in page.inner_text("#report-progress")
            # a locator's wait goes on across the page's reloads (an evaluate would die with its page)
            page.locator("h2", has_text="Summary").first.wait_for(timeout=120_000)
            assert page.locator("script").count() == 0
            assert errors == []
    finally:
        srv.shutdown()
        srv.server_close()
