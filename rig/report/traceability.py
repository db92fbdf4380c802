"""The certificate's statement of metrological traceability (ISO/IEC 17025:2017 7.8.4.1 c and Annex A;
ILAC P10): the chain from the SI down to the DUT's calibration, link by link, or what breaks it.

    chain = assess(record)      # record: rig/report/certificate_record.py
    chain.traceable, chain.why_not, chain.links

A calibration is traceable here when the run's field source was commissioned with a reference
magnetometer whose calibration file transcribes a calibration certificate (its `source.certificate:`:
id, issuer, date and U, rig/config/lab.py), and the reference that measured the run's ambient or site
field, where another, has one too; and no calibration file says otherwise (format 3's
`reference_chain.traceable`). Without, every page of the certificate says NOT TRACEABLE and this
section says why. The thermometers' link is stated as it is: a datasheet's accuracy, not a certificate.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from calib.io.digest import sha256_text
from rig.budget.run_inputs import temperature_accuracy_c
from rig.config.lab import ReferenceCertificate, recorded_certificate

NOT_TRACEABLE = "NOT TRACEABLE"


@dataclass
class Traceability:
    traceable: bool
    why_not: str  # what breaks the chain ("" when traceable)
    links: list[list[str]] = field(default_factory=list)  # [link, what it is], from the SI down
    certificates: dict[str, ReferenceCertificate] = field(default_factory=dict)  # reference: its certificate
    calibration_sha256: dict[str, str] = field(default_factory=dict)  # reference: its calibration's sha256


def _needed_references(record) -> tuple[list[str], str | None]:
    """(the reference magnetometers the run's field rests on, what is missing when it rests on none)."""
    station, com = record.station, record.commissioning_record
    source = station.field_source
    names = []
    if com is not None:
        names.append(com["reference_magnetometer"]["name"])
    if source.measures_ambient():
        measuring = source.measuring_magnetometer([r.name for r in station.reference_magnetometers])
        if measuring is not None and measuring not in names:
            names.append(measuring)
    if com is None:
        return names, (f"the field source was not commissioned: the run's reference field rests on "
                       f"{source.described}'s declared values, which no calibration certificate states")
    return names, None


def _reference_sha256(record, name: str, data: dict) -> str:
    """Its calibration file's sha256 as the commissioning recorded it, else of what the session holds."""
    measured = (record.commissioning_record or {}).get("reference_magnetometer") or {}
    if measured.get("name") == name and measured.get("calibration_sha256"):
        return measured["calibration_sha256"]
    return sha256_text(json.dumps(data, sort_keys=True))


def assess(record) -> Traceability:
    station, chain = record.station, record.chain
    names, broken = _needed_references(record)
    recorded = chain.get("reference_calibrations") or {}
    refs = {r.name: r for r in station.reference_magnetometers}
    out = Traceability(traceable=False, why_not="")
    problems = [broken] if broken else []
    si_links, ref_links = [], []
    for name in names:
        data = recorded.get(name)
        if data is None:
            problems.append(f"reference magnetometer {name}: its calibration is not in the session")
            continue
        out.calibration_sha256[name] = sha = _reference_sha256(record, name, data)
        certificate, bad = recorded_certificate(data.get("source") or {})
        config = refs.get(name)
        serial = f", serial {config.serial}" if config is not None and config.serial else ""
        kind = config.type if config is not None else "?"
        file = config.calibration if config is not None else "?"
        ref_links.append([f"reference magnetometer {name}",
                          f"{kind}{serial}; its {str(data.get('model', '?')).upper()} calibration in {file} "
                          f"(sha256 {sha}), with U on every parameter"])
        if certificate is None:
            problems.append(f"reference magnetometer {name}: its calibration file states no calibration "
                            "certificate (source.certificate: id, issuer, date and U)" + (f": {bad}" if bad
                                                                                          else ""))
            continue
        out.certificates[name] = certificate
        route = certificate.route_to_si or "not stated by the file (source.certificate.route_to_si)"
        si_links.append(["SI", f"the tesla, realised by a national metrology institute: {route}"])
        scope = f", {certificate.scope}" if certificate.scope else ""
        k = f"k = {certificate.coverage_factor:g}" + (
            f", p = {certificate.coverage_probability:g}" if certificate.coverage_probability else "")
        si_links.append([f"calibration certificate of {name}",
                         f"{certificate.id} of {certificate.date.isoformat()} by {certificate.issuer} "
                         f"({certificate.issuer_accreditation or 'its accreditation not stated'}): "
                         f"U = {certificate.expanded_uncertainty_nt:g} nT ({k}){scope}"])
    for cal_file in record.cals.values():
        stated = cal_file.raw.get("reference_chain")
        if isinstance(stated, dict) and stated.get("traceable") is False:
            problems.append(f"{cal_file.path.name}: reference_chain: {stated.get('text', 'not traceable')}")
    out.links = si_links + ref_links + _lower_links(record)
    out.traceable = not problems
    out.why_not = "; ".join(dict.fromkeys(problems))
    return out


def _lower_links(record) -> list[list[str]]:
    """The links below the reference: the commissioning, the field at the DUT, the calibration, and the
    thermometer that gave tau."""
    chain, station, com = record.chain, record.station, record.commissioning_record
    source = station.field_source
    rows = []
    recorded = chain.get("commissioning")
    if recorded is not None:
        rows.append(["commissioning", f"{recorded.get('path')} (sha256 {recorded.get('sha256')}), written "
                     f"{(com or {}).get('created_utc', '?')}: {source.described} measured with "
                     f"{((com or {}).get('reference_magnetometer') or {}).get('name', '?')}"])
    else:
        rows.append(["commissioning", f"none: {source.described} as declared in the station"])
    position = tuple(record.config.position_mm or (0.0, 0.0, 0.0))
    measured = f"; its {source.measured_name} measured during the run" if source.measures_ambient() else ""
    rows.append(["reference field at the DUT", f"{source.described} at {record.dut}'s position {position} mm"
                 f"{measured}"])
    rows.append(["this calibration", f"{record.dut}'s readings against that field; every link's uncertainty "
                 "is a line of the budget (Uncertainty budget)"])
    config = record.config
    accuracy, stated = temperature_accuracy_c(station, config)
    sensor = "its own sensor" if config.temp_source == "self" else config.temp_source
    origin = "its datasheet's or the station's temp_accuracy_c" if stated else "assumed: nothing states it"
    rows.append(["temperature (tau)", f"{sensor}: +-{accuracy:g} degC ({origin}), not a calibration "
                 "certificate: the temperature coefficients rest on that statement"])
    return rows
