"""A real headless browser for the cockpit's tests, bench and screenshots: the system's Chromium driven by
playwright (nothing is downloaded: playwright only talks to /usr/bin/chromium).

    with headless_page(viewport) as (page, errors):     # errors: console errors and uncaught exceptions
        page.goto(url); wait_js(page, "window.cockpit.messages > 2")

    with cockpit(folder) as url:                        # `rig serve FOLDER --port 0` in a process of its own
        ...

`missing()` says why no browser can run here (then the tests skip with that reason).
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

CHROMIUM = os.environ.get("MAGRIG_CHROMIUM", "/usr/bin/chromium")
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]


def missing() -> str | None:
    """Why the browser tests cannot run here, or None."""
    if not (os.path.isfile(CHROMIUM) or shutil.which(CHROMIUM)):
        return f"no Chromium at {CHROMIUM} (apt-get install chromium, or set MAGRIG_CHROMIUM)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is not installed (pip install -e '.[test]')"
    return None


@contextlib.contextmanager
def headless_page(viewport: tuple[int, int] = (1200, 900)) -> Iterator[tuple[object, list[str]]]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
            errors: list[str] = []
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            yield page, errors
        finally:
            browser.close()


def wait_js(page, expression: str, timeout_s: float = 60.0, poll_s: float = 0.05):
    """Until `expression` (evaluated in the page) is truthy; its value. Polled from here because the
    page's policy forbids the string evaluation playwright's own waiting uses."""
    end = time.monotonic() + timeout_s
    while True:
        value = page.evaluate(expression)
        if value:
            return value
        if time.monotonic() > end:
            raise TimeoutError(f"page never showed: {expression}")
        time.sleep(poll_s)


@contextlib.contextmanager
def cockpit(*args: str, timeout_s: float = 60.0) -> Iterator[str]:
    """`rig serve ARGS --port 0` as its own process (as an operator runs it); yields its base URL. Its
    output goes to a file (a pipe nobody reads could fill and stall the server)."""
    import tempfile

    with tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen([sys.executable, "-m", "rig", "serve", *args, "--port", "0"], cwd=REPO,
                                stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, text=True)
        try:
            end = time.monotonic() + timeout_s
            while (found := re.search(r"http://127\.0\.0\.1:(\d+)/", _text(out))) is None:
                if proc.poll() is not None or time.monotonic() > end:
                    raise RuntimeError(f"rig serve did not start: {_text(out)}")
                time.sleep(0.05)
            yield f"http://127.0.0.1:{found.group(1)}"
        finally:
            proc.terminate()
            proc.wait(timeout=30)


def _text(f) -> str:
    f.seek(0)
    return f.read()
