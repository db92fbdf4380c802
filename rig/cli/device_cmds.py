"""CLI: rig devices check."""

from __future__ import annotations

import click
from rich.console import Console
from rich.table import Table


class DevicesFailed(click.ClickException):
    exit_code = 1

    def show(self, file=None) -> None:
        click.echo(f"error: {self.message}", err=True)


def _reading_text(reading) -> str:
    if reading is None:
        return "-"
    fields = getattr(reading, "__dataclass_fields__", None)
    if not fields:
        return str(reading)
    parts = []
    for name in fields:
        if name == "t":
            continue
        value = getattr(reading, name)
        if isinstance(value, float):
            value = f"{value:.3f}"
        elif isinstance(value, tuple) and value and isinstance(value[0], float):
            value = "(" + ", ".join(f"{v:.1f}" for v in value) + ")"
        elif isinstance(value, frozenset):
            value = ",".join(sorted(value)) or "-"
        parts.append(f"{name}={value}")
    return " ".join(parts)


def _identity_text(describe: dict | None) -> str:
    if describe is None:
        return "-"
    keys = ("model", "firmware", "product_id", "serial_number", "link", "address", "port")
    return " ".join(f"{k}={describe[k]}" for k in keys if describe.get(k) not in (None, ""))


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""

    @group.group("devices")
    def devices():
        """Commission a station's devices."""

    @devices.command("check")
    @click.argument("station_path", type=click.Path(dir_okay=False))
    def check(station_path):
        """Connect to every device of STATION.yaml, show its identity and one reading, and say which
        devices fail and why (exit code 1 if any does)."""
        from rig.config import load_station
        from rig.station import check_devices

        station = load_station(station_path)
        results = check_devices(station)
        simulated = station.simulated_devices()
        table = Table(title=f"station {station.name}")
        for col in ("device", "sim", "status", "identity", "reading / error"):
            table.add_column(col, overflow="fold")
        failed = []
        for name, describe, reading, error in results:
            sim = "sim" if simulated.get(name) else "real"
            if error is None:
                table.add_row(name, sim, "[green]ok[/]", _identity_text(describe), _reading_text(reading))
            else:
                failed.append(name)
                table.add_row(name, sim, "[red]FAILED[/]", "-", error)
        Console().print(table)
        if failed:
            raise DevicesFailed(f"{len(failed)} of {len(results)} devices failed: {', '.join(failed)}")
        click.echo(f"all {len(results)} devices answer")
