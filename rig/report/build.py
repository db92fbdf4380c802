"""Build the calibration report: fit every model the data allows, compare them on held-out points,
collect data-quality warnings, draw the figures and write one self-contained HTML file plus the PNGs.

    path = build_report(SESSION_OR_CAL, data=None, dut=None, out_dir="report")
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from rig.core.errors import DataError
from rig.core.names import collision
from rig.core.paths import inside
from rig.report.evaluate import analyse_dut
from rig.report.html import ItemList, Links, Section, Table, images_in, render_html
from rig.report.page import dut_sections, summary_table
from rig.report.sources import ReportInputs, from_calibration, from_session
from rig.session.schema import looks_like_session


def build_report(
    source: str | Path,
    *,
    data: str | Path | None = None,
    dut: str | None = None,
    out_dir: str | Path = "report",
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Write report.html and its PNG figures into out_dir; return the HTML path. `progress` hears of each
    DUT drawn."""
    return write_report(read_inputs(source, data=data, dut=dut), out_dir, progress)[0]


def write_report(inputs: ReportInputs, out_dir: str | Path, progress: Callable[[str], None] | None = None
                 ) -> list[Path]:
    """Analyse, draw and write: returns [the HTML page, *the PNG figures]; `progress` hears of each DUT."""
    sections = report_sections(inputs, progress)
    out = Path(out_dir)
    written = [out / "report.html"]
    try:
        out.mkdir(parents=True, exist_ok=True)
        if inputs.session is not None:  # each DUT's certificate beside the page, linked from it
            certificates, refused = write_certificates(inputs.session, [d.name for d in inputs.duts], out)
            none = "none: no DUT has a calibration file beside the session"
            sections.insert(-1, Section("Calibration certificates", [
                Links(certificates, none if not refused else "none written"),
                ItemList([f"refused: {why}" for why in refused], kind="warning", empty_text="")]))
        for img in images_in(sections):
            written.append(inside(out, img.filename))
            written[-1].write_bytes(img.png)
        written[0].write_text(
            render_html(inputs.title, sections, subtitle=_subtitle(inputs)), encoding="utf-8"
        )
    except OSError as exc:
        raise DataError(f"{out}: cannot write the report: {exc.strerror or exc}") from None
    return written


def write_certificates(session: Path, duts: list[str], out: Path) -> tuple[list[tuple[str, str]], list[str]]:
    """Each DUT's calibration certificate (HTML; rig certificate prints PDFs and DCCs too) in `out`:
    ([(text, name)], [why a certificate was refused])."""
    from rig.core.paths import calibration_file
    from rig.report.certificate import CertificateRefused, session_record, write_certificate
    from rig.report.certificate_record import CERTIFIED_MODELS

    links, refused, recorded = [], [], None
    for dut in duts:
        if any(calibration_file(session, dut, m).is_file() for m in CERTIFIED_MODELS):
            recorded = recorded or session_record(session)
            try:
                page = write_certificate(session, dut, out, pdf=False, dcc=False, recorded=recorded)[0][0]
            except CertificateRefused as exc:
                refused.append(str(exc))
                continue
            links.append((f"{dut}: calibration certificate", page.name))
    return links, refused


def read_inputs(
    source: str | Path, *, data: str | Path | None = None, dut: str | None = None
) -> ReportInputs:
    path = Path(source)
    if not path.is_file():
        raise DataError(f"{path}: no such file (expected a session file or a calibration file)")
    if looks_like_session(path):
        if data is not None:
            raise DataError(f"{path}: is a session file; --data is only for a calibration file")
        return from_session(path, dut)
    return from_calibration(path, data, dut)


def acceptance_section(recorded: list[dict]) -> Section:
    """The run's PASS/FAIL per DUT against the plan's acceptance limits, as recorded in the session."""
    def fig(x) -> str:
        return "-" if x is None else f"{x:.4g}"

    rows = [[r["dut"], str(r["model"]).upper(), r["verdict"], r["failed"] or "-", fig(r["heldout_rms_nt"]),
             fig(r["fit_rms_nt"]), r["notes"] or "-"] for r in recorded]
    header = ["DUT", "model", "verdict", "failed criteria", "held-out RMS (nT)", "fit RMS (nT)", "notes"]
    return Section("Acceptance", [Table(header, rows)])


def _subtitle(inputs: ReportInputs) -> str:
    return "; ".join(f"{k}: {v}" for k, v in inputs.provenance[:2])


POOL_MIN_DUTS = 4  # a worker's start (a new interpreter importing matplotlib) costs about one DUT's figures
POOL_MAX_WORKERS = 8  # each holds about 120 MB (numpy, matplotlib: measured); 64 DUTs need no more


def each_dut_sections(results: list, steps: dict, progress: Callable[[str], None] | None = None
                      ) -> list[list[Section]]:
    """Each DUT's sections, in order. Their figures are most of a report's time (64 DUTs' 384 took a
    minute on one core), so with several DUTs they are drawn on every core, each DUT in a new process
    (spawned, not forked: a cockpit builds reports beside its threads). `progress` hears of each DUT done,
    as "name (n of N)"."""
    workers = min(len(results), os.cpu_count() or 1, POOL_MAX_WORKERS)
    if len(results) < POOL_MIN_DUTS or workers < 2:
        out = []
        for n, r in enumerate(results, 1):
            out.append(dut_sections(r, steps))
            _tell(progress, f"{r.name} ({n} of {len(results)})")
        return out
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_leave_interrupts_to_the_caller)
    try:
        futures = {pool.submit(dut_sections, r, steps): r.name for r in results}
        for n, done in enumerate(as_completed(futures), 1):
            _tell(progress, f"{futures[done]} ({n} of {len(results)})")
        return [future.result() for future in futures]
    finally:  # after a failure or a Ctrl-C, the DUTs not begun are dropped, not drawn
        pool.shutdown(wait=True, cancel_futures=True)


def _leave_interrupts_to_the_caller() -> None:
    """In a worker: a Ctrl-C at the terminal reaches the whole process group; the caller stops the report,
    and the worker ends with the pool, without a traceback of its own."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _tell(progress: Callable[[str], None] | None, message: str) -> None:
    if progress is not None:
        progress(message)


def report_sections(inputs: ReportInputs, progress: Callable[[str], None] | None = None) -> list[Section]:
    clash = collision(d.name for d in inputs.duts)
    if clash:
        raise DataError(f"report: DUT names {clash[1].removesuffix('; rename one')}, so their figures would "
                        "overwrite each other; report on one at a time (--dut)")
    results = [analyse_dut(d, inputs.steps) for d in inputs.duts]
    warnings = list(inputs.warnings) + [f"{r.name}: {w}" for r in results for w in r.warnings]
    sections = [
        Section("Summary", [summary_table(results)]),
        Section("Data-quality warnings", [ItemList(warnings, kind="warning", empty_text="No warnings.")]),
    ]
    if inputs.acceptance:
        sections.insert(1, acceptance_section(inputs.acceptance))
    for dut_part in each_dut_sections(results, inputs.steps, progress):
        sections += dut_part
    sections.append(Section("Provenance", [Table(["item", "value"], [list(p) for p in inputs.provenance])]))
    return sections
