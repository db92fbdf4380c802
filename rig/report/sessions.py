"""`rig sessions`: one line per session file, from rig.session.reader.SessionReader.summary (the cockpit's
list
shows the same cells)."""

from __future__ import annotations

from pathlib import Path

from rig.report.sources import utc
from rig.session.events import Reason

WIDTHS = (28, 17, 16, 16, 18, 12, 14)  # file, started, station, DUTs, points, exit, acceptance; judged fit


def _row(*cells: str) -> str:
    *fixed, last = cells
    return " ".join(f"{c:<{w}}" for c, w in zip(fixed, WIDTHS, strict=True)) + " " + last


COLUMNS = ("file", "started (UTC)", "station", "DUTs", "points done", "exit", "acceptance",
           "judged calibration (the plan's model)")
HEADER = _row(*COLUMNS)


def session_files(directory: Path, suffixes: tuple[str, ...]) -> list[Path]:
    return sorted(p for p in directory.iterdir() if p.is_file() and p.suffix.lower() in suffixes)


def session_line(path: Path) -> str:
    """The session at a glance; raises SessionError for a file that is not a session or is damaged."""
    return _row(*session_cells(path))


def session_cells(path: Path) -> list[str]:
    """The COLUMNS of one session (`rig sessions` and the cockpit's list); SessionError as above."""
    from rig.analysis.acceptance import verdict_text
    from rig.analysis.judged import judged_cell, judged_fits
    from rig.session.reader import SessionReader

    with SessionReader(path) as reader:
        s = reader.summary()
        accepted = verdict_text(reader.acceptance())
        judged = judged_cell(*judged_fits(reader))
    points = f"{s['points_done']}/{s['points_planned']}"
    if s["points_failed"]:
        points += f" ({s['points_failed']} failed)"
    started = utc(s.get("wall_started") or s["started"]).removesuffix(" UTC")[:16]
    exit_status = s["exit_status"] or "not finished"
    if s["exit_code"] and s["exit_code"] != Reason.COMPLETED:  # why it stopped, as a code
        exit_status += f" ({s['exit_code']})"
    duts = ",".join(s["duts"]) or "-"
    return [path.name, started, s["station"], duts, points, exit_status, accepted, judged]


def skipped_line(path: Path, reason: str) -> str:
    """One line for a file that could not be read; the reason without a repeated path."""
    for prefix in (f"{path}: ", f"{path.name}: "):
        reason = reason.removeprefix(prefix)
    return f"{path.name:<{WIDTHS[0]}} SKIPPED: {reason}"
