"""A DUT's Digital Calibration Certificate: PTB's DCC 3.1.2 XML beside its certificate's page
(`<session stem>.<dut>.dcc.xml`), stating what the page states, for a program to read.

    write_dcc(certificate, path)        # certificate: rig/report/certificate.py Certificate

administrativeData: the software (magrig and its release); the core data (the certificate's id as its
unique identifier, the session's and the calibration files' sha256 as identifications, the dates of
receipt and of the calibration, where it was made); the item (its model, maker, serial number and its
name at the station, its condition); the laboratory, the persons responsible (the station's
`lab.responsible`, else the operator the session names) and the customer (a key the files do not state
is written "not stated": the schema wants the element); the statements: the decision rule and every
criterion's conformity, the marks NOT VALID: SIMULATED STATION and NOT TRACEABLE (or the traceability
chain), what is not stated, the deviations, and that the results relate only to the item.
measurementResults: rig/report/dcc_results.py.
"""

from __future__ import annotations

import datetime as dt
import xml.etree.ElementTree as ET
from pathlib import Path

from rig import __version__
from rig.report import decision_rule
from rig.report.certificate_record import deviations
from rig.report.dcc_results import measurement_results
from rig.report.dcc_xml import LANG, SCHEMA_VERSION, contact, el, rich, statement, text

NOT_STATED = "not stated"


def _run_dates(info: dict) -> tuple[str, str]:
    """(first, last day of the run), UTC: by the wall clock where the session has it, else its run clock."""
    clock = "wall_" if info.get("wall_started") is not None else ""
    start = info.get(f"{clock}started") or 0.0
    end = info.get(f"{clock}ended") or start
    return tuple(dt.datetime.fromtimestamp(t, dt.UTC).date().isoformat() for t in (start, end))


def dcc_document(c) -> ET.ElementTree:
    root = el(None, "dcc:digitalCalibrationCertificate", schemaVersion=SCHEMA_VERSION)
    admin = el(root, "dcc:administrativeData")
    _software(admin)
    _core_data(admin, c)
    _items(admin, c)
    _laboratory(admin, c)
    _responsible(admin, c)
    _customer(admin, c)
    _statements(admin, c)
    measurement_results(el(root, "dcc:measurementResults"), c)
    ET.indent(root)
    return ET.ElementTree(root)


def write_dcc(c, path: Path) -> Path:
    dcc_document(c).write(path, encoding="utf-8", xml_declaration=True)
    return path


def _software(admin: ET.Element) -> None:
    software = el(el(admin, "dcc:dccSoftware"), "dcc:software")
    text(software, "dcc:name", "magrig")
    el(software, "dcc:release", __version__)
    el(software, "dcc:type", "application")
    rich(software, "dcc:description", "drives the calibration station, fits the calibration and its "
         "uncertainty budget, and writes this certificate (rig certificate)")


def _core_data(admin: ET.Element, c) -> None:
    r = c.record
    lab, info, plan = r.station.lab, r.info, r.plan
    core = el(admin, "dcc:coreData")
    el(core, "dcc:countryCodeISO3166_1", (lab and lab.country) or "ZZ")  # ZZ: ISO 3166's "unknown"
    el(core, "dcc:usedLangCodeISO639_1", LANG)
    el(core, "dcc:mandatoryLangCodeISO639_1", LANG)
    el(core, "dcc:uniqueIdentifier", c.id)
    ids = el(core, "dcc:identifications")
    stated = [("calibrationLaboratory", r.session_sha256, f"sha256 of the session file {r.session.name}")]
    stated += [("calibrationLaboratory", f.sha256, f"sha256 of the calibration file {f.path.name}")
               for f in r.cals.values()]
    if plan.customer is not None and plan.customer.order:
        stated.append(("customer", plan.customer.order, "the customer's order"))
    for issuer, value, name in stated:
        identification = el(ids, "dcc:identification")
        el(identification, "dcc:issuer", issuer)
        el(identification, "dcc:value", value)
        text(identification, "dcc:name", name)
    if plan.received is not None:
        el(core, "dcc:receiptDate", plan.received.isoformat())
    begin, end = _run_dates(info)
    el(core, "dcc:beginPerformanceDate", begin)
    el(core, "dcc:endPerformanceDate", end)
    el(core, "dcc:performanceLocation", lab.performed_at if lab is not None else "laboratory")


def _items(admin: ET.Element, c) -> None:
    r = c.record
    item = el(el(admin, "dcc:items"), "dcc:item")
    model = r.identity.get("model") or r.config.type
    text(item, "dcc:name", f"three-axis magnetometer {r.dut} ({model})")
    rich(item, "dcc:description", f"condition when received: {r.plan.condition or NOT_STATED}",
         f"position in the station: {tuple(r.config.position_mm or (0.0, 0.0, 0.0))} mm")
    text(el(item, "dcc:manufacturer"), "dcc:name", r.config.spec.manufacturer or NOT_STATED)
    el(item, "dcc:model", str(model))
    ids = el(item, "dcc:identifications")
    serial, by = r.serial
    for issuer, value, name in [("manufacturer", serial, f"serial number ({by})"),
                                ("calibrationLaboratory", r.dut, f"its name at station {r.station.name}")]:
        if value:
            identification = el(ids, "dcc:identification")
            el(identification, "dcc:issuer", issuer)
            el(identification, "dcc:value", str(value))
            text(identification, "dcc:name", name)


def _laboratory(admin: ET.Element, c) -> None:
    lab = c.record.station.lab
    node = el(admin, "dcc:calibrationLaboratory")
    if lab is not None and lab.accreditation_id:
        el(node, "dcc:calibrationLaboratoryCode", lab.accreditation_id)
    contact(node, "dcc:contact", (lab and lab.name) or NOT_STATED, lab and lab.email,
            lab and lab.address, lab and lab.country)


def _responsible(admin: ET.Element, c) -> None:
    lab, operator = c.record.station.lab, c.record.info.get("operator")
    people = [(p.name, p.role or "") for p in (lab.responsible if lab is not None else [])]
    people = people or [(operator or NOT_STATED, "operator who ran the calibration (lab.responsible not "
                         "stated)")]
    persons = el(admin, "dcc:respPersons")
    for i, (name, role) in enumerate(people):
        person = el(persons, "dcc:respPerson")
        text(el(person, "dcc:person"), "dcc:name", name)
        if role:
            el(person, "dcc:role", role)
        el(person, "dcc:mainSigner", "true" if i == 0 else "false")


def _customer(admin: ET.Element, c) -> None:
    customer = c.record.plan.customer
    if customer is None:
        contact(admin, "dcc:customer", NOT_STATED, None, None, None)
        return
    contact(admin, "dcc:customer", customer.name, customer.email, customer.address, None)


def _statements(admin: ET.Element, c) -> None:
    node = el(admin, "dcc:statements")
    statement(node, "The results relate only to the item calibrated, under the conditions stated.")
    if c.record.simulated:
        statement(node, f"NOT VALID: SIMULATED STATION: simulated devices {', '.join(c.record.simulated)}",
                  valid=False)
    chain = "; ".join(f"{link}: {what}" for link, what in c.chain.links)
    statement(node, ("Traceable to the SI (ILAC P10): " if c.chain.traceable else
                     f"NOT TRACEABLE: {c.chain.why_not}. The chain as it stands: ") + chain,
              traceable=c.chain.traceable, norms=("ILAC P10/07:2020",))
    if c.not_stated:
        statement(node, c.not_stated)
    rows = deviations(c.record)
    statement(node, "Deviations from the procedure: " + ("; ".join(
        f"{what} x{times} ({points}): {message}" for what, times, points, message in rows)
        if rows else "none"))
    if not c.criteria:
        statement(node, "No statement of conformity: the plan states no acceptance limits.")
        return
    statement(node, decision_rule.RULE, convention="ILAC-G8:09/2019 guarded acceptance, w = U",
              norms=("ILAC-G8:09/2019",))
    for x in c.criteria:
        statement(node, f"{x.name}: limit {x.limit}; figure {x.figure}; guard band {x.guard}; {x.result}: "
                  f"{x.words}", convention="ILAC-G8:09/2019 guarded acceptance, w = U",
                  conformity=x.conformity)
