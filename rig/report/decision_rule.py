"""The statement of conformity (ISO/IEC 17025:2017 7.8.6) against the plan's `acceptance:` limits, by
the decision rule of ILAC-G8:09/2019 (guarded acceptance, guard band w = U, non-binary statement).

    criteria = judge(record)            # one Criterion per limit the plan gives, in its words
    overall(criteria)                   # PASS, CONDITIONAL or FAIL

For a limit on a figure with a stated expanded uncertainty U (a parameter's bounds: its U from the
calibration file), the acceptance zone is the tolerance shrunk by w = U on each side:
- PASS: every estimate lies inside its limits by at least U (the interval estimate +- U within them);
- FAIL: an estimate lies outside its limits by at least U (its interval wholly outside);
- CONDITIONAL: otherwise: an interval straddles a limit (a conditional pass with the estimate inside,
  a conditional fail with it outside; ILAC-G8 4.2.3).
A limit on a figure no uncertainty is stated for (a residual's or a held-out RMS, a standard error, the
expanded uncertainty itself, the thermal lag, the temperatures the data reached, a model check's test)
is applied to the figure as it is (w = 0: PASS or FAIL), and the certificate says so for each. The run's
own verdict (rig/analysis/acceptance.py, on the estimates alone) is quoted beside, never replaces this.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.analysis.acceptance import coverage_problem, model_check_findings
from rig.report.html import Section, Table

PASS, FAIL, CONDITIONAL = "PASS", "FAIL", "CONDITIONAL"
# ILAC-G8's four outcomes as the DCC names them (dcc:stringConformityStatementStatusType), each a result
RESULTS = {"pass": PASS, "conditionalPass": CONDITIONAL, "conditionalFail": CONDITIONAL, "fail": FAIL}
RULE = ("Decision rule: ILAC-G8:09/2019 guarded acceptance with guard band w = U (the expanded uncertainty "
        "of the figure judged, k as stated, 95.45 %). A result is PASS when its estimate lies inside the "
        "limit by at least U, FAIL when it lies outside the limit by at least U, and CONDITIONAL when the "
        "interval estimate +- U straddles the limit (a conditional pass with the estimate inside, a "
        "conditional fail with it outside): the probability of a false accept of a PASS is then below "
        "about 2.3 % (one-sided, for a normal distribution). A figure with no stated uncertainty is judged "
        "as it is (w = 0), said per criterion.")
NO_U = "w = 0: no uncertainty is stated for this figure"


@dataclass(frozen=True)
class Criterion:
    name: str  # as rig/analysis/acceptance.py names it: heldout_rms, bounds.b_nt, ...
    limit: str
    figure: str
    guard: str  # the guard band used, in words
    conformity: str  # pass | conditionalPass | conditionalFail | fail (RESULTS)
    words: str  # why, in a sentence

    @property
    def result(self) -> str:
        """PASS, CONDITIONAL or FAIL."""
        return RESULTS[self.conformity]


def upper_limit(name: str, value: float | None, limit: float, unit: str, expanded: float = 0.0) -> Criterion:
    """A figure that must not exceed `limit`, guarded by its U (0: judged as it is)."""
    guard = f"w = U = {expanded:.3g} {unit}" if expanded > 0 else NO_U
    if value is None or not np.isfinite(value):
        return Criterion(name, f"<= {limit:g} {unit}", "not computable", guard, "fail",
                         "the figure could not be computed")
    figure = f"{value:.4g} {unit}"
    if value + expanded <= limit:
        status, words = "pass", f"{figure} is within the limit by at least the guard band"
    elif value - expanded > limit:
        status, words = "fail", f"{figure} exceeds the limit" + (" by more than U" if expanded else "")
    elif value <= limit:
        status, words = "conditionalPass", f"conditional pass: {figure} is within the limit by less than U"
    else:
        status, words = "conditionalFail", f"conditional fail: {figure} exceeds the limit by less than U"
    return Criterion(name, f"<= {limit:g} {unit}", figure, guard, status, words)


def within_bounds(name: str, values, expanded, labels: list[str], low: float, high: float,
                  unit: str) -> Criterion:
    """Every element within [low, high], each guarded by its own U."""
    values, expanded = np.ravel(values).astype(float), np.ravel(expanded).astype(float)
    inside_by = np.minimum(values - low, high - values)  # > 0 inside, < 0 outside
    margin = inside_by - expanded  # >= 0: inside by at least U
    worst = int(np.argmin(inside_by - expanded))
    figure = ", ".join(f"{lab} {v:.6g} +- {u:.3g}"
                       for lab, v, u in zip(labels, values, expanded, strict=True))
    guard = "w = U of each element (the calibration file's uncertainty.expanded)"
    lab, value, big_u = labels[worst], values[worst], expanded[worst]
    if np.all(margin >= 0):
        status, words = "pass", "every element is inside the bounds by at least its U"
    elif np.any(inside_by + expanded < 0):
        bad = int(np.argmin(inside_by + expanded))
        status, words = "fail", f"{labels[bad]} {values[bad]:.6g} lies outside the bounds by more than its U"
    elif np.all(inside_by >= 0):
        status = "conditionalPass"
        words = f"conditional pass: {lab} {value:.6g} is inside the bounds by less than its U {big_u:.3g}"
    else:
        status = "conditionalFail"
        words = f"conditional fail: {lab} {value:.6g} is outside the bounds by less than its U {big_u:.3g}"
    return Criterion(name, f"every element within [{low:g}, {high:g}] {unit}", figure, guard, status, words)


def judge(record) -> list[Criterion]:
    """The plan's acceptance limits, each judged by the rule on the calibration the plan judges ([]
    without acceptance limits or without that calibration)."""
    from rig.report.calsection import PARAM_UNITS
    from rig.report.certificate_results import labels

    acceptance = record.plan.acceptance
    verdict = record.verdicts[0] if record.verdicts else {}
    model = verdict.get("model") or record.plan.judged_model
    if acceptance is None or model not in record.cals:
        return []
    cal_file = record.cals[model]
    cal, u = cal_file.cal, cal_file.uncertainty
    out = []
    figures: dict = {}
    plan = record.plan
    problem = coverage_problem(cal, plan.temperatures.covered_c(), plan.temperatures.band_c(), figures)
    reached = "the data reach both ends of the plan's range"
    out.append(Criterion("coverage", f"the data reach both ends of {plan.temperatures.covered_c()} degC "
                         f"within {plan.temperatures.band_c()} degC", problem or "reached", NO_U,
                         "fail" if problem else "pass", problem or reached))
    for name, limit, value, unit in (
            ("heldout_rms", acceptance.max_heldout_rms_nt, verdict.get("heldout_rms_nt"), "nT"),
            ("fit_rms", acceptance.max_rms_nt, cal.stats.get("rms_after_nt"), "nT"),
            ("uncertainty", acceptance.max_expanded_uncertainty_nt, u.get("expanded_vector_error_nt"), "nT"),
            ("lag", acceptance.max_lag_s, verdict.get("lag_s"), "s")):
        if limit is not None:
            out.append(upper_limit(name, value, limit, unit))
    for name, limit in acceptance.max_std_error.items():
        out.append(upper_limit(f"std_error.{name}", float(np.max(np.abs(cal.std_errors[name]))), limit,
                               PARAM_UNITS.get(name, "")))
    names = labels(cal_file)
    flat_names = dict(zip(names, [n for n, v in cal.params.items() for _ in np.ravel(v)], strict=True))
    for name, (low, high) in acceptance.bounds.items():
        own = [lab for lab, parent in flat_names.items() if parent == name]
        expanded = np.ravel((u.get("expanded") or {}).get(name, np.zeros(np.size(cal.params[name]))))
        out.append(within_bounds(f"bounds.{name}", cal.params[name], expanded, own, low, high,
                                 PARAM_UNITS.get(name, "")))
    if acceptance.model_checks:
        t24 = record.cals.get("t24")
        failures, not_run = model_check_findings(None if t24 is None else t24.cal.stats, model)
        said = "; ".join(failures) or "no model check of T24 fails where the judged model does not capture it"
        if not_run:
            said += f" (not run: {', '.join(not_run)})"
        out.append(Criterion("model checks", "T24's checks at p = 0.01", said,
                             "w = 0: a test of significance decides", "fail" if failures else "pass", said))
    return out


def overall(criteria: list[Criterion]) -> str:
    results = {c.result for c in criteria}
    return FAIL if FAIL in results else CONDITIONAL if CONDITIONAL in results else PASS


def conformity_section(criteria: list[Criterion], verdicts: list[dict]) -> Section:
    """The statement of conformity: the rule in words, each criterion's result, the run's own verdict."""
    if not criteria:
        return Section("Statement of conformity", [
            "None: the plan states no acceptance limits, so no conformity is stated."])
    rows = [[x.name, x.limit, x.figure, x.guard, x.result, x.words] for x in criteria]
    run = "; ".join(f"{v['verdict']} ({v['model']})" for v in verdicts) or "not recorded"
    return Section("Statement of conformity", [
        RULE,
        Table(["criterion", "limit", "figure", "guard band", "result", "why"], rows,
              caption=f"Against the plan's acceptance limits: {overall(criteria)}"),
        f"The run's own verdict, on the estimates alone without a guard band: {run}; this certificate's "
        "statement is the table's."])
