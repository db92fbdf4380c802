"""The report's blocks about the calibration shown: where it comes from (its file and sha256), its equation,
its measurand (how h was read, tau's thermometer, the frames, the indexing, the reference chain, what the
file does not state), its residual beside its stated uncertainty (flagged when the residual is the
larger), its parameters with their standard errors and expanded uncertainties (named as the file names
them: calib/equations.py parameter_label, zero-based), its budget, its model checks, and the run's other
calibrations. Every figure here is read from the calibration itself (rig/analysis/judged.py for the words).
"""

from __future__ import annotations

import numpy as np

from calib.equations import parameter_label
from rig.analysis.judged import RADIUS_LABEL, field_figures, quality_of
from rig.analysis.measurand import measurand_rows
from rig.report.html import ItemList, Table

PARAM_UNITS = {
    "S": "-",
    "K": "1/°C",
    "K2": "1/°C²",
    "b_nt": "nT",
    "h0_nt": "nT",
    "kb_nt_per_c": "nT/°C",
    "kb2_nt_per_c2": "nT/°C²",
    "k": "-",
    "angles_deg": "deg",
    "A": "-",
    "c_nt": "nT",
    "KA_per_c": "1/°C",
    "kc_nt_per_c": "nT/°C",
}
TAU_WORDS = {"absolute_c": "the DUT temperature in °C as measured (absolute: nothing is subtracted)",
             "not_used": "not used (the model has no temperature terms)"}


def fmt(x: float | None, digits: int = 4) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.{digits}g}"


def number(x: object) -> float:
    try:
        value = float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return float("nan")
    return value if np.isfinite(value) else float("nan")


def equation_text(cal) -> str:
    keys = cal.equation_keys()
    tau = TAU_WORDS.get(keys["tau"], keys["tau"])
    tau_0 = f"; tau_0_c = {keys['tau_0_c']:g} °C (part of the equation)" if "tau_0_c" in keys else ""
    return f"Equation: {keys['equation']}; tau: {tau}{tau_0}."


def quality_text(cal) -> str:
    """Residual beside the stated uncertainty, what dominates it, and the flag."""
    q = quality_of(cal)
    parts = [f"Residual RMS {fmt(q.rms_nt)} nT"]
    if q.radius_nt is not None:
        parts.append(f"stated 95 % error radius {q.radius_nt:.4g} nT (the largest radius holding 95 % of the "
                     "calibrated field's 3-D error at a point of the plan's fields and temperatures)")
    if q.dominant:
        parts.append(f"largest contribution: {q.dominant}")
    text = "; ".join(parts) + "."
    return text + (f" FLAGGED: {q.exceeds_text()}." if q.exceeds else "")


def intro_blocks(r) -> list:
    """Where the calibration shown comes from, its equation and its quality, in three sentences."""
    origin = r.origin or (f"a {r.main.model.upper()} calibration fitted here (robust: "
                          f"{str(r.robust).lower()}): the run wrote none")
    return [f"{len(r.ds)} samples; residuals shown for {origin}.", equation_text(r.main),
            quality_text(r.main), measurand_table(r.main)]


def measurand_table(cal) -> Table:
    """What the calibration states of its measurand, and a line for each thing it does not."""
    return Table(["measurand", "as the calibration file states it"],
                 [list(row) for row in measurand_rows(cal)],
                 f"{cal.model.upper()}: the measurand (the file's reading, tau_source, frame, indexing, "
                 "reference_chain and source)")


def params_table(title: str, cal) -> Table:
    rows = []
    expanded = (getattr(cal, "uncertainty", None) or {}).get("expanded") or {}
    k = number((getattr(cal, "uncertainty", None) or {}).get("coverage_factor"))
    for key, value in cal.params.items():
        values = np.asarray(value, dtype=float)
        errors = np.asarray(cal.std_errors.get(key, np.full(values.shape, np.nan)), dtype=float)
        big_u = np.asarray(expanded.get(key, np.full(values.shape, np.nan)), dtype=float)
        unit = PARAM_UNITS.get(key, "")
        for index in np.ndindex(values.shape):
            label = parameter_label(key, index)
            se = errors[index] if errors.shape == values.shape else np.nan
            u = big_u[index] if big_u.shape == values.shape else np.nan
            rows.append([label, f"{values[index]:.8g}", fmt(se, 3), fmt(u, 3), unit])
    stats = cal.stats if isinstance(cal.stats, dict) else {}
    centre = cal.equation_keys().get("solve_centre_c")
    solve = "" if centre is None else f"; the solve centred tau at {centre:.4g} °C internally (not applied)"
    caption = (f"{cal.model.upper()}: {title}; RMS after {fmt(stats.get('rms_after_nt'))} nT{solve}; "
               "named as in the file: M[row][column], zero-based, row = output axis of B")
    k_text = f"k = {fmt(k, 2)}" if np.isfinite(k) else "no budget"
    header = ["parameter", "value", "std error", f"expanded uncertainty ({k_text})", "unit"]
    return Table(header, rows, caption)


def budget_rows(uncertainty: dict | None) -> list[tuple[str, float, str]]:
    """[(source, contribution nT, note)] of a budget; [] without one."""
    if not uncertainty:
        return []
    return [(str(b.get("source", "?")), number(b.get("contribution_nt")), str(b.get("note", "")))
            for b in uncertainty.get("budget") or [] if isinstance(b, dict)]


def uncertainty_blocks(r) -> list:
    """The budget table (and its notes), or why there is none."""
    rows = budget_rows(r.uncertainty)
    if not rows:
        return ["No uncertainty budget: the calibration states none (calibrations from a campaign carry "
                "one; see rig/budget/run_inputs.py)."]
    u = r.uncertainty
    f = field_figures(u)
    k = "-" if f.coverage_factor is None else fmt(f.coverage_factor, 3)
    table = Table(["input", "standard uncertainty of the field (nT)", "how it was drawn"],
                  [[name, fmt(value, 3), note] for name, value, note in rows]
                  + [["combined standard uncertainty u", fmt(f.standard_nt, 3),
                      f"RMS over the plan's fields and temperatures; {u.get('method', '')}"],
                     [f"expanded uncertainty U = k u (k = {k})", fmt(f.expanded_nt, 3),
                      f"{k} times the combined standard uncertainty above"],
                     [RADIUS_LABEL, fmt(f.radius_nt, 3),
                      "a radius over the grid, not k u: at every point of the plan's fields and "
                      "temperatures 95 % of the calibrated field's 3-D error lies within it"]],
                  f"Uncertainty budget of {r.uncertainty_of}")
    notes = [f"Note: {n}" for n in u.get("notes") or []]
    return [table, *notes]


def check_blocks(cal) -> list:
    """The model checks the calibration records (T24's linearity in temperature, a scalar fit's choice,
    a ramp's thermal lag) and its warnings."""
    stats = cal.stats if isinstance(cal.stats, dict) else {}
    rows = []
    lin = stats.get("linearity")
    if isinstance(lin, dict):
        verdict = {True: "holds", False: "does NOT hold", None: "not testable"}.get(lin.get("holds"), "?")
        figures = ", ".join(f"{k} {fmt(number(lin[k]))}" for k in ("quadratic_nt", "chi2", "dof", "p")
                            if k in lin)
        rows.append(["linearity in temperature", verdict, f"{figures}. {lin.get('message', '')}"])
    lag = stats.get("thermal_lag")
    if isinstance(lag, dict):
        rows.append(["thermal lag", "applied" if lag.get("applied") else "not applied",
                     str(lag.get("message", ""))])
    tm = stats.get("temperature_model")  # T24 or T36, chosen where T24's linearity in temperature failed
    if isinstance(tm, dict):
        rows.append(["temperature model", str(tm.get("model", "?")).upper() + " chosen",
                     f"{tm.get('why', '')}. {tm.get('message', '')}"])
    choice = stats.get("validation")
    if isinstance(choice, dict):
        rows.append(["variant", str(choice.get("chosen", "?")), str(choice.get("method", ""))])
    out: list = [Table(["check", "result", "figures"], rows)] if rows else [
        f"The {cal.model.upper()} calibration records no model check."]
    warnings = stats.get("warnings") or []
    return out + ([ItemList([str(w) for w in warnings], kind="warning")] if warnings else [])


def others_table(others: list) -> Table:
    """The run's other calibrations of this DUT: file, residual, stated uncertainty, flag."""
    rows = []
    for rec in others:
        q = quality_of(rec.calibration)
        rows.append([rec.model.upper(), rec.file_text(), fmt(q.rms_nt), q.uncertainty_text(),
                     ("RMS > radius: " + q.exceeds_text()) if q.exceeds else ("ok" if q.radius_nt else "-")])
    return Table(["model", "file", "RMS after (nT)", RADIUS_LABEL, "check"], rows)
