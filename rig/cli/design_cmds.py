"""CLI: rig design (the least-time plan for a plan's targets on a station)."""

from __future__ import annotations

import os
from pathlib import Path

import click

from rig.core.errors import ConfigError


@click.command("design")
@click.argument("plan_path", metavar="PLAN.yaml", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--station", "station_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Station file (default: the plan's `station:`, else configs/stations/sim.yaml).")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Designed plan to write (default: PLAN-designed.yaml beside the plan).")
@click.option("--from", "session_path", type=click.Path(dir_okay=False, path_type=Path),
              help="An earlier session of these DUTs: their noise and lags, the chamber's pace and a point's "
              "pace are taken from it.")
@click.option("--criterion", type=click.Choice(["I", "D"]), default="I", show_default=True,
              help="Field design: I-optimal (average prediction variance over the plan's fields) or "
              "D-optimal.")
@click.option("--checks", "n_checks", type=click.IntRange(0, 20), default=3, show_default=True,
              help="Interior temperatures of the model check (T24's linearity), one sweep each.")
def design_cmd(plan_path: Path, station_path: Path | None, output: Path | None, session_path: Path | None,
               criterion: str, n_checks: int) -> None:
    """Design the plan that reaches PLAN's targets (stop_when, or acceptance.max_std_error) for every DUT
    of the station in the least chamber time, and write it as a plan file."""
    from calib.io.atomic import atomic_write
    from rig.config.loading import load_campaign
    from rig.planning.design import design_inputs, design_plan, designed_plan_text, schedule_lines
    from rig.schedules.compile import check_campaign, located_errors

    campaign = load_campaign(plan_path, station_path)
    if session_path is not None and not session_path.is_file():
        raise ConfigError(f"--from {session_path}: no such session file")
    with located_errors(campaign):
        check_campaign(campaign)  # the plan as given must be sound on this station first
        inputs = design_inputs(campaign.plan, campaign.station, session_path)
        designed = design_plan(campaign.plan, campaign.station, inputs, criterion=criterion,
                               n_checks=n_checks)
    output = output or plan_path.with_name(f"{plan_path.stem}-designed.yaml")
    station_ref = os.path.relpath(campaign.station_path.resolve(), output.resolve().parent)
    made_for = (f"from {plan_path.name} and the noise and lags of session {session_path.name}" if session_path
                else f"from {plan_path.name} and the noise and lags the station states or its commissioning "
                "measured")
    text = designed_plan_text(campaign.plan_text, designed, campaign.station,
                              name=f"{campaign.plan.name}-designed", station_ref=station_ref,
                              made_for=made_for)
    output.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(output, "w") as f:
        f.write(text)
    s = designed.schedule
    click.echo(f"designed {output} for station {campaign.station.name}: {len(designed.targets_nt)} "
               f"{criterion}-optimal fields x {designed.samples} samples per sweep, "
               f"{sum(leg.sweeps for leg in s.legs)} sweeps in {len(s.legs)} legs")
    for line in inputs.planning.lines():
        click.echo(line)
    for note in inputs.notes:
        click.echo(f"note: {note}")
    for line in schedule_lines(s, inputs):
        click.echo(line)
    checked = load_campaign(output, campaign.station_path)
    with located_errors(checked):
        report = check_campaign(checked)
    click.echo(f"rig check of {output}: OK, estimated duration {report.duration_text()}")


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""
    group.add_command(design_cmd)
