"""The live view with many DUTs: the DUTs with the largest live residual first, then a count; the
temperatures as a range."""

from __future__ import annotations

import io
from types import SimpleNamespace

from rich.console import Console

from rig.engine.executor import RunStatus
from rig.run.display import MAX_DUT_ROWS, LiveDisplay, fit_rows, temperatures_text


def _runner(n: int):
    live = {f"d{k:02d}": SimpleNamespace(rms_nt=None if k == 0 else float(k % 13)) for k in range(n)}
    summaries = {name: f"{name} fit text" for name in live}
    return SimpleNamespace(live=live, live_summaries=summaries, on_point=[])


def test_a_few_duts_are_all_shown_in_their_order():
    runner = _runner(4)
    assert fit_rows(runner.live_summaries, runner.live) == list(runner.live_summaries.items())
    assert temperatures_text({"a": 20.0, "b": 21.5}) == "a 20.00 C, b 21.50 C"


def test_many_duts_show_the_largest_residuals_and_a_count():
    runner = _runner(64)
    rows = fit_rows(runner.live_summaries, runner.live)
    assert len(rows) == MAX_DUT_ROWS + 1
    shown = [name for name, _ in rows[:-1]]
    rms = [runner.live[name].rms_nt for name in shown]
    assert rms == sorted(rms, reverse=True) and rms[0] == 12.0
    assert rows[-1][0] == f"+{64 - MAX_DUT_ROWS} more"
    temps = {f"d{k:02d}": 20.0 + k / 100 for k in range(64)}
    assert temperatures_text(temps) == "64 DUTs, 20.00 .. 20.63 C"


def test_the_panel_of_64_duts_fits_a_screen():
    runner = _runner(64)
    status = RunStatus()
    status.dut_temps_c.update({name: 22.0 for name in runner.live})
    console = Console(file=io.StringIO(), width=120)
    console.print(LiveDisplay(status, runner, console=console).render())
    lines = console.file.getvalue().splitlines()
    assert len(lines) < 25, len(lines)
    assert sum("fit text" in line for line in lines) == MAX_DUT_ROWS
