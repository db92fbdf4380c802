"""Writes the cockpit's screenshots in docs/img/ (the README links them): the live page of a running demo
campaign (desktop and phone), that session's page once it completed, and the fleet page over a
throwaway PostgreSQL server holding a few pushed sessions of two rigs.

    python bench/make_screenshots.py

Needs Chromium and playwright (the test extra) and, for the fleet page, PostgreSQL's server programs.
"""

from __future__ import annotations

import datetime as dt
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import yaml  # noqa: E402

from rig.config.loading import load_campaign  # noqa: E402
from rig.run.campaign import run_campaign  # noqa: E402
from tests import pg_server  # noqa: E402
from tests.system import browser  # noqa: E402

OUT = REPO / "docs" / "img"


def demo_with_acceptance(folder: Path) -> Path:
    plan = yaml.safe_load((REPO / "configs/plans/demo.yaml").read_text())
    plan["station"] = str(REPO / "configs/stations/sim.yaml")
    plan["acceptance"] = {"model": "t24", "max_heldout_rms_nt": 60.0}
    path = folder / "demo.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return path


def live_and_session(page, url: str, folder: Path) -> None:
    session = folder / "demo.session"
    campaign = load_campaign(demo_with_acceptance(folder.parent))
    thread = threading.Thread(target=run_campaign, kwargs={"campaign": campaign, "session_path": session})
    thread.start()
    while not session.exists():
        time.sleep(0.02)
    page.goto(f"{url}/s/0/demo.session/live")
    browser.wait_js(page, "window.cockpit.state.summary && window.cockpit.state.summary.progress.done >= 66",
                    timeout_s=300, poll_s=0.01)
    time.sleep(0.5)  # the plot is drawn a few times a second
    page.screenshot(path=str(OUT / "cockpit-live.png"), full_page=True)
    page.set_viewport_size({"width": 390, "height": 844})
    time.sleep(0.7)
    page.screenshot(path=str(OUT / "cockpit-live-phone.png"), full_page=True)
    page.set_viewport_size({"width": 1200, "height": 900})
    thread.join()
    page.goto(f"{url}/s/0/demo.session")
    page.screenshot(path=str(OUT / "cockpit-session.png"), full_page=True)


def fleet(page, folder: Path) -> None:
    from rig.fleet.push import push_snapshot
    from rig.fleet.schema import connect
    from rig.fleet.source import session_snapshot
    from rig.session.writer import Session
    from tests.fleet_sessions import Spec, write_session

    with pg_server.running() as pg:
        db = pg_server.create_database(pg, "screenshots")
        with connect(db) as conn:
            for seed in range(1, 15):
                station = "rig-a" if seed % 3 else "rig-b"
                day = dt.date(2026, 3, 2) + dt.timedelta(days=seed // 2)
                path = write_session(folder / f"s{seed:02d}.session",
                                     Spec(seed=seed, station=station, duts=("dut1", "dut2"), day=day))
                fails = {"dut2"} if seed % 5 == 0 else set()
                with Session.open(path) as s:
                    s.record_acceptance([{"dut": d, "model": "t24", "passed": int(d not in fails),
                                          "verdict": "FAIL" if d in fails else "PASS", "failed": "",
                                          "heldout_rms_nt": 20.0, "fit_rms_nt": 18.0, "lag_s": None,
                                          "notes": ""} for d in ("dut1", "dut2")])
                push_snapshot(conn, session_snapshot(path))
        with browser.cockpit(str(folder), "--db", db) as url:
            page.goto(f"{url}/fleet")
            page.screenshot(path=str(OUT / "cockpit-fleet.png"), full_page=True)


def main() -> None:
    if (why := browser.missing()) is not None:
        sys.exit(f"cannot run: {why}")
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="screenshots-") as tmp:
        sessions, pushed = Path(tmp) / "sessions", Path(tmp) / "pushed"
        sessions.mkdir()
        pushed.mkdir()
        with browser.cockpit(str(sessions)) as url, browser.headless_page() as (page, errors):
            live_and_session(page, url, sessions)
            fleet(page, pushed)
            if errors:
                sys.exit(f"page errors: {errors}")
    for name in sorted(OUT.glob("cockpit-*.png")):
        print(f"wrote {name.relative_to(REPO)}")


if __name__ == "__main__":
    main()
