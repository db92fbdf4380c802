"""The measurement results of a Digital Calibration Certificate (rig/report/dcc.py): one
dcc:measurementResult per calibration file, holding

- its measurand in words (equation, how h was read, the thermometer of tau, the frames, the index order,
  the units), the methods (JCGM 100, and JCGM 101 where Monte Carlo decided), the reference magnetometers
  with their calibration certificates, and the influence conditions (the DUT temperatures and the field
  magnitudes of the calibration, lowest and highest);
- a dcc:result per parameter, one si:real per element labelled in the file's numbering (`S[0][1]`), its
  value, D-SI unit and si:expandedUnc (U, k, coverage probability); where Monte Carlo decided, a second
  si:real per element with the S1 si:coverageInterval;
- a dcc:result of the calibrated field's figures under the file's own keys (combined_standard_nt,
  expanded_vector_error_nt, ...), in nanotesla.
Every value is the calibration file's, written as Python writes the float.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from rig.report.certificate_measurand import frame_text, indexing_text, reading_text, tau_text, units_text
from rig.report.certificate_results import parameter_rows, s1_interval
from rig.report.dcc_xml import coverage_interval, el, expanded_unc, quantity, rich, text

# D-SI units of every parameter of calib/equations.py (a temperature coefficient per degC is per kelvin)
DSI_UNITS = {"S": r"\one", "K": r"\kelvin\tothe{-1}", "K2": r"\kelvin\tothe{-2}",
             "b_nt": r"\nano\tesla", "h0_nt": r"\nano\tesla", "kb_nt_per_c": r"\nano\tesla\kelvin\tothe{-1}",
             "kb2_nt_per_c2": r"\nano\tesla\kelvin\tothe{-2}", "k": r"\one", "angles_deg": r"\degree",
             "A": r"\one", "c_nt": r"\nano\tesla", "KA_per_c": r"\kelvin\tothe{-1}",
             "kc_nt_per_c": r"\nano\tesla\kelvin\tothe{-1}"}
NANOTESLA, CELSIUS = r"\nano\tesla", r"\degreecelsius"
FIELD_KEYS = {"combined_standard_nt": "u of the calibrated field, RMS over the plan's fields and "
                                      "temperatures",
              "expanded_vector_error_nt": "the largest radius of the calibrated field's error over them",
              "vector_radius_nt": "the calibrated field's error radius",
              "expanded_norm_error_nt": "the largest interval of |B|'s error over them"}


def measurement_results(parent: ET.Element, c) -> None:
    r = c.record
    for model, cal_file in r.cals.items():
        result = el(parent, "dcc:measurementResult")
        text(result, "dcc:name", f"{model.upper()} calibration of {r.dut}")
        rich(result, "dcc:description", *_measurand(r, cal_file))
        _methods(result, cal_file)
        _equipment(result, c)
        _conditions(result, r)
        results = el(result, "dcc:results")
        _parameters(results, cal_file, c.probability)
        _field(results, cal_file)


def _measurand(r, cal_file) -> list[str]:
    keys = cal_file.cal.equation_keys()
    return [f"equation: {keys['equation']}; tau: {keys['tau']}",
            f"how h was read: {reading_text(r, cal_file)[0]}",
            f"tau from: {tau_text(r, cal_file)[0]}",
            f"frames: {frame_text(r, cal_file)[0]}",
            f"index order: {indexing_text(cal_file)[0]}",
            f"parameters and units: {units_text(cal_file)}",
            f"calibration file {cal_file.path.name}, sha256 {cal_file.sha256}"]


def _methods(parent: ET.Element, cal_file) -> None:
    method = el(el(parent, "dcc:usedMethods"), "dcc:usedMethod")
    text(method, "dcc:name", f"least-squares fit of the {cal_file.model.upper()} model to the raw readings "
                             "against the reference field; uncertainty budget")
    rich(method, "dcc:description", str(cal_file.uncertainty.get("method", "not stated")))
    el(method, "dcc:norm", "JCGM 100:2008")
    if s1_interval(cal_file) is not None or cal_file.uncertainty.get("monte_carlo"):
        el(method, "dcc:norm", "JCGM 101:2008")


def _equipment(parent: ET.Element, c) -> None:
    if not c.chain.calibration_sha256:
        return
    equipments = el(parent, "dcc:measuringEquipments")
    for name, sha in c.chain.calibration_sha256.items():
        equipment = el(equipments, "dcc:measuringEquipment")
        text(equipment, "dcc:name", f"reference magnetometer {name}")
        certificate = c.chain.certificates.get(name)
        if certificate is None:
            rich(equipment, "dcc:description", "its calibration file states no calibration certificate")
            continue
        rich(equipment, "dcc:description", f"calibrated {certificate.date.isoformat()}: U = "
             f"{certificate.expanded_uncertainty_nt:g} nT (k = {certificate.coverage_factor:g})")
        stated = el(equipment, "dcc:certificate")
        text(stated, "dcc:referral", certificate.issuer)
        el(stated, "dcc:referralID", certificate.id)
        el(stated, "dcc:procedure", "sha256 of the calibration file that transcribes the certificate")
        el(stated, "dcc:value", sha)


def _conditions(parent: ET.Element, r) -> None:
    ds = r.ds
    norms = np.linalg.norm(ds.ref_nt, axis=1)
    conditions = el(parent, "dcc:influenceConditions")
    for name, values, unit in (("temperature of the DUT", ds.temp_c, CELSIUS),
                               ("magnitude of the reference field", norms, NANOTESLA)):
        condition = el(conditions, "dcc:influenceCondition")
        text(condition, "dcc:name", name)
        data = el(condition, "dcc:data")
        for which, value in (("lowest", np.min(values)), ("highest", np.max(values))):
            quantity(data, which, f"{name}, {which}", float(value), unit)


def _parameters(parent: ET.Element, cal_file, p: float) -> None:
    s1 = s1_interval(cal_file)
    kind = (s1 or {}).get("kind", "")
    by_name: dict[str, list] = {}
    for row in parameter_rows(cal_file):
        by_name.setdefault(row.name, []).append(row)
    for name, rows in by_name.items():
        result = el(parent, "dcc:result")
        text(result, "dcc:name", name)
        said = f"{name} in the calibration file's numbering; U = k u ({p * 100:.2f} %)"
        rich(result, "dcc:description", said + (f"; beside it the S1 {kind} interval" if s1 else ""))
        data = el(result, "dcc:data")
        unit = DSI_UNITS[name]
        for row in rows:
            expanded_unc(quantity(data, row.label, row.label, row.value, unit), row.expanded, row.k, p)
            if row.s1 is not None:
                coverage_interval(quantity(data, f"{row.label}: S1 coverage interval", row.label, row.value,
                                           unit), row.expanded / row.k, row.s1[0], row.s1[1],
                                  float(s1.get("probability", p)), kind)


def _field(parent: ET.Element, cal_file) -> None:
    u = cal_file.uncertainty
    result = el(parent, "dcc:result")
    text(result, "dcc:name", "calibrated field")
    rich(result, "dcc:description", "the calibrated field's uncertainty, each figure under the calibration "
                                    "file's own key (uncertainty.<key>)")
    data = el(result, "dcc:data")
    for key, what in FIELD_KEYS.items():
        if u.get(key) is not None:
            quantity(data, key, key, float(u[key]), NANOTESLA, what)
    radius = (s1_interval(cal_file) or {}).get("vector_radius_nt")
    if radius is not None:
        quantity(data, "s1_interval.vector_radius_nt", "s1_interval.vector_radius_nt", float(radius),
                 NANOTESLA, "the calibrated field's error radius from the Monte Carlo draws (GUM S1)")
