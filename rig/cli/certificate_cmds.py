"""CLI: rig certificate (a calibration certificate per DUT and its DCC, rig/report/certificate.py)."""

from __future__ import annotations

from pathlib import Path

import click


@click.command("certificate")
@click.argument("session", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--dut", "duts", multiple=True,
              help="The DUT to certify (repeat for several; default: every DUT with a calibration).")
@click.option("-o", "--output-dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("certificates"), show_default=True, help="Folder for the certificates.")
@click.option("--pdf/--no-pdf", default=True, show_default=True, help="Print each to PDF too.")
@click.option("--dcc/--no-dcc", default=True, show_default=True,
              help="Write each one's Digital Calibration Certificate (PTB DCC 3.1.2 XML), NAME.dcc.xml.")
def certificate_cmd(session: Path, duts: tuple[str, ...], output_dir: Path, pdf: bool, dcc: bool) -> None:
    """Write the calibration certificate of a session's DUT (ISO/IEC 17025 7.8): HTML, PDF and its DCC.
    Refused, naming the file and what it lacks, for a calibration without an uncertainty, with inputs of
    unstated uncertainty, or without a reference chain."""
    from rig.core.errors import DataError
    from rig.report.certificate import session_record, write_certificate
    from rig.session.schema import looks_like_session

    if not session.is_file() or not looks_like_session(session):
        raise DataError(f"{session}: not a session file")
    recorded = session_record(session)  # once for every DUT certified
    for dut in duts or recorded["duts"]:
        written, said = write_certificate(session, dut, output_dir, pdf=pdf, dcc=dcc, recorded=recorded)
        others = ", ".join(p.name for p in written[1:])
        click.echo(f"wrote {written[0]}" + (f" and {others}" if others else "")
                   + ("" if any(p.suffix == ".pdf" for p in written) else f"; {said}"))


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""
    group.add_command(certificate_cmd)
