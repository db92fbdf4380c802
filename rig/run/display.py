"""What the operator sees while a campaign runs.

LiveDisplay: a rich Live panel refreshed a few times a second: current point and step, chamber and DUT
temperatures, what the temperatures are doing, recent events, ETA, and the streaming T24 fit of each DUT.
PlainLog: progress lines (stdout is not a terminal, or --no-live): the first recorded point, then at most
one line every `every_s` seconds of wall time (a log or a pipe is read by people and programs, not
watched point by point); `every_s = 0` writes one line per point (`rig run --progress-every 0`).
Both are context managers built by `make_display(status, runner, live=...)`; the runner calls their
`point_done(point_id)` after each stored point.
"""

from __future__ import annotations

import sys
import time

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from rig.engine.executor import RunStatus

# DUT rows the live panel shows; with more DUTs it shows those with the largest live residual and a count
# (a 64-DUT table fills no screen, and redrawing it four times a second cost a third of a core)
MAX_DUT_ROWS = 8
PLAIN_PROGRESS_EVERY_S = 5.0  # piped output: at most one progress line this often (wall clock)


def temperatures_text(temps_c: dict[str, float]) -> str:
    """Each DUT's temperature, or their count and range when there are more than MAX_DUT_ROWS."""
    if len(temps_c) > MAX_DUT_ROWS:
        values = temps_c.values()
        return f"{len(temps_c)} DUTs, {min(values):.2f} .. {max(values):.2f} C"
    return ", ".join(f"{k} {v:.2f} C" for k, v in temps_c.items()) or "-"


def fit_rows(summaries: dict[str, str], live: dict) -> list[tuple[str, str]]:
    """(DUT, live fit text) rows: every DUT, or the MAX_DUT_ROWS with the largest residual and a count."""
    if len(summaries) <= MAX_DUT_ROWS:
        return list(summaries.items())

    def rms(dut: str) -> float:
        value = getattr(live.get(dut), "rms_nt", None)
        return -1.0 if value is None else value

    worst = sorted(summaries, key=rms, reverse=True)[:MAX_DUT_ROWS]
    return [(dut, summaries[dut]) for dut in worst] + [
        (f"+{len(summaries) - MAX_DUT_ROWS} more", "(largest live residual first; every DUT in the session)")]


class _Progress:
    """Points done and a wall-clock ETA from the pace of the points taken in this process."""

    def __init__(self, status: RunStatus):
        self.status = status
        self.wall0 = time.perf_counter()
        self.done0: int | None = None

    def eta_text(self) -> str:
        s = self.status
        if self.done0 is None:
            self.done0 = s.points_done
        taken = s.points_done - self.done0
        left = s.points_total - s.points_done
        if taken <= 0 or left <= 0:
            return "-" if left else "0 s"
        per_point = (time.perf_counter() - self.wall0) / taken
        return f"{per_point * left:.0f} s"


def fit_progress_line(dut: str | None, model: str | None, done: int, total: int) -> str:
    """The post-run fits' progress (rig/analysis/fitprogress.py), one line."""
    if dut is None:
        return f"post-run fits: {total} of {total} done"
    return f"post-run fits: {dut} {model} ({done + 1} of {total})"


class LiveDisplay:
    def __init__(self, status: RunStatus, runner, console: Console | None = None):
        self.status = status
        self.runner = runner
        self.progress = _Progress(status)
        self.live = Live(get_renderable=self.render, console=console, refresh_per_second=4, transient=False)

    def render(self):
        s = self.status
        head = Table.grid(padding=(0, 2))
        head.add_row("point", f"{s.point_id or '-'}  ({s.points_done}/{s.points_total} done)",
                     "command", s.command or "-")
        chamber = "-" if s.chamber_c is None else f"{s.chamber_c:.2f} C"
        head.add_row("chamber", chamber, "DUTs", temperatures_text(s.dut_temps_c))
        head.add_row("thermal", s.thermal or "-", "ETA", self.progress.eta_text())
        fits = Table("DUT", "live T24 fit", box=None)
        for dut, text in fit_rows(self.runner.live_summaries, getattr(self.runner, "live", {})):
            fits.add_row(dut, text)
        events = Text("\n".join(list(s.events)[-6:]) or "-", style="dim")
        return Group(head, fits, Text("recent events:", style="bold"), events)

    def point_done(self, point_id: str) -> None:
        pass  # the panel refreshes itself

    def fit_progress(self, dut: str | None, model: str | None, done: int, total: int) -> None:
        """After the panel: one line, rewritten in place, while the post-run fits run."""
        end = "\n" if dut is None else ""
        self.live.console.file.write("\r\x1b[2K" + fit_progress_line(dut, model, done, total) + end)
        self.live.console.file.flush()

    def suspended(self, prompt):
        """`prompt` wrapped so that the panel stops while the operator answers."""
        def ask(message: str) -> str:
            self.live.stop()
            try:
                return prompt(message)
            finally:
                self.live.start()
        return ask

    def __enter__(self):
        self.progress.eta_text()
        self.runner.on_point.append(self.point_done)
        self.live.__enter__()
        return self

    def __exit__(self, *exc):
        self.live.__exit__(*exc)


class PlainLog:
    def __init__(self, status: RunStatus, runner, stream=None, every_s: float = PLAIN_PROGRESS_EVERY_S,
                 monotonic=time.monotonic):
        self.status = status
        self.runner = runner
        self.progress = _Progress(status)
        self.stream = stream or sys.stdout
        self.every_s = every_s
        self.monotonic = monotonic  # the display's own pace, injectable (tests): not the run's clock
        self._last_line: float | None = None
        self.first_model: str | None = None

    def point_done(self, point_id: str) -> None:
        now = self.monotonic()
        last = self.status.points_done + 1 >= self.status.points_total
        if self._last_line is not None and now - self._last_line < self.every_s and not last:
            return
        self._last_line = now
        s = self.status
        temps = (temperatures_text(s.dut_temps_c) if len(s.dut_temps_c) > MAX_DUT_ROWS
                 else " ".join(f"{k}={v:.2f}C" for k, v in s.dut_temps_c.items()))
        chamber = "-" if s.chamber_c is None else f"{s.chamber_c:.2f}C"
        print(f"{point_id} done ({s.points_done + 1}/{s.points_total}) chamber={chamber} {temps} "
              f"eta={self.progress.eta_text()}", file=self.stream, flush=True)

    def fit_progress(self, dut: str | None, model: str | None, done: int, total: int) -> None:
        """A line per DUT (its first model) and at the end, while the post-run fits run."""
        if dut is None or model == self.first_model or self.first_model is None:
            self.first_model = self.first_model or model
            print(fit_progress_line(dut, model, done, total), file=self.stream, flush=True)

    def __enter__(self):
        self.progress.eta_text()
        self.runner.on_point.append(self.point_done)
        return self

    def __exit__(self, *exc):
        return None


def make_display(status: RunStatus, runner, *, live: bool, progress_every_s: float | None = None):
    """The live panel when asked for and stdout is a terminal; plain progress lines otherwise, at most one
    every `progress_every_s` seconds (default PLAIN_PROGRESS_EVERY_S; 0: one per point)."""
    if live and sys.stdout.isatty():
        return LiveDisplay(status, runner)
    every = PLAIN_PROGRESS_EVERY_S if progress_every_s is None else progress_every_s
    return PlainLog(status, runner, every_s=every)
