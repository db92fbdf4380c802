"""CLI: rig report, rig export-cal, rig sessions."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from rig.cli.fleet_cmds import fleet_filters, list_fleet
from rig.core.errors import ERRORS, DataError, SessionError
from rig.report.exports import FORMATS
from rig.session.schema import SESSION_SUFFIXES


@click.command("report")
@click.argument("source", metavar="SESSION_OR_CAL", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--data",
    type=click.Path(dir_okay=False, path_type=Path),
    help="With a calibration file: the CSV it was fitted on.",
)
@click.option("--dut", help="Report on this DUT only (a session file; default: every DUT).")
@click.option(
    "-o",
    "--output-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("report"),
    show_default=True,
    help="Folder for report.html and its PNG figures.",
)
def report_cmd(source: Path, data: Path | None, dut: str | None, output_dir: Path) -> None:
    """Write a calibration report (one self-contained HTML file plus PNG figures) from a session file,
    or from a calibration file and the CSV it was fitted on (--data)."""
    from rig.report.build import read_inputs, write_report

    try:
        inputs = read_inputs(source, data=data, dut=dut)
        for d in inputs.duts:  # what the calibration shown does not state of its measurand, a line each
            for what in [] if d.calibration is None else d.calibration.missing_measurand():
                click.echo(f"note: {d.name}: its {d.calibration.model} calibration does not state {what}",
                           err=True)
        page, *figures = write_report(inputs, output_dir,
                                      progress=lambda said: click.echo(f"report: {said}", err=True))
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # numbers the checks let through
        raise DataError(f"{source}: cannot build the report: {exc}") from None
    click.echo(f"wrote {page} ({len(figures)} figures beside it)")


@click.command("export-cal")
@click.argument("calibration", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(FORMATS), required=True, help="Export format.")
@click.option("--name", help="Name of the C symbols (default: the DUT, else the calibration file's name).")
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    help="File to write (default: standard output).",
)
def export_cal_cmd(calibration: Path, fmt: str, name: str | None, output: Path | None) -> None:
    """Export a calibration for firmware (C header) or other tools (JSON, CSV of parameters)."""
    from calib.io import calfile
    from calib.io.atomic import atomic_write
    from rig.report.exports import export_calibration

    cal = calfile.load(calibration)
    symbol = name or cal.source.get("dut") or (output.stem if output else calibration.stem)
    text = export_calibration(cal, fmt, str(symbol))
    if output is None:
        click.echo(text, nl=False)
        return
    try:
        with atomic_write(output) as f:
            f.write(text)
    except OSError as exc:
        raise DataError(f"{output}: cannot write ({exc.strerror or exc})") from None
    click.echo(f"wrote {output} ({fmt}, model {cal.model})")


DEFAULT_SESSIONS_DIR = Path("sessions")  # where `rig run` writes (a plan's default outputs.dir)


@click.command("sessions")
@click.argument("directory", required=False, type=click.Path(file_okay=False, path_type=Path))
@click.option("--db", "db_url", metavar="URL", help="List the fleet database's sessions instead (all rigs).")
@fleet_filters
def sessions_cmd(directory: Path | None, db_url: str | None, **filters) -> None:
    """One line per session file in DIRECTORY (default: sessions/, where `rig run` writes): date, station,
    DUTs, points done of planned, exit status, verdict, and the residual of the calibration the plan judges.
    Files that are not sessions, or are damaged, get a one-line note. With --db, the sessions pushed to
    the fleet database, across rigs, filtered by station, DUT, date and verdict."""
    from rig.report.sessions import HEADER, session_files, session_line, skipped_line

    if db_url:
        list_fleet(db_url, **filters)
        return
    given = [f"--{name}" for name, value in filters.items() if value is not None]
    if given:
        raise click.UsageError(f"{', '.join(given)}: filters of the fleet database listing; add --db URL")

    if directory is None:
        directory = DEFAULT_SESSIONS_DIR
        if not directory.is_dir():
            raise SessionError(f"{directory}/: no such folder here (`rig run` writes its sessions into the "
                               "plan's outputs.dir, default sessions/); give the folder: rig sessions DIR")
    if not directory.is_dir():
        raise SessionError(f"{directory}: no such folder")
    files = session_files(directory, SESSION_SUFFIXES)
    if not files:
        click.echo(f"no session files ({', '.join('*' + s for s in SESSION_SUFFIXES)}) in {directory}")
        return
    click.echo(HEADER)
    for path in files:
        try:
            click.echo(session_line(path))
        except ERRORS as exc:
            click.echo(skipped_line(path, str(exc)))


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""
    group.add_command(report_cmd)
    group.add_command(export_cal_cmd)
    group.add_command(sessions_cmd)
