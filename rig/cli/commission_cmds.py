"""CLI: rig commission."""

from __future__ import annotations

from pathlib import Path

import click

from rig.core.signals import set_terminate_handler


def _terminate(signum, frame):
    raise KeyboardInterrupt("SIGTERM")


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""

    @group.command("commission")
    @click.argument("station_path", metavar="STATION.yaml", type=click.Path(dir_okay=False, path_type=Path))
    @click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
                  help="Folder for <station>.commissioning.yaml.")
    @click.option("--repeats", type=click.IntRange(1, 20), default=2, show_default=True,
                  help="How many times the whole set of settings is measured (drift between repeats).")
    @click.option("--current", "current_a", type=float, default=None,
                  help="Largest coil current, A (default: 0.8 x max_current_a, at most ~60 uT per coil).")
    @click.option("--thermal", is_flag=True,
                  help="Also measure what planning needs: the chamber's real rate and overshoot, each DUT's "
                  "lag, offset and noise, the pace of a point (a step of the chamber's set point: hours).")
    @click.option("--thermal-step", "thermal_step_c", type=click.FloatRange(1.0, 50.0), default=None,
                  help="The step of the chamber's set point, degC (default 15; down when up leaves the "
                  "limits).")
    @click.option("--position", "position", default=None, metavar="X,Y,Z",
                  help="The reference moved to this place (mm): measured there and added to the file written "
                  "at its own place, and each coil loop fitted to every place (run once per place).")
    def commission_cmd(station_path: Path, out_dir: Path, repeats: int, current_a: float | None,
                       thermal: bool, thermal_step_c: float | None, position: str | None) -> None:
        """Measure the field source (coil matrix and ambient, or the turntable's axes) with the station's
        reference magnetometer and write the commissioning file a station names in
        `field_source: {commissioning: FILE}`; with --thermal also the chamber and each DUT position."""
        from rig.commission.procedure import commission
        from rig.config import load_station
        from rig.config.commissioning_file import read

        set_terminate_handler(_terminate)  # every exit leaves the coils safe (commission's finally)
        out_dir.mkdir(parents=True, exist_ok=True)
        if position is not None:
            from rig.commission.places import commission_place, parse_position
            from rig.core.errors import ConfigError

            if thermal:
                raise ConfigError("rig commission: --thermal is measured with the reference at its own place "
                                  "(without --position)")
            path = commission_place(station_path, out_dir, parse_position(position), repeats=repeats,
                                    current_a=current_a)
        else:
            path = commission(station_path, out_dir, repeats=repeats, current_a=current_a, thermal=thermal,
                              thermal_step_c=thermal_step_c)
        com = read(path)
        click.echo(f"wrote {path}")
        click.echo(com.summary())
        station = load_station(station_path)
        for line in station.field_source.commissioning_lines(com.section):
            click.echo(line)
        if com.thermal is not None:
            from rig.planning.inputs import thermal_lines

            for line in thermal_lines(com.thermal):
                click.echo(line)
