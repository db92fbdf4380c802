"""CLI: rig run."""

from __future__ import annotations

import sys
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from rig.core.errors import ConfigError
from rig.core.signals import set_terminate_handler


class RunNotCompleted(click.ClickException):
    """The run ended without taking every point (aborted or failed): exit code 1, one line."""

    exit_code = 1

    def show(self, file=None) -> None:
        click.echo(f"run not completed: {self.message}", err=True)


class AcceptanceFailed(click.ClickException):
    """The run completed but at least one DUT failed the plan's acceptance limits: exit code 3."""

    exit_code = 3

    def show(self, file=None) -> None:
        click.echo(f"acceptance: {self.message}", err=True)


def _terminate(signum, frame):
    raise KeyboardInterrupt("SIGTERM")


def _print_summary(outcome) -> None:
    from rig.run.summary import (
        CALIBRATION_COLUMNS,
        calibration_files,
        calibration_notes,
        calibration_rows,
        next_steps,
        outcome_lines,
    )

    console = Console()
    for line in outcome_lines(outcome):
        console.print(line, soft_wrap=True, highlight=False, markup=False)
    if outcome.stale_lock_pid is not None:
        console.print(f"note: took over the lock of dead run pid {outcome.stale_lock_pid} after making "
                      "the hardware safe")
    if not outcome.fits:
        return
    table = Table(title="calibrations")
    for col in CALIBRATION_COLUMNS:
        table.add_column(col, overflow="fold")
    for row in calibration_rows(outcome):
        table.add_row(*row)
    console.print(table)
    for line in [*calibration_files(outcome), *calibration_notes(outcome)]:  # paths whole: they are copied
        console.print(line, soft_wrap=True, highlight=False, markup=False)
    if outcome.verdicts:
        from rig.analysis.acceptance import summary_csv_path

        table = Table(title=f"acceptance (summary: {summary_csv_path(outcome.session_path)})")
        for col in ("DUT", "model", "verdict", "held-out RMS (nT)", "failed criteria"):
            table.add_column(col, overflow="fold")
        for v in outcome.verdicts:
            held = v.figures.get("heldout_rms_nt")
            table.add_row(v.dut, v.model, v.verdict, "-" if held is None else f"{held:.1f}",
                          "; ".join(v.failed + v.notes) or "-")
        console.print(table)
    for line in next_steps(outcome):
        console.print(line, soft_wrap=True, highlight=False, markup=False)


def _station_path_text(campaign, resume_path: Path | None) -> str:
    """The station file a run's header names: the plan's (or --station), or the one a session recorded."""
    if campaign is not None:
        return str(campaign.station_path)
    from rig.session.reader import SessionReader

    with SessionReader(resume_path) as reader:
        recorded = reader.info()["station_path"]
    return f"{recorded or 'its file'} as the session recorded it"


def _print_header(station, station_path: str) -> None:
    """The station, whether it is simulated, and what will dominate the uncertainty: printed once every
    limit is checked and the rig is connected, before the first point."""
    from rig.run.summary import header_lines

    for line in header_lines(station, station_path):
        click.echo(line)


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""

    @group.command("run")
    @click.argument("plan", required=False, type=click.Path(dir_okay=False))
    @click.option("--station", type=click.Path(dir_okay=False), help="Station file (default: the plan's, "
                  "else configs/stations/sim.yaml).")
    @click.option("--session", "session_path", type=click.Path(dir_okay=False),
                  help="Session file to create.")
    @click.option("--out", "out_dir", type=click.Path(file_okay=False),
                  help="Directory for the session and calibration files (default: the plan's outputs.dir).")
    @click.option("--resume", "resume_path", type=click.Path(dir_okay=False),
                  help="Continue this session at its first incomplete point (plan and station from it).")
    @click.option("--no-live", is_flag=True, help="Plain log lines instead of the live display.")
    @click.option("--progress-every", "progress_every_s", type=click.FloatRange(min=0), metavar="SECONDS",
                  help="Plain log (piped, or --no-live): at most one progress line this often "
                  "(default 5; 0: one line per point).")
    def run(plan, station, session_path, out_dir, resume_path, no_live, progress_every_s):
        """Run a calibration campaign (PLAN.yaml), or resume one (--resume SESSION)."""
        from rig.config.loading import load_campaign
        from rig.core.paths import session_file
        from rig.engine.commands import COMPLETED
        from rig.engine.executor import prompt_from_tty
        from rig.run.campaign import run_campaign
        from rig.run.display import make_display
        from rig.schedules.compile import located_errors

        if resume_path:
            if plan or station or session_path or out_dir:
                raise ConfigError("rig run --resume SESSION takes the plan and the station from the "
                                  "session: give no PLAN, --station, --session or --out with it")
            campaign, path = None, Path(resume_path)
        else:
            if not plan:
                raise ConfigError("rig run: give a PLAN file, or --resume SESSION")
            if session_path and out_dir:
                raise ConfigError("rig run: give --session PATH or --out DIR, not both")
            campaign = load_campaign(plan, station)
            path = Path(session_path) if session_path else session_file(
                out_dir or campaign.plan.outputs.dir, campaign.plan.name)
        station_path = _station_path_text(campaign, path if resume_path else None)
        interactive = sys.stdin.isatty()
        set_terminate_handler(_terminate)  # outside the engine's own handling: clean exit too
        with located_errors(campaign):  # a plan refused while compiling names its file, key and line
            outcome = run_campaign(
                campaign=campaign, session_path=path, resume=bool(resume_path),
                prompt=prompt_from_tty if interactive else None,
                display_factory=lambda status, runner: make_display(status, runner, live=not no_live,
                                                                    progress_every_s=progress_every_s),
                on_rig=lambda rig: _print_header(rig.station, station_path),
            )
        _print_summary(outcome)
        if outcome.result.status != COMPLETED:
            raise RunNotCompleted(f"{outcome.result.status}: {outcome.result.reason}; continue with: "
                                  f"rig run --resume {outcome.session_path}")
        failed = [v.dut for v in outcome.verdicts if not v.passed]
        if failed:
            total = len(outcome.verdicts)
            raise AcceptanceFailed(f"{len(failed)} of {total} DUT(s) FAIL: {', '.join(failed)}")
