"""CLI: rig devices check, rig devices scan."""

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
        from rig.devices.build import check_devices

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

    @devices.command("scan")
    @click.argument("station_path", required=False, metavar="[STATION.yaml]", type=click.Path(dir_okay=False))
    @click.option("--bus", "buses", type=click.IntRange(0, 255), multiple=True, metavar="N",
                  help="Scan /dev/i2c-N (repeatable), without a station file.")
    @click.option("--port", "ports", multiple=True, metavar="PATH",
                  help="Scan this serial port (repeatable).")
    @click.option("--baud", type=click.Choice(["9600", "19200"]), default="9600", show_default=True,
                  help="First baud rate to ask --port at (the other is tried when nothing answers).")
    @click.option("--ids", metavar="A-B", help="Serial device ids to ask (default: 0-98, all of them).")
    @click.option("--bridges", is_flag=True,
                  help="List the USB-to-I2C bridges plugged in (MCP2221A, CP2112, FT232H) and scan each "
                       "one's bus.")
    def scan(station_path, buses, ports, baud, ids, bridges):
        """Which I2C addresses answer on each bus of STATION.yaml (and behind each TCA9548A/PCA9548A switch
        channel), and which serial devices on its ports, each with what it is (its identification
        registers or replies), matched with the station's devices. Or one bus (--bus N) or port (--port)."""
        from rig.devices.scan import scan_station, scan_targets

        if not (station_path or buses or ports or bridges):
            raise click.UsageError("give STATION.yaml, --bus N, --port PATH or --bridges")
        device_ids = _id_range(ids)
        if station_path:
            from rig.config import load_station

            report = scan_station(load_station(station_path), device_ids=device_ids)
            if buses or ports or bridges:
                extra = scan_targets(list(buses), [(p, int(baud)) for p in ports], device_ids=device_ids,
                                     bridges=bridges)
                report.bridges += extra.bridges
                report.buses += extra.buses
                report.ports += extra.ports
        else:
            report = scan_targets(list(buses), [(p, int(baud)) for p in ports], device_ids=device_ids,
                                  bridges=bridges)
        for line in report.lines():
            click.echo(line)
        if report.problems:
            raise DevicesFailed("; ".join(report.problems))


def _id_range(text: str | None) -> range | None:
    if text is None:
        return None
    low, sep, high = text.partition("-")
    try:
        first, last = int(low), int(high if sep else low)
    except ValueError:
        raise click.BadParameter(f"{text!r}: give ids as A-B, e.g. 0-98", param_hint="--ids") from None
    if not 0 <= first <= last <= 98:
        raise click.BadParameter(f"{text!r}: ids are 0..98", param_hint="--ids")
    return range(first, last + 1)
