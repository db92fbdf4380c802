"""The measurand, in full, as the certificate states it for each calibration file: its equation and tau
convention, how h was read from the device, the thermometer that gave tau, the frames of B and of h, the
index order of its parameters (the file's own numbering) and the unit of each.

A file of format 3 states these in keys of its own (`reading`, `tau_source`, `frame`, `indexing`: README.md,
"Calibration file"); the certificate quotes them. A file of format 2 does not: the
certificate then states what the session recorded of the same things (the plan's SET/RESET mode, the
station's thermometer and field source, the device as it reported itself) and says, per line, that the
calibration file does not state it.
"""

from __future__ import annotations

import json

from calib.equations import INDEXING
from rig.budget.modelerror import CORRECTED, CORRECTED_U
from rig.report.calsection import PARAM_UNITS, TAU_WORDS
from rig.report.html import Table

FROM_SESSION = "the session's record (the calibration file does not state it)"


def _said(stated: dict) -> str:
    """A stated mapping in one line: its `text` keys first, then the rest as key: value."""
    parts = []
    for key, value in stated.items():
        if isinstance(value, dict):
            parts.append(f"{key}: " + ", ".join(f"{k} {v}" for k, v in value.items() if v is not None))
        elif value is not None:
            parts.append(f"{key}: {value}")
    return "; ".join(parts)


def reading_text(record, cal_file) -> tuple[str, str]:
    """(how h was read, where that is stated)."""
    stated = cal_file.raw.get("reading")
    if isinstance(stated, dict):
        return _said(stated), "the calibration file (reading:)"
    plan, config, identity = record.plan, record.config, record.identity
    mode = ("a SET and a RESET reading per sample, h = (h_SET - h_RESET) / 2: the bridge offset cancels"
            if plan.set_reset == "pair" else "one plain reading per sample: the bridge offset stays in h")
    options = json.dumps(config.options.model_dump(mode="json"), sort_keys=True) if config.options else "{}"
    model = identity.get("model") or config.type
    return (f"device {record.dut} ({model}, {config.type}); plan set_reset {plan.set_reset}: {mode}; the "
            f"driver's settings {options}; h in nT (the driver's conversion of the device's output codes); "
            f"{plan.samples_per_point} readings per point, each one sample of the fit"), FROM_SESSION


def tau_text(record, cal_file) -> tuple[str, str]:
    stated = cal_file.raw.get("tau_source")
    if isinstance(stated, dict):
        return _said(stated), "the calibration file (tau_source:)"
    config, station = record.config, record.station
    if config.temp_source == "self":
        return f"the DUT's own die sensor ({config.type}), degC as measured", FROM_SESSION
    sensor = next((s for s in station.temperature_sensors if s.name == config.temp_source), None)
    where = f"beside {sensor.beside}" if sensor is not None else "place not recorded"
    kind = sensor.type if sensor is not None else "?"
    return f"{config.temp_source} ({kind}, {where}), degC as measured", FROM_SESSION


def frame_text(record, cal_file) -> tuple[str, str]:
    stated = cal_file.raw.get("frame")
    if isinstance(stated, dict):
        return "; ".join(f"{k}: {(v or {}).get('text', v)}" for k, v in stated.items()), \
            "the calibration file (frame:)"
    source = record.station.field_source
    return (f"B: the station's field frame ({source.described}'s axes x, y, z of station "
            f"{record.station.name}) as the DUT was mounted; h: the DUT's axes as its driver reports them "
            "(x, y, z)"), FROM_SESSION


def indexing_text(cal_file) -> tuple[str, str]:
    stated = cal_file.raw.get("indexing")
    if isinstance(stated, dict):
        return _said(stated), "the calibration file (indexing:)"
    return _said(INDEXING), "this certificate, the same as the file's covariance names (the file does not " \
                            "state it in words)"


def units_text(cal_file) -> str:
    """`S (3x3) dimensionless; b_nt (3) in nT; ...`."""
    parts = []
    for name, value in cal_file.cal.params.items():
        unit = PARAM_UNITS.get(name, "-")
        shape = "x".join(map(str, getattr(value, "shape", ()))) or "1"
        parts.append(f"{name} ({shape}) " + ("dimensionless" if unit == "-" else f"in {unit}"))
    return "; ".join(parts)


def measurand_blocks(record) -> list:
    """Per calibration file, a table of the measurand's definition; then what the parameters stand for
    and what a point of use adds."""
    blocks: list = []
    for model, cal_file in record.cals.items():
        keys = cal_file.cal.equation_keys()
        tau = TAU_WORDS.get(keys["tau"], keys["tau"])
        tau_0 = f"; tau_0_c = {keys['tau_0_c']:g} degC (part of the equation)" if "tau_0_c" in keys else ""
        rows = [["equation", keys["equation"], "the calibration file (equation:)"],
                ["tau", f"{tau}{tau_0}", "the calibration file (tau:)"]]
        for what, (text, where) in (("how h was read", reading_text(record, cal_file)),
                                    ("the thermometer that gave tau", tau_text(record, cal_file)),
                                    ("frames of B and h", frame_text(record, cal_file)),
                                    ("index order", indexing_text(cal_file))):
            rows.append([what, text, where])
        rows.append(["parameters and units", units_text(cal_file), "the calibration file (params:)"])
        blocks.append(Table(["item", "definition", "stated by"], rows,
                            caption=f"{model.upper()}: the measurand ({cal_file.path.name})"))
    return blocks + _stands_for(record)


def _stands_for(record) -> list[str]:
    """What the parameters stand for, and what a point of use adds to their uncertainty."""
    ds = record.ds
    said = [f"The parameters of each model are those that describe the DUT best over the conditions stated "
            f"({ds.temp_c.min():.1f} .. {ds.temp_c.max():.1f} degC, the plan's fields), in its mean thermal "
            "state. What the model cannot follow there (the terms the model checks found, the misfit) and "
            "the DUT's thermal state at a point of use are uncertainties of the calibrated field: at any "
            "reading they add to what the parameters' covariance gives (rig apply --uncertainty; the files' "
            "model_error_nt and hysteresis_state_nt)."]
    fixed = next((c.cal.source for c in record.cals.values() if CORRECTED in (c.cal.source or {})), None)
    if fixed is not None:
        said.append("Correction: the readings were taken to the DUT's mean thermal state before every fit, "
                    "for the thermal hysteresis the model checks found (the offset heating against cooling): "
                    "d = (" + ", ".join(f"{v:.3g}" for v in fixed[CORRECTED]) + ") nT per axis, standard "
                    "uncertainty (" + ", ".join(f"{v:.2g}" for v in fixed.get(CORRECTED_U, [])) + ") nT "
                    "(GUM 3.2.4). The budgets carry the correction's uncertainty.")
    if "scalar" in record.cals:
        said.append("SCALAR fits |B| alone: its calibrated field is in the DUT's own frame (A "
                    "upper-triangular), and a rotation of it, one that changes with temperature included, "
                    "leaves |B| unchanged and is not seen. Its uncertainty answers for |B| (the interval of "
                    "|B|'s error; rig apply --uncertainty writes it per row as u_norm); for the field's "
                    "direction only as far as |B| shows it. It holds over the directions taken (Conditions).")
    for model, cal_file in record.cals.items():
        u = cal_file.uncertainty
        model_error, state = u.get("model_error_nt"), u.get("hysteresis_state_nt")
        if model_error is None and state is None:
            continue
        parts = [] if model_error is None else [
            "model error (" + ", ".join(f"{v:.3g}" for v in model_error) + ") nT, standard"]
        parts += [] if state is None else [
            "thermal state +-(" + ", ".join(f"{v:.3g}" for v in state) + ") nT, either sign"]
        said.append(f"{model.upper()} at a point of use, per axis: " + "; ".join(parts) + ".")
    return said
