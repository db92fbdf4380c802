"""CLI: rig serve (the cockpit in the browser)."""

from __future__ import annotations

import os
from pathlib import Path

import click

from rig.cli.fleet_cmds import DB_OPTION
from rig.core.errors import SessionError
from rig.core.signals import set_terminate_handler

DEFAULT_DIR = Path("sessions")
NICENESS = 10  # the cockpit yields the CPU to a campaign running on the same machine


def _stop(signum, frame):
    raise KeyboardInterrupt


@click.command("serve")
@click.argument("sessions_dirs", metavar="[SESSIONS_DIR]...", nargs=-1,
                type=click.Path(file_okay=False, path_type=Path))
@DB_OPTION
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on; anything but loopback needs --token.")
@click.option("--port", type=click.IntRange(0, 65535), default=8765, show_default=True,
              help="Port to listen on (0: any free one, printed at start).")
@click.option("--token", envvar="MAGRIG_TOKEN", metavar="TOKEN",
              help="Secret every request must carry (default: $MAGRIG_TOKEN); needed off loopback.")
def serve_cmd(sessions_dirs: tuple[Path, ...], db_url: str | None, host: str, port: int,
              token: str | None) -> None:
    """The cockpit: live campaigns (temperatures, progress, residuals, events; pause and abort), the
    sessions of SESSIONS_DIR (default: ./sessions) with their calibrations, reports and downloads, and with
    --db the fleet database. Session files are only read; Ctrl-C stops the server."""
    from rig.web.server import Cockpit, serve

    roots = list(sessions_dirs) or ([DEFAULT_DIR] if DEFAULT_DIR.is_dir() or not db_url else [])
    for root in roots:
        if not root.is_dir():
            raise SessionError(f"{root}: no such folder (give the folders holding session files)")
    app = Cockpit(roots=roots, db_url=db_url, token=token or None)

    def ready(server) -> None:
        shown = f"[{host}]" if ":" in host else host
        what = ", ".join(str(r) for r in roots) or "no session folder"
        click.echo(f"cockpit on http://{shown}:{server.server_address[1]}/ serving {what}"
                   + (" and the fleet database" if db_url else "")
                   + ("; open it once with ?token=YOUR_TOKEN" if token else "") + "; Ctrl-C stops it")

    set_terminate_handler(_stop)
    if hasattr(os, "nice"):  # Windows has no nice: the cockpit then runs at normal priority
        os.nice(NICENESS)
    serve(app, host, port, ready=ready)


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""
    group.add_command(serve_cmd)
