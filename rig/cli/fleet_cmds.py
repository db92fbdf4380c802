"""CLI: rig push (sessions into the fleet database), rig fleet list (sessions across rigs), rig refit-all
(every DUT of every session, in parallel on Dask). The database is PostgreSQL, named by a URL
(postgresql://user@host:port/dbname) given with --db or in $MAGRIG_DB."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import click

from calib.models.registry import MODELS
from rig import __version__
from rig.core.errors import ERRORS, MagrigError
from rig.fleet import DATE_FORMATS

DB_OPTION = click.option("--db", "db_url", metavar="URL", envvar="MAGRIG_DB",
                         help="Fleet database, e.g. postgresql://rig@db.lab/magrig (default: $MAGRIG_DB).")
DATE = click.DateTime(DATE_FORMATS)


def fleet_filters(f):
    """The fleet listing's filters, shared by `rig fleet list` and `rig sessions --db`."""
    for option in reversed((
        click.option("--station", help="Only this station."),
        click.option("--dut", metavar="NAME_OR_SERIAL",
                     help="Only sessions with this DUT (name or serial number)."),
        click.option("--since", type=DATE, help="Started on or after this UTC date/time."),
        click.option("--until", type=DATE, help="Started before this UTC date/time."),
        click.option("--verdict", type=click.Choice(["PASS", "FAIL"], case_sensitive=False),
                     help="Only sessions whose acceptance result is this."),
    )):
        f = option(f)
    return f


def _need_db(db_url: str | None) -> str:
    if not db_url:
        raise click.UsageError("name the fleet database with --db URL (or set MAGRIG_DB)")
    return db_url


def _expand(paths: tuple[Path, ...]) -> list[Path]:
    """Files as given; a folder stands for its session files."""
    from rig.fleet.source import session_files

    out: list[Path] = []
    for p in paths:
        out.extend(session_files(p) if p.is_dir() else [p])
    return out


@click.command("push")
@click.argument("sessions", metavar="SESSION_OR_DIR...", nargs=-1, required=True,
                type=click.Path(path_type=Path))
@DB_OPTION
def push_cmd(sessions: tuple[Path, ...], db_url: str | None) -> None:
    """Copy sessions into the fleet database, one transaction each. A session already there unchanged
    is left alone; one that grew since (a campaign still running) is replaced whole. Run it again after
    an interruption: it carries on where it stopped."""
    from rig.fleet.push import push_snapshot
    from rig.fleet.schema import connect
    from rig.fleet.source import session_snapshot

    paths = _expand(sessions)
    counts = {"added": 0, "replaced": 0, "unchanged": 0, "failed": 0}
    with connect(_need_db(db_url)) as conn:
        for path in paths:
            try:
                result = push_snapshot(conn, session_snapshot(path))
            except ERRORS as exc:
                counts["failed"] += 1
                click.echo(f"failed     {path}: {str(exc).removeprefix(f'{path}: ')}")
                continue
            counts[result.outcome] += 1
            click.echo(f"{result.outcome:<10} {path} (session {result.uid[:12]}, {result.samples} samples)")
    click.echo("pushed " + ", ".join(f"{n} {what}" for what, n in counts.items() if n or what == "added"))
    if counts["failed"]:
        raise MagrigError(f"{counts['failed']} of {len(paths)} session(s) not pushed (reasons above)")


@click.group("fleet")
def fleet_group() -> None:
    """The fleet database: sessions of every rig."""


@fleet_group.command("list")
@DB_OPTION
@fleet_filters
def list_cmd(db_url, station, dut, since, until, verdict) -> None:
    """One line per session in the fleet database: started, station, DUTs, points, exit, verdict, file."""
    list_fleet(_need_db(db_url), station, dut, since, until, verdict)


def list_fleet(db_url: str, station, dut, since, until, verdict) -> None:
    """The fleet listing (also `rig sessions --db URL`)."""
    from rig.fleet.query import LISTING_COLUMNS, Filters, list_sessions, listing_cells
    from rig.fleet.schema import connect

    filters = Filters(station=station, dut=dut, since=_utc(since), until=_utc(until), verdict=verdict)
    with connect(db_url) as conn:
        rows = list_sessions(conn, filters)
    if not rows:
        click.echo("no sessions match")
        return
    click.echo(fleet_line(*LISTING_COLUMNS))
    for r in rows:
        click.echo(fleet_line(*listing_cells(r)))
    click.echo(f"{len(rows)} session(s)")


def fleet_line(*cells: str) -> str:
    widths = (13, 17, 16, 20, 10, 13, 8)
    *fixed, last = cells
    return " ".join(f"{c:<{w}}" for c, w in zip(fixed, widths, strict=True)) + " " + last


def _utc(value: dt.datetime | None) -> dt.datetime | None:
    return None if value is None else value.replace(tzinfo=dt.UTC)


@click.command("refit-all")
@click.argument("sessions_dir", metavar="[SESSIONS_DIR]", required=False,
                type=click.Path(file_okay=False, path_type=Path))
@DB_OPTION
@click.option("--model", type=click.Choice(MODELS), default="t24", show_default=True)
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Results table to write (Parquet).")
@click.option("--scheduler", metavar="tcp://HOST:PORT",
              help="An existing Dask cluster (default: a local one).")
@click.option("--workers", type=click.IntRange(1, 256), default=2, show_default=True,
              help="Worker processes of the local cluster.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
def refit_all_cmd(sessions_dir, db_url, model, out, scheduler, workers, no_progress) -> None:
    """Re-fit every DUT of every session in SESSIONS_DIR, or of the fleet database (--db), in parallel.
    One row per DUT (parameters, standard errors, residuals, status and reason) goes to OUT; with --db
    the rows also go into the database's refit_results. A failed fit is a row with its reason."""
    from rig.fleet import batch
    from rig.fleet.query import session_uids
    from rig.fleet.schema import connect
    from rig.fleet.source import session_files

    if sessions_dir is None and not db_url:
        raise click.UsageError("give SESSIONS_DIR, or --db URL to re-fit the fleet database's sessions")
    conn = connect(db_url) if db_url else None
    try:
        if sessions_dir is not None:
            if not sessions_dir.is_dir():
                raise MagrigError(f"{sessions_dir}: no such folder")
            tasks = batch.file_tasks(session_files(sessions_dir), model, __version__)
        else:
            tasks = batch.db_tasks(db_url, session_uids(conn), model, __version__)
        if not tasks:
            raise MagrigError(f"no sessions in {sessions_dir or 'the fleet database'}")
        with batch.dask_client(scheduler, workers) as client:
            rows = batch.run_tasks(client, tasks, model, __version__, progress=not no_progress)
        batch.write_parquet(rows, out)
        if conn is not None:
            batch.write_results_db(conn, rows)
    finally:
        if conn is not None:
            conn.close()
    failed = [r for r in rows if r["status"] != "ok"]
    click.echo(f"re-fitted {len(rows) - len(failed)} DUT(s) of {len(tasks)} session(s) with {model}; "
               f"{len(failed)} failed; wrote {out}" + (" and the fleet database" if conn is not None else ""))
    for r in failed[:20]:
        click.echo(f"  failed {r['source']} {r['dut'] or '(session)'}: {r['reason']}")
    if len(failed) > 20:
        click.echo(f"  ... and {len(failed) - 20} more (see {out})")


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""
    group.add_command(push_cmd)
    group.add_command(fleet_group)
    group.add_command(refit_all_cmd)
