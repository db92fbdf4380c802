"""A PDF printed from the same HTML page (a calibration certificate): by Chromium headless where there is
one (Debian's `chromium`, or MAGRIG_CHROMIUM naming it), else by WeasyPrint where it is installed
(`pip install weasyprint`), else not at all, and the message says which to install. Both print the page's
own print style (rig/report/certificate.py PRINT_CSS: A4, page x of y)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

TIMEOUT_S = 120.0
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
NO_RENDERER = ("no PDF written: no renderer here (apt-get install chromium, set MAGRIG_CHROMIUM to a Chrome, "
               "or pip install weasyprint); the HTML prints to the same pages from any browser")


def chromium() -> str | None:
    """A Chromium to print with, or None."""
    named = os.environ.get("MAGRIG_CHROMIUM")
    if named:
        return named if (os.path.isfile(named) or shutil.which(named)) else None
    return next((found for name in CHROMIUM_NAMES if (found := shutil.which(name))), None) or \
        ("/usr/bin/chromium" if os.path.isfile("/usr/bin/chromium") else None)


def print_pdf(html_path: Path, pdf_path: Path) -> str:
    """Print `html_path` to `pdf_path`; what was done, in one line."""
    browser = chromium()
    if browser is not None:
        cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--no-pdf-header-footer",
               f"--print-to-pdf={pdf_path}", Path(html_path).resolve().as_uri()]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_S)
        except (OSError, subprocess.TimeoutExpired) as exc:
            return f"no PDF written: {browser} failed ({exc})"
        if proc.returncode == 0 and pdf_path.is_file():
            return f"printed {pdf_path} with {Path(browser).name}"
        return f"no PDF written: {browser} exited {proc.returncode}: {proc.stderr.strip()[-300:]}"
    try:
        from weasyprint import HTML  # optional
    except ImportError:
        return NO_RENDERER
    HTML(filename=str(html_path)).write_pdf(str(pdf_path))
    return f"printed {pdf_path} with WeasyPrint"
