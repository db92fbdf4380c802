"""A calibration certificate per DUT, from its session and its calibration files: one self-contained HTML
page (rig/report/html.py), printed to PDF from the same page (rig/report/pdf.py), and its Digital
Calibration Certificate (rig/report/dcc.py, PTB's DCC 3.1.2 XML).

    paths, said = write_certificate(SESSION, "dut3", out_dir)   # HTML, PDF, NAME.dcc.xml; what was done
    html_text = certificate_html(SESSION, "dut3")               # the cockpit serves it as is

It follows ISO/IEC 17025:2017 7.8.2 (every report) and 7.8.4 (calibration certificates), each item a
section (ITEMS, the order of the page; docs/certificate.md says where each item stands). Every page, on
screen and printed, carries the certificate's id, "page x of y" (printed), the marks NOT VALID:
SIMULATED STATION (a run with a simulated device) and NOT TRACEABLE (no reference calibration
certificate behind the field source: rig/report/traceability.py), and what the files do not state
(the laboratory's keys, the item's serial, the customer, the date of receipt, its condition:
rig/report/certificate_record.py). A calibration without an uncertainty, with inputs of unstated
uncertainty or without a reference chain is refused (CertificateRefused) before anything is written.
"""

from __future__ import annotations

import datetime as dt
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.io.digest import sha256_text
from calib.stats.directions import reach_deg, taken_directions
from rig.core.errors import DataError
from rig.core.paths import inside
from rig.report import decision_rule
from rig.report.asfound import AsFound, as_found, as_found_section
from rig.report.certificate_measurand import measurand_blocks
from rig.report.certificate_record import (  # noqa: F401 - session_record: the callers know it from here
    CertificateRefused,
    Record,
    deviations,
    gather,
    session_record,
)
from rig.report.certificate_results import coverage_probability, results_sections
from rig.report.html import Section, Table, render_html
from rig.report.traceability import NOT_TRACEABLE, Traceability, assess

TITLE = "Calibration certificate of a three-axis magnetometer"
SIMULATED = "NOT VALID: SIMULATED STATION"
ITEMS = ("Identification", "Calibration laboratory", "Customer", "Item calibrated", "Method and plan",
         "Measurand", "Dates", "Conditions", "Results", "Uncertainty budget", "As found", "Deviations",
         "Statement of conformity", "Traceability", "Model checks", "Software and records", "Statement")


def _utc(t: float | None) -> str:
    return "-" if t is None else dt.datetime.fromtimestamp(t, dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


@dataclass
class Certificate:
    """What one certificate states, worked out once for its page and its DCC."""

    record: Record
    chain: Traceability
    criteria: list[decision_rule.Criterion]
    as_found: list[AsFound]
    as_found_notes: list[str]
    issued: dt.datetime = field(default_factory=lambda: dt.datetime.now(dt.UTC))

    @property
    def id(self) -> str:
        return self.record.certificate_id

    @property
    def marks(self) -> list[str]:
        """The marks every page carries."""
        simulated = [SIMULATED] if self.record.simulated else []
        return simulated + ([] if self.chain.traceable else [NOT_TRACEABLE])

    @property
    def not_stated(self) -> str:
        missing = self.record.missing_items()
        return "" if not missing else "NOT STATED: " + ", ".join(missing)

    @property
    def probability(self) -> float:
        return coverage_probability(self.record)[0]


def certificate_of(session: str | Path, dut: str, recorded: dict | None = None) -> Certificate:
    record = gather(Path(session), dut, recorded)
    rows, notes = as_found(record)
    return Certificate(record, assess(record), decision_rule.judge(record), rows, notes)


def certificate_sections(c: Certificate) -> list[Section]:
    r = c.record
    departures = deviations(r)
    info, station, plan, lab = r.info, r.station, r.plan, r.station.lab
    serial, serial_by = r.serial
    identity = json.dumps(r.identity, sort_keys=True, default=str)[:600] or "-"
    return [
        Section("Identification", [Table(["item", "value"], [
            ["title", TITLE], ["certificate", c.id],
            ["pages", "every page carries this id and, printed, its number: page x of y"],
            ["marks", ", ".join(c.marks) or "none"], ["not stated", c.not_stated or "nothing"]])]),
        Section("Calibration laboratory", [Table(["item", "value"], [
            ["laboratory", _stated(lab and lab.name)], ["address", _stated(lab and lab.address)],
            ["accreditation", _stated(lab and lab.accreditation_id)],
            ["place of work", _stated(lab and lab.place_of_work) + (f" ({lab.performed_at})" if lab else "")],
            ["station", f"{station.name} ({info.get('station_path') or 'path not recorded'})"],
            ["operator", info.get("operator") or "-"],
            ["simulated devices", ", ".join(r.simulated) or "none: every device real"]])]),
        _customer(r),
        Section("Item calibrated", [Table(["item", "value"], [
            ["description", f"three-axis magnetometer {r.dut}: {r.identity.get('model') or r.config.type} "
                            f"({r.config.type}) by {r.config.spec.manufacturer or 'a maker not stated'}"],
            ["serial number", f"{serial} ({serial_by})" if serial else "NOT STATED (duts[].serial)"],
            ["identity as reported", identity],
            ["received", _stated(plan.received and plan.received.isoformat(), "received")],
            ["condition when received", _stated(plan.condition, "condition")],
            ["position (mm)", str(tuple(r.config.position_mm or (0.0, 0.0, 0.0)))]])]),
        _method(r),
        Section("Measurand", measurand_blocks(r)),
        Section("Dates", [Table(["item", "value"], [
            ["received", _stated(plan.received and plan.received.isoformat(), "received")],
            ["calibration", f"{_utc(info.get('wall_started'))} to {_utc(info.get('wall_ended'))}"],
            ["issue of this certificate", c.issued.strftime("%Y-%m-%d %H:%M:%S UTC")]])]),
        _conditions(r),
        *results_sections(r),
        as_found_section(c.as_found, c.as_found_notes, c.probability),
        Section("Deviations", [
            "Additions to, deviations and exclusions from the procedure: the run's events, grouped.",
            Table(["what", "times", "points", "first message"], departures)
            if departures else "none: every point was taken as planned, without a hold, fault, pause "
                               "or retake"]),
        decision_rule.conformity_section(c.criteria, r.verdicts),
        Section("Traceability", [
            "Traceable to the SI through the chain below (ILAC P10)." if c.chain.traceable else
            f"{NOT_TRACEABLE}: {c.chain.why_not}.",
            Table(["link", "what"], c.chain.links)]),
        _checks(r),
        Section("Software and records", [Table(["item", "value"], [
            ["run by", f"magrig {info.get('software_version')}"],
            ["calibrations fitted by", ", ".join(sorted({f.cal.software_version for f in r.cals.values()}))],
            ["session file", f"{r.session.name}, sha256 {r.session_sha256}"],
            *[[f"{m.upper()} calibration file", f"{f.path.name}, sha256 {f.sha256}"]
              for m, f in r.cals.items()],
            ["plan", f"{plan.name}, sha256 {sha256_text(info['plan_text'])}"]])]),
        Section("Statement", [
            "The results relate only to the item calibrated, under the conditions stated. No result comes "
            "from an external provider; the reference's calibration certificate is the chain's link "
            "(Traceability). This certificate recommends no calibration interval. It shall not be "
            "reproduced except in full.",
            *_signatures(lab), f"End of certificate {c.id}."]),
    ]


def _stated(value: str | None, key: str | None = None) -> str:
    return str(value) if value else "NOT STATED" + (f" ({key})" if key else "")


def _customer(r: Record) -> Section:
    customer = r.plan.customer
    if customer is None:
        return Section("Customer", ["NOT STATED (the plan's customer:)."])
    return Section("Customer", [Table(["item", "value"], [
        ["name", customer.name], ["address", _stated(customer.address)], ["e-mail", _stated(customer.email)],
        ["order", _stated(customer.order)]]),
        "The customer's name, address and order are as the customer supplied them (7.8.2.2)."])


def _signatures(lab) -> list[str]:
    people = lab.responsible if lab is not None else []
    if not people:
        return ["Authorized by: NOT STATED (lab.responsible) ______________________ (name, function, "
                "signature)"]
    return [f"Authorized by: {p.name}" + (f", {p.role}" if p.role else "") + "  ______________________ "
            "(signature)" for p in people]


def _method(r: Record) -> Section:
    plan, info, lab = r.plan, r.info, r.station.lab
    temps, setpoints = plan.temperatures, r.recorded["setpoints_c"]
    shown = (", ".join(f"{t:g}" for t in setpoints) if len(setpoints) <= 12 else
             f"{len(setpoints)} set points, {min(setpoints):g} .. {max(setpoints):g}")
    return Section("Method and plan", [Table(["item", "value"], [
        ["procedure", _stated(lab and lab.procedure_id, "lab.procedure_id")],
        ["method", "the DUT's raw readings against the reference field of the station's field source at "
                   "each temperature of the plan; least-squares fit of the model; uncertainty by the law of "
                   "propagation (JCGM 100, GUM) where exact, the adaptive Monte Carlo of JCGM 101 (GUM S1) "
                   "where needed"],
        ["models", ", ".join(m.upper() for m in r.cals)],
        ["plan", f"{plan.name} ({info.get('plan_path') or 'path not recorded'}), sha256 "
                 f"{sha256_text(info['plan_text'])}"],
        ["temperatures", f"{getattr(temps, 'mode', None) or 'steps'}: {shown} degC"],
        ["fields", f"{plan.fields.kind}: {r.recorded['targets']} targets; {r.recorded['points']} points "
                   f"taken of {r.recorded['points_planned']} planned"],
        ["samples per point", str(plan.samples_per_point)],
        ["sampling", "none: the item itself was calibrated, every point of the plan on it"]])])


def _conditions(r: Record) -> Section:
    ds = r.ds
    norms = np.linalg.norm(ds.ref_nt, axis=1)
    ambient = next((f.cal.stats.get("ambient") for f in r.cals.values() if f.cal.stats.get("ambient")), None)
    rows = [["DUT temperature", f"{ds.temp_c.min():.2f} .. {ds.temp_c.max():.2f} degC"],
            ["field magnitude", f"{norms.min():.0f} .. {norms.max():.0f} nT"],
            ["field directions (the DUT's frame)",
             f"every direction within {reach_deg(taken_directions(ds.ref_nt)):.0f} deg of one taken"],
            ["samples", f"{len(ds)} ({ds.source.get('rows_rejected', 0)} flagged and left out)"]]
    if ambient:
        drift = ", drifting" if ambient.get("drift") else ""
        what = getattr(getattr(r.station, "field_source", None), "measured_name", "ambient field")
        rows.append([f"{what} (measured)", ", ".join(f"{v:.1f}" for v in ambient["value_nt"]) + " nT, "
                     f"{ambient['measurements']} measurements{drift}"])
    return Section("Conditions", [Table(["item", "value"], rows)])


def _checks(r: Record) -> Section:
    rows = []
    for model, f in r.cals.items():
        for check in f.cal.stats.get("model_checks") or []:
            p, size = check.get("p"), check.get("magnitude_nt")
            rows.append([model.upper(), check["name"], check["verdict"], "-" if p is None else f"{p:.2g}",
                         "-" if size is None else f"{size:.3g}", check["message"]])
    blocks = [Table(["model", "check", "verdict", "p", "size (nT)", "finding"], rows)] if rows else \
        ["no model checks recorded (a calibration of a model other than T24, or one from before they were)"]
    return Section("Model checks", blocks)


def _css_string(text: str) -> str:
    """A CSS string's content: quotes, backslashes and `<` escaped (it sits inside a <style>)."""
    return text.replace("\\", "\\\\").replace('"', '\\"').replace("<", "\\3C ").replace("\n", " ")


def print_css(c: Certificate) -> str:
    """A4 pages, each with the marks and what is not stated at its head (the top margin alone: a line
    each, at full width), the id and "page x of y" at its foot."""
    head = "\\A ".join(_css_string(line) for line in ["  \u2014  ".join(c.marks), c.not_stated] if line)
    return f"""
td, th {{ text-align: left; vertical-align: top; }}
div.marks {{ position: sticky; top: 0; background: #fff4f4; border: 2px solid #b00000; color: #b00000;
             padding: .4em .8em; font-weight: bold; z-index: 1; }}
div.marks p {{ margin: .1em 0; }}
div.marks p.missing {{ font-weight: normal; color: #7a3b00; }}
@page {{ size: A4; margin: 26mm 14mm 18mm;
        @top-center {{ content: "{head}"; white-space: pre-wrap; font-size: 8.5pt; font-weight: bold;
                       color: #b00000; }}
        @bottom-left {{ content: "Certificate {_css_string(c.id)}"; font-size: 8pt; }}
        @bottom-right {{ content: "page " counter(page) " of " counter(pages); font-size: 8pt; }} }}
@media print {{ body {{ margin: 0; max-width: none; font-size: 10pt; }} h2 {{ break-after: avoid; }}
               div.marks {{ display: none; }} }}
"""


def certificate_html(session: str | Path, dut: str, recorded: dict | None = None,
                     certificate: Certificate | None = None) -> str:
    c = certificate or certificate_of(session, dut, recorded)
    banner = [(f"Certificate {c.id}", "id"), *((mark, "mark") for mark in c.marks)]
    banner += [(c.not_stated, "missing")] if c.not_stated else []
    return render_html(f"Calibration certificate {c.id}", certificate_sections(c),
                       subtitle=f"issued by magrig from {Path(session).name}", banner=banner,
                       css=print_css(c))


def certificate_file(out_dir: str | Path, session: str | Path, dut: str, suffix: str) -> Path:
    stem = Path(session).name.removesuffix(".session")
    return inside(out_dir, f"{stem}.{dut}.{suffix}")


def write_certificate(session: str | Path, dut: str, out_dir: str | Path, *, pdf: bool = True,
                      dcc: bool = True, recorded: dict | None = None) -> tuple[list[Path], str]:
    """([the HTML file, the PDF when one could be printed, the DCC], what happened to the PDF);
    `recorded`: the session's session_record, read once for several DUTs."""
    from rig.report.dcc import write_dcc
    from rig.report.pdf import print_pdf

    c = certificate_of(session, dut, recorded)  # refused before anything is written
    out = Path(out_dir)
    page = certificate_file(out, session, dut, "certificate.html")
    written = [page]
    try:
        out.mkdir(parents=True, exist_ok=True)
        page.write_text(certificate_html(session, dut, certificate=c), encoding="utf-8")
        if dcc:
            written.append(write_dcc(c, certificate_file(out, session, dut, "dcc.xml")))
    except OSError as exc:
        raise DataError(f"{out}: cannot write the certificate: {exc.strerror or exc}") from None
    if not pdf:
        return written, "PDF not asked for"
    target = certificate_file(out, session, dut, "certificate.pdf")
    said = print_pdf(page, target)
    return (written[:1] + [target] + written[1:] if target.is_file() else written), said
