"""The `rig` command. Each family of subcommands lives in its own module and registers itself; a module
is imported only when one of its commands runs (or `rig --help` lists them), so `rig --version` and a
`rig refit` do not pay for the imports of `rig run` or `rig report`.

Errors of the project's family print as one line (`error: ...`) with exit code 2; a traceback only
with --debug. A bad option or argument value (a folder given for a file) is one line too. Ctrl-C exits 130.
"""

from __future__ import annotations

import os

# One BLAS thread: on a small machine BLAS threads fight each other and the rig's I/O threads
# (a robust scalar fit ran 10x slower with the default). Must be set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import importlib  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402

import click

from rig import __version__
from rig.core.errors import ERRORS

# command name -> the module of rig.cli whose register() adds it (tests/unit/rig/test_cli_startup.py)
COMMAND_MODULES = {
    "refit": "calib_cmds", "apply": "calib_cmds",
    "devices": "device_cmds",
    "check": "store_cmds", "export": "store_cmds",
    "run": "campaign_cmds",
    "commission": "commission_cmds",
    "design": "design_cmds",
    "report": "report_cmds", "export-cal": "report_cmds", "sessions": "report_cmds",
    "push": "fleet_cmds", "fleet": "fleet_cmds", "refit-all": "fleet_cmds",
    "serve": "serve_cmds",
    "certificate": "certificate_cmds",
}


class LazyGroup(click.Group):
    """Imports a command's module when the command is asked for."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMAND_MODULES)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in self.commands and name in COMMAND_MODULES:
            importlib.import_module(f"rig.cli.{COMMAND_MODULES[name]}").register(self)
        return self.commands.get(name)


@click.group(cls=LazyGroup)
@click.version_option(__version__, prog_name="magrig")
@click.option("--debug", is_flag=True, help="Show tracebacks and debug logs (raw frames).")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """magrig: run the AMR magnetometer calibration rig and fit its calibrations."""
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug
    logging.basicConfig(
        level=logging.DEBUG if debug else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    # pymodbus logs every timeout as ERROR with frame dumps; our transport retries and reports them itself.
    logging.getLogger("pymodbus").setLevel(logging.DEBUG if debug else logging.CRITICAL)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    debug = "--debug" in args
    try:
        cli.main(args=args, prog_name="rig", standalone_mode=False)
    except ERRORS as err:
        if debug:
            raise
        for line in str(err).splitlines() or [""]:  # a file with several problems: one line each
            click.echo(f"error: {line}", err=True)
        return 2
    except click.BadParameter as err:  # e.g. a folder where a file belongs: the value is the news
        click.echo(f"error: {' '.join(err.format_message().split())}", err=True)
        return 2
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return 130
    except click.ClickException as err:
        err.show()
        return err.exit_code
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
