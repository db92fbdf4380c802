"""CLI: rig check, rig export."""

from __future__ import annotations

from pathlib import Path

import click

from calib.io.atomic import atomic_write
from rig.config.loading import load_campaign
from rig.core.errors import ConfigError
from rig.schedules.compile import check_campaign
from rig.session.reader import SessionReader


@click.command("check")
@click.argument("plan_path", metavar="PLAN.yaml", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--station", "station_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Station file (default: the plan's `station:`, else configs/stations/sim.yaml).")
@click.option("--figure", "figure_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Designed or sequential plan: write the predicted temperatures and standard errors "
              "against chamber time to this PNG.")
def check_cmd(plan_path: Path, station_path: Path | None, figure_path: Path | None) -> None:
    """Validate a plan against its station without touching hardware; print the step count and an
    estimate of the campaign's duration (and, for a designed plan, its predicted standard errors)."""
    campaign = load_campaign(plan_path, station_path)
    report = check_campaign(campaign)
    if figure_path is not None and report.prediction is None:
        raise ConfigError(f"--figure {figure_path}: plan {campaign.plan.name} predicts no standard errors to "
                          "draw (a designed or sequential plan with stop_when does)")
    from rig.run.summary import header_lines

    click.echo(f"plan {campaign.plan.name} ({plan_path}): OK")
    for line in [*header_lines(campaign.station, campaign.station_path), *report.summary_lines()]:
        click.echo(line)
    if figure_path is not None:
        from rig.report.designfig import write_schedule_figure

        write_schedule_figure(report.prediction,
                              f"plan {campaign.plan.name} on station {campaign.station.name}",
                              figure_path)
        click.echo(f"wrote {figure_path}")


@click.command("export")
@click.argument("session_path", metavar="SESSION", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--csv", "as_csv", is_flag=True, default=True, help="Write CSV (the only format so far).")
@click.option("--dut", help="Which DUT (needed when the session has several).")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Output CSV file.")
@click.option("--include-flagged", is_flag=True,
              help="Also write flagged samples (overflow, saturated...); they are left out by default.")
def export_cmd(session_path: Path, as_csv: bool, dut: str | None, output: Path,
               include_flagged: bool) -> None:
    """Write one DUT's samples as CSV: hx,hy,hz raw nT, temp degC, bx,by,bz reference nT, plus point, t,
    setpoint, reference temperature, SET/RESET offsets and flags. `rig refit` reads it."""
    with SessionReader(session_path) as reader:
        dut, rows = reader.sample_rows(dut)
    kept = [r for r in rows if include_flagged or not r["flags"]]
    _write_csv_atomically(output, kept)
    left_out = len(rows) - len(kept)
    note = f" ({left_out} flagged sample(s) left out)" if left_out else ""
    click.echo(f"wrote {len(kept)} samples of {dut} to {output}{note}")


def _write_csv_atomically(output: Path, rows: list[dict]) -> None:
    """A failure never leaves half a file (nor touches an existing one)."""
    from rig.report.exports import write_samples_csv

    output.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(output, "w", newline="") as f:
        write_samples_csv(f, rows)


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""
    group.add_command(check_cmd)
    group.add_command(export_cmd)
