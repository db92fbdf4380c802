"""A calibration certificate per DUT, from its session and its calibration files: one self-contained HTML
page (rig/report/html.py), printed to PDF from the same page (rig/report/pdf.py).

    paths = write_certificate(SESSION, "dut3", out_dir)       # [html, pdf or nothing], and a message
    html_text = certificate_html(SESSION, "dut3")             # the cockpit serves it as is

What it states, following ISO/IEC 17025:2017 7.8.2 (every report) and 7.8.4 (calibration certificates),
each as a section of its own (ITEMS, the order of the page): the certificate's unique identification and
page count (a title, an id, "page x of y" when printed); the calibration laboratory: the station, its
operator, where the devices were simulated; the item calibrated: the DUT, its type and identity as it
reported itself, its position; the method and the plan (the model, the fit, the temperatures and fields,
the plan text's sha256); the dates of the calibration and of issue; the conditions (temperature range,
field range and the directions taken, ambient); the results with their expanded uncertainty and coverage
factor, the field error's 95 % radius and the budget's every line with its origin; the traceability chain
(the reference magnetometer, its calibration and that file's sha256, the commissioning file and its sha256
and age); the model checks; the software version and the session file's sha256; and the statement that
the results relate only to the item calibrated.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

import numpy as np

from calib.io import calfile
from calib.io.digest import sha256_text
from calib.stats.directions import reach_deg, taken_directions
from rig.budget.modelerror import CORRECTED, CORRECTED_U
from rig.core.errors import DataError, SessionError
from rig.core.paths import calibration_file, inside
from rig.report.html import ItemList, Section, Table, render_html

ITEMS = ("Identification", "Calibration laboratory", "Item calibrated", "Method and plan", "Dates",
         "Conditions", "Results", "Uncertainty budget", "Traceability", "Model checks", "Software",
         "Statement")


def _utc(t: float | None) -> str:
    return "-" if t is None else dt.datetime.fromtimestamp(t, dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def _fig(x, spec: str = ".6g") -> str:
    return "-" if x is None else format(float(x), spec)


def session_record(session: str | Path) -> dict:
    """What every certificate of a session states alike, read once for all its DUTs: the session's
    information, reference chain, sha256, points, verdicts, and its recorded plan and station parsed."""
    from rig.reference import chain_record
    from rig.session.reader import SessionReader

    session = Path(session)
    with SessionReader(session) as reader:
        info, chain = reader.info(), reader.snapshot(chain_record.SNAPSHOT) or {}
        points = [p for p in reader.points() if p["state"] == "done"]
        record = {"duts": reader.duts(), "sha256": reader.sha256, "acceptance": reader.acceptance(),
                  "setpoints_c": sorted({round(p["setpoint_c"], 2) for p in points}),
                  "targets": len({p["target_json"] for p in points}), "points": len(points)}
    plan, station = chain_record.recorded_plan_and_station(session, info, chain)
    com = chain.get("commissioning")
    return record | {"session": session, "info": info, "chain": chain, "plan": plan, "station": station,
                     "commissioning_record": None if com is None else _commissioning_record(com)}


def _gather(session: Path, dut: str, recorded: dict | None = None) -> dict:
    """Everything the certificate states: the session's record (session_record) and the DUT's own, read
    from the session and the calibration files beside it."""
    from rig.session.reader import SessionReader

    recorded = recorded or session_record(session)
    if dut not in recorded["duts"]:
        raise SessionError(f"{session}: no DUT named {dut!r} (DUTs: {', '.join(recorded['duts'])})")
    with SessionReader(session) as reader:
        identity = reader.snapshot(dut) or {}
        ds = reader.dataset(dut)
    cals = {}
    for model in dict.fromkeys([*recorded["plan"].fit.models, "t36"]):  # a T36 where T24's linearity failed
        path = calibration_file(session, dut, model)
        if path.is_file():
            cals[model] = (path, calfile.load(path))
    if not cals:
        raise DataError(f"{session}: DUT {dut} has no calibration file beside the session (the run's "
                        "post-run fits write them): nothing to certify")
    return recorded | {"dut": dut, "identity": identity, "ds": ds, "cals": cals,
                       "verdicts": [r for r in recorded["acceptance"] if r["dut"] == dut]}


def certificate_sections(session: str | Path, dut: str, recorded: dict | None = None
                         ) -> tuple[str, list[Section]]:
    """(title, sections) of the certificate of `dut` in `session` (`recorded`: its session_record, when
    certificates of several DUTs are made)."""
    g = _gather(Path(session), dut, recorded)
    info, station, plan = g["info"], g["station"], g["plan"]
    config = station.dut(dut)
    number = f"{Path(session).name.removesuffix('.session')}/{dut}"
    issued = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
    simulated = [k for k, v in (info.get("simulated") or {}).items() if v]
    sections = [
        Section("Identification", [Table(["item", "value"], [
            ["certificate", number], ["title", "Calibration certificate of a three-axis magnetometer"],
            ["pages", "every page is numbered, page x of y (the printed PDF)"]])]),
        Section("Calibration laboratory", [Table(["item", "value"], [
            ["station", f"{station.name} ({info.get('station_path') or 'path not recorded'})"],
            ["field source", f"{station.field_source.described} ({station.field_source.name})"],
            ["operator", info.get("operator") or "-"],
            ["simulated devices", ", ".join(simulated) or "none: every device real"]])]),
        Section("Item calibrated", [Table(["item", "value"], [
            ["DUT", dut], ["type", config.type],
            ["identity as reported", json.dumps(g["identity"], sort_keys=True, default=str)[:600] or "-"],
            ["position (mm)", str(tuple(config.position_mm or (0.0, 0.0, 0.0)))],
            ["temperature source", config.temp_source or "-"]])]),
        _method(plan, info, g),
        Section("Dates", [Table(["item", "value"], [
            ["calibration", f"{_utc(info.get('wall_started'))} to {_utc(info.get('wall_ended'))}"],
            ["issue of this certificate", issued]])]),
        _conditions(g),
        *_results(g),
        _traceability(g),
        _checks(g),
        Section("Software", [Table(["item", "value"], [
            ["run by", f"magrig {info.get('software_version')}"],
            ["calibrations fitted by", ", ".join(sorted({c.software_version
                                                         for _, c in g["cals"].values()}))],
            ["session file", f"{Path(session).name}, sha256 {g['sha256']}"]])]),
        Section("Statement", [
            "The results relate only to the item calibrated, under the conditions stated. The expanded "
            "uncertainties are the standard uncertainties times the coverage factor k stated with them, for "
            "a coverage probability of about 95 %, evaluated as JCGM 100 (GUM) and JCGM 101 (Supplement 1) "
            "describe; the budget states how.",
            *[f"Acceptance against the plan's limits: {v['verdict']} ({v['model']})" for v in g["verdicts"]],
            "Approved by: ______________________  (name, function, signature)"]),
    ]
    return f"Calibration certificate {number}", sections


def _method(plan, info, g) -> Section:
    temps = plan.temperatures
    models = ", ".join(m.upper() for m in g["cals"])
    return Section("Method and plan", [Table(["item", "value"], [
        ["method", "the DUT's raw readings against the reference field of the station's field source at each "
                   "temperature of the plan; least-squares fit of the model; uncertainty by the law of "
                   "propagation (GUM) where exact, the adaptive Monte Carlo of GUM S1 where needed"],
        ["models", models],
        ["plan", f"{plan.name} ({info.get('plan_path') or 'path not recorded'}), sha256 "
                 f"{sha256_text(info['plan_text'])}"],
        ["temperatures", f"{getattr(temps, 'mode', None) or 'steps'}: " + (
            ", ".join(f"{t:g}" for t in g["setpoints_c"]) if len(g["setpoints_c"]) <= 12 else
            f"{len(g['setpoints_c'])} set points, {min(g['setpoints_c']):g} .. {max(g['setpoints_c']):g}")
         + " degC"],
        ["fields", f"{plan.fields.kind}: {g['targets']} targets; {g['points']} points taken"],
        ["samples per point", str(plan.samples_per_point)]])])


def _conditions(g) -> Section:
    ds = g["ds"]
    norms = np.linalg.norm(ds.ref_nt, axis=1)
    ambient = next((c.stats.get("ambient") for _, c in g["cals"].values() if c.stats.get("ambient")), None)
    rows = [["DUT temperature", f"{ds.temp_c.min():.2f} .. {ds.temp_c.max():.2f} degC"],
            ["field magnitude", f"{norms.min():.0f} .. {norms.max():.0f} nT"],
            ["field directions (the DUT's frame)",
             f"every direction within {reach_deg(taken_directions(ds.ref_nt)):.0f} deg of one taken"],
            ["samples", f"{len(ds)} ({ds.source.get('rows_rejected', 0)} flagged and left out)"]]
    if ambient:
        drift = ", drifting" if ambient.get("drift") else ""
        # the coils' ambient field, a turntable's site field (as its reference read it at home)
        what = getattr(getattr(g["station"], "field_source", None), "measured_name", "ambient field")
        rows.append([f"{what} (measured)", ", ".join(f"{v:.1f}" for v in ambient["value_nt"]) + " nT, "
                     f"{ambient['measurements']} measurements{drift}"])
    return Section("Conditions", [Table(["item", "value"], rows)])


def _results(g) -> list[Section]:
    rows, budgets = [], []
    for model, (path, cal) in g["cals"].items():
        u = cal.uncertainty or {}
        expanded, factors = u.get("expanded") or {}, u.get("coverage_factors") or {}
        for name, value in cal.params.items():
            flat, big_u = np.ravel(value), np.ravel(expanded.get(name, np.full(np.shape(value), np.nan)))
            k = np.broadcast_to(np.ravel(factors.get(name, u.get("coverage_factor", np.nan))), flat.shape)
            for idx, v in enumerate(flat):
                label = name + (f"[{idx}]" if flat.size > 1 else "")
                rows.append([model.upper(), label, _fig(v), _fig(big_u[idx], ".3g"), _fig(k[idx], ".3g")])
        lines = [[b["source"], _fig(b["contribution_nt"], ".3g"), b.get("method", ""), b.get("note", "")]
                 for b in u.get("budget", [])]
        largest = _fig(u.get("expanded_vector_error_nt"), ".4g")
        size_u = u.get("expanded_norm_error_nt")
        norm = "" if size_u is None else f"; the 95 % interval of |B|'s error, largest: +-{size_u:.4g} nT"
        budgets += [f"{model.upper()} ({path.name}): the calibrated field's 95 % error radius, largest over "
                    f"the plan's fields and temperatures: {largest} nT{norm}; "
                    f"combined standard uncertainty (RMS) {_fig(u.get('combined_standard_nt'), '.4g')} nT; "
                    f"method: {u.get('method', 'not stated')}",
                    Table(["source", "contribution (nT, standard)", "propagation", "origin"], lines,
                          caption=f"{model.upper()} budget"),
                    ItemList(list(u.get("notes", [])), empty_text="no notes")]
    results = Section("Results", [
        "Parameters with their expanded uncertainty U = k u (coverage probability about 95 %; k from each "
        "one's effective degrees of freedom, GUM G.4: 2 where every input is well known); temperatures "
        "in degC, fields in nT (the calibration files hold the full covariance).",
        *_measurand(g),
        Table(["model", "parameter", "value", "U (expanded)", "k"], rows)])
    return [results, Section("Uncertainty budget", budgets)]


def _measurand(g) -> list[str]:
    """What the parameters stand for (the measurand, rig/budget/modelerror.py), and what a point of use
    adds to their uncertainty: said once, with each model's figures."""
    ds = g["ds"]
    said = [f"Measurand: the parameters of each model are those that describe the DUT best over the "
            f"conditions stated ({ds.temp_c.min():.1f} .. {ds.temp_c.max():.1f} degC, the plan's fields), in "
            "its mean thermal state. What the model cannot follow there (the terms the model checks found, "
            "the misfit) and the DUT's thermal state at a point of use are uncertainties of the calibrated "
            "field: at any reading they add to what the parameters' covariance gives (rig apply "
            "--uncertainty; the files' model_error_nt and hysteresis_state_nt)."]
    fixed = next((cal.source for _, cal in g["cals"].values() if CORRECTED in (cal.source or {})), None)
    if fixed is not None:
        said.append("Correction: the readings were taken to the DUT's mean thermal state before every fit, "
                    "for the thermal hysteresis the model checks found (the offset heating against cooling): "
                    "d = (" + ", ".join(f"{v:.3g}" for v in fixed[CORRECTED]) + ") nT per axis, standard "
                    "uncertainty (" + ", ".join(f"{v:.2g}" for v in fixed.get(CORRECTED_U, [])) + ") nT "
                    "(GUM 3.2.4). The budgets carry the correction's uncertainty.")
    if "scalar" in g["cals"]:
        said.append("SCALAR fits |B| alone: its calibrated field is in the DUT's own frame (A "
                    "upper-triangular), and a rotation of it, one that changes with temperature included, "
                    "leaves |B| unchanged and is not seen. Its uncertainty answers for |B| (the interval of "
                    "|B|'s error; rig apply --uncertainty writes it per row as u_norm); for the field's "
                    "direction only as far as |B| shows it. It holds over the directions taken (Conditions): "
                    "farther from them |B|'s error is the fit's extrapolation, which its data cannot state "
                    "(with no reference direction, nothing holds it there).")
    for model, (_, cal) in g["cals"].items():
        u = cal.uncertainty or {}
        model_error, state = u.get("model_error_nt"), u.get("hysteresis_state_nt")
        if model_error is None and state is None:
            continue
        parts = [] if model_error is None else [
            "model error (" + ", ".join(f"{v:.3g}" for v in model_error) + ") nT, standard"]
        parts += [] if state is None else [
            "thermal state +-(" + ", ".join(f"{v:.3g}" for v in state) + ") nT, either sign"]
        said.append(f"{model.upper()} at a point of use, per axis: " + "; ".join(parts) + ".")
    return said


def _traceability(g) -> Section:
    chain, station = g["chain"], g["station"]
    com = chain.get("commissioning")
    rows = []
    cals = chain.get("reference_calibrations") or {}
    record = g["commissioning_record"]
    for name, data in cals.items():
        ref = next((r for r in station.reference_magnetometers if r.name == name), None)
        measured = record["reference_magnetometer"] if record else {}
        sha = (measured["calibration_sha256"] if measured.get("name") == name
               else sha256_text(json.dumps(data, sort_keys=True)))
        u = data.get("uncertainty") or {}
        kind, file = (ref.type, ref.calibration) if ref else ("?", "?")
        rows.append([f"reference magnetometer {name}",
                     f"{kind}, calibration {file} (sha256 {sha}); its {data.get('model', '?').upper()} "
                     f"calibration of {data.get('created_utc', '?')} states U (k = "
                     f"{u.get('coverage_factor', '?')}) on every parameter"])
    if not cals:
        rows.append(["reference magnetometer", "none recorded: the field source's stated values only"])
    if com is not None:
        rows.append(["commissioning", f"{com.get('path')} (sha256 {com.get('sha256')}), written "
                     f"{record['created_utc'] if record else '?'} with reference "
                     f"{record['reference_magnetometer']['name'] if record else '?'}"])
    else:
        rows.append(["commissioning", "none: the field source as declared"])
    return Section("Traceability", [Table(["link", "what"], rows)])


def _commissioning_record(com: dict) -> dict | None:
    import yaml

    try:
        return yaml.safe_load(com.get("text") or "")
    except yaml.YAMLError:
        return None


def _checks(g) -> Section:
    rows = []
    for model, (_, cal) in g["cals"].items():
        for c in cal.stats.get("model_checks") or []:
            rows.append([model.upper(), c["name"], c["verdict"], _fig(c.get("p"), ".2g"),
                         _fig(c.get("magnitude_nt"), ".3g"), c["message"]])
    blocks = [Table(["model", "check", "verdict", "p", "size (nT)", "finding"], rows)] if rows else \
        ["no model checks recorded (a calibration of a model other than T24, or one from before they were)"]
    return Section("Model checks", blocks)


def certificate_html(session: str | Path, dut: str, recorded: dict | None = None) -> str:
    title, sections = certificate_sections(session, dut, recorded)
    return render_html(title, sections, subtitle=f"issued by magrig from {Path(session).name}") \
        .replace("</style>", PRINT_CSS + "</style>", 1)


PRINT_CSS = """
td, th { text-align: left; vertical-align: top; }
@page { size: A4; margin: 16mm 14mm 18mm;
        @bottom-right { content: "page " counter(page) " of " counter(pages); font-size: 9pt; } }
@media print { body { margin: 0; max-width: none; font-size: 10pt; } h2 { break-after: avoid; } }
"""


def certificate_file(out_dir: str | Path, session: str | Path, dut: str, suffix: str) -> Path:
    stem = Path(session).name.removesuffix(".session")
    return inside(out_dir, f"{stem}.{dut}.certificate.{suffix}")


def write_certificate(session: str | Path, dut: str, out_dir: str | Path, *, pdf: bool = True,
                      recorded: dict | None = None) -> tuple[list[Path], str]:
    """([the HTML file, the PDF when one could be printed], what happened to the PDF); `recorded`: the
    session's session_record, read once for several DUTs."""
    from rig.report.pdf import print_pdf

    out = Path(out_dir)
    page = certificate_file(out, session, dut, "html")
    try:
        out.mkdir(parents=True, exist_ok=True)
        page.write_text(certificate_html(session, dut, recorded), encoding="utf-8")
    except OSError as exc:
        raise DataError(f"{out}: cannot write the certificate: {exc.strerror or exc}") from None
    if not pdf:
        return [page], "PDF not asked for"
    target = certificate_file(out, session, dut, "pdf")
    said = print_pdf(page, target)
    return ([page, target] if target.is_file() else [page]), said
