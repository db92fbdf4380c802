"""Acceptance per DUT: the plan's `acceptance:` limits turned into PASS or FAIL, with the failed criteria.

    v = judge_dut(plan, dut, dut_type, ds, fitted, errors, lag)    # where a DUT's fits are made (dutfits.py)
    verdicts = judge_session(session.path, plan, station, fits)   # offline, from a session on disk
    record(session, verdicts)                                      # the session's `acceptance` table
    write_summary_csv(path, session_name, station_name, verdicts)  # for a production line

Criteria (each only when the plan gives it; names as they appear in `failed`):
    heldout_rms        RMS error on held-out points (k-fold over whole points, rig/analysis/heldout.py):
                       vector error for vector models, |B| error for scalar ones
    fit_rms            RMS residual of the full fit
    uncertainty        the calibration's expanded vector uncertainty (its budget, rig/budget/run_inputs.py); a
                       calibration without a budget fails it
    std_error.<name>   largest standard error of parameter <name>
    bounds.<name>      every element of parameter <name> within [low, high]
    lag                thermal lag time constant (calib/thermal/lag.py); data with no lag information (step
    and
                       dwell) is not judged on it, and says so in `notes`
    coverage           always: the DUT temperatures its calibration's data covers (the fit's
                       `temperature_range_c`, at the element where the lag was corrected) reach both ends of
                       the plan's range within the plan's stability band; a calibration that would
                       extrapolate over part of the range fails
    model checks       with `model_checks` (the default): a check of the DUT's T24 calibration
                       (calib/checks/model_checks.py: linearity in temperature, thermal hysteresis, linearity
                       in the field) that fails and that the judged model does not capture fails the DUT,
                       named with its statistic and p; only T36, judged because it validated better
                       (rig/analysis/tempchoice.py), captures a failed linearity in temperature. A check
                       the data could not run is "not run": said in the verdict line, never a failure
A DUT whose model could not be fitted fails with criterion "fit". Its judged model is the plan's, or T36
where the plan judges T24 and T36 was chosen (rig/analysis/judged.py `judged_for_dut`).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calib.equations import renamed
from calib.io.atomic import atomic_write
from rig.core.errors import ERRORS

PASS, FAIL = "PASS", "FAIL"
CSV_COLUMNS = ("session", "station", "dut", "type", "model", "verdict", "failed", "heldout_rms_nt",
               "fit_rms_nt", "expanded_uncertainty_nt", "lag_s", "samples", "notes")


@dataclass
class Verdict:
    dut: str
    model: str
    failed: list[str] = field(default_factory=list)
    figures: dict[str, float | None] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    dut_type: str = ""
    samples: int = 0
    not_run: list[str] = field(default_factory=list)  # the model checks the data could not run

    @property
    def passed(self) -> bool:
        return not self.failed

    @property
    def verdict(self) -> str:
        return PASS if self.passed else FAIL

    def line(self) -> str:
        """`mmc0 PASS` or `mmc0 FAIL (heldout_rms 212 nT > 150, bounds.b_nt)`, and the model checks not run:
        `mmc0 PASS (model checks not run: thermal hysteresis)`."""
        said = list(self.failed)
        if self.not_run:
            said.append(f"model checks not run: {', '.join(self.not_run)}")
        return f"{self.dut} {self.verdict}" + (f" ({', '.join(said)})" if said else "")


def _finite(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def heldout_rms_nt(ds, model: str, robust: bool) -> float | None:
    """RMS error on held-out points: k-fold with whole points held out (as the report does)."""
    import calib
    from calib.models.registry import REGISTRY
    from rig.analysis import heldout

    points = ds.columns.get("point")
    folds, _ = heldout.fold_of_each_row(ds, labels=points if points is not None else ds.group)
    score = heldout.cross_validate(ds, model, lambda d, m: calib.fit(d, m, robust=robust), folds)
    return _finite(score.heldout_vector_rms if REGISTRY[model].vector else score.heldout_norm_rms)


def _lag_s(lag: dict | None) -> tuple[float | None, str | None]:
    """(tau, None) from the lag the fits estimated (rig/analysis/lagfit.py), else (None, why not)."""
    if lag is None:
        return None, "lag not judged: not estimated"
    if not lag.get("identifiable"):
        return None, f"lag not judged: {lag.get('message')}"
    return lag.get("tau_s"), None


def coverage_problem(cal, range_c: tuple[float, float] | None, band_c: float | None,
                     figures: dict) -> str | None:
    """What the calibration's data misses of the plan's range (None: it covers it within band_c)."""
    covered = cal.stats.get("temperature_range_c")
    if range_c is None or band_c is None or covered is None:
        return None
    low, high = covered
    figures["temperature_low_c"], figures["temperature_high_c"] = low, high
    lo, hi = range_c
    if low <= lo + band_c and high >= hi - band_c:
        return None
    return (f"coverage {low:.2f} .. {high:.2f} degC at the DUT does not reach the plan's {lo:g} .. {hi:g} "
            f"degC within {band_c:g}")


def model_check_findings(t24_stats: dict | None, judged_model: str) -> tuple[list[str], list[str]]:
    """(failures, checks not run) of a DUT's T24 model checks (its calibration's stats) for the model its
    verdict judges: a failed check fails the DUT unless that model captures it (T36, chosen, captures a
    failed linearity in temperature; nothing captures a hysteresis or a field non-linearity)."""
    from calib.checks.model_checks import TEMPERATURE
    from rig.analysis.judged import chosen_temperature_model

    checks = (t24_stats or {}).get("model_checks")
    if not checks:
        return [], ["all (no T24 model checks recorded)"]
    captured = {TEMPERATURE} if judged_model == "t36" and chosen_temperature_model(
        {"stats": t24_stats}) == "t36" else set()
    failures, not_run = [], []
    for check in checks:
        name = str(check.get("name"))
        if check.get("verdict") == "not testable":
            not_run.append(name)
        elif check.get("verdict") == "fails" and name not in captured:
            failures.append(f"{name} fails (statistic {check['statistic']:.4g} on {check['dof']} dof; p "
                            f"{check['p']:.2g}; {check['magnitude_nt']:.3g} nT)")
    return failures, not_run


def judge(acceptance, ds, cal, *, robust: bool = False, range_c: tuple[float, float] | None = None,
          band_c: float | None = None, lag: dict | None = None) -> tuple[list[str], dict, list[str]]:
    """(failed criteria, figures, notes) of one DUT's calibration `cal` fitted to `ds`; `range_c` and
    `band_c`: the plan's temperature range and stability band its data must cover; `lag`: the thermal lag
    the fits estimated (rig/analysis/lagfit.py), for acceptance.max_lag_s."""
    failed: list[str] = []
    notes: list[str] = []
    figures: dict[str, float | None] = {"fit_rms_nt": _finite(cal.stats.get("rms_after_nt"))}
    if problem := coverage_problem(cal, range_c, band_c, figures):
        failed.append(problem)
    figures["heldout_rms_nt"] = heldout_rms_nt(ds, cal.model, robust)
    figures["expanded_uncertainty_nt"] = _finite((cal.uncertainty or {}).get("expanded_vector_error_nt"))
    for name, limit, figure in (("heldout_rms", acceptance.max_heldout_rms_nt, "heldout_rms_nt"),
                                ("fit_rms", acceptance.max_rms_nt, "fit_rms_nt"),
                                ("uncertainty", acceptance.max_expanded_uncertainty_nt,
                                 "expanded_uncertainty_nt")):
        if limit is None:
            continue
        value = figures[figure]
        if value is None or value > limit:
            shown = "not computable" if value is None else f"{value:.4g} nT"
            failed.append(f"{name} {shown} > {limit:g}")
    for name, limit in acceptance.max_std_error.items():
        se = float(np.max(np.abs(cal.std_errors[renamed(cal.model, name)])))
        figures[f"std_error.{name}"] = se
        if not se <= limit:
            failed.append(f"std_error.{name} {se:.3g} > {limit:g}")
    for name, (low, high) in acceptance.bounds.items():
        values = np.asarray(cal.params[renamed(cal.model, name)], float)
        outside = values[(values < low) | (values > high)]
        if outside.size:
            failed.append(f"bounds.{name} {float(outside[np.argmax(np.abs(outside))]):.4g} "
                          f"outside [{low:g}, {high:g}]")
    if acceptance.max_lag_s is not None:
        tau_s, note = _lag_s(lag)
        figures["lag_s"] = tau_s
        if note:
            notes.append(note)
        elif tau_s is not None and tau_s > acceptance.max_lag_s:
            failed.append(f"lag {tau_s:.0f} s > {acceptance.max_lag_s:g}")
    return failed, figures, notes


def judge_dut(plan, dut: str, dut_type: str, ds, fitted: dict, errors: dict[str, str],
              lag: dict | None = None) -> Verdict:
    """One DUT's verdict on the plan's acceptance model (the first fitted model unless `acceptance.model`
    names another), where its fits are made (rig/analysis/dutfits.py): `ds` the data as they were fitted,
    `fitted` {model: calibration}, `errors` {model: why its fit failed}, `lag` the fits' lag estimate."""
    from rig.analysis.judged import judged_for_dut

    acceptance = plan.acceptance
    model = judged_for_dut(plan.judged_model, fitted)
    v = Verdict(dut, model, dut_type=dut_type)
    if model not in fitted:
        v.failed.append("fit")
        v.notes.append(errors.get(model) or f"no {model} fit")
        return v
    try:
        v.samples = len(ds)
        v.failed, v.figures, v.notes = judge(acceptance, ds, fitted[model], robust=plan.fit.robust,
                                             range_c=plan.temperatures.covered_c(),
                                             band_c=plan.temperatures.band_c(), lag=lag)
        if acceptance.model_checks:
            t24 = fitted.get("t24")
            failures, v.not_run = model_check_findings(None if t24 is None else t24.stats, model)
            v.failed += failures
            if v.not_run:
                v.notes.append(f"model checks not run: {', '.join(v.not_run)}")
    except ERRORS as exc:
        v.failed.append("fit")
        v.notes.append(str(exc))
    return v


def judge_session(session_path, plan, station, fits: list[dict]) -> list[Verdict]:
    """One verdict per DUT of the station from a session on disk and the fits made of it (an offline
    judgement; a run judges each DUT where its fits are made, with the data they were made from)."""
    from rig.analysis.judged import judged_for_dut
    from rig.analysis.sessionfit import SessionFitter
    from rig.session.reader import SessionReader

    out = []
    with SessionReader(session_path) as reader:
        fitter = SessionFitter.of(reader)
        for dut in station.duts:
            fitted = {f["model"]: f["calibration"] for f in fits
                      if f["dut"] == dut.name and f.get("calibration") is not None}
            errors = {f["model"]: str(f["error"]) for f in fits
                      if f["dut"] == dut.name and f.get("error") is not None}
            try:
                prepared = fitter.prepare(reader.dataset(dut.name))
            except ERRORS as exc:
                v = Verdict(dut.name, judged_for_dut(plan.judged_model, fitted), dut_type=dut.device_type)
                v.failed.append("fit")
                v.notes.append(str(exc))
                out.append(v)
                continue
            out.append(judge_dut(plan, dut.name, dut.device_type, prepared.ds, fitted, errors, prepared.lag))
    return out


def rows(verdicts: list[Verdict]) -> list[dict[str, Any]]:
    """The `acceptance` table's rows (`passed` is what the fleet database reads)."""
    return [{"dut": v.dut, "model": v.model, "passed": int(v.passed), "verdict": v.verdict,
             "failed": "; ".join(v.failed), "heldout_rms_nt": v.figures.get("heldout_rms_nt"),
             "fit_rms_nt": v.figures.get("fit_rms_nt"), "lag_s": v.figures.get("lag_s"),
             "notes": "; ".join(v.notes)} for v in verdicts]


def summary_csv_path(session_path: str | Path) -> Path:
    """The production summary beside the session: <session stem>.acceptance.csv."""
    session_path = Path(session_path)
    return session_path.with_name(session_path.name.removesuffix(".session") + ".acceptance.csv")


def write_summary_csv(path: Path, session: str, station: str, verdicts: list[Verdict]) -> Path:
    """One row per DUT, written atomically (never half a file)."""
    with atomic_write(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(CSV_COLUMNS)
        for v in verdicts:
            fig = {k: ("" if v.figures.get(k) is None else f"{v.figures[k]:.6g}")
                   for k in ("heldout_rms_nt", "fit_rms_nt", "expanded_uncertainty_nt", "lag_s")}
            writer.writerow([session, station, v.dut, v.dut_type, v.model, v.verdict, "; ".join(v.failed),
                             fig["heldout_rms_nt"], fig["fit_rms_nt"], fig["expanded_uncertainty_nt"],
                             fig["lag_s"], v.samples, "; ".join(v.notes)])
    return path


def verdict_text(recorded: list[dict]) -> str:
    """`rig sessions`' column: "PASS 16/16", "FAIL 2/16: mmc03, ser1", or "-" without acceptance."""
    if not recorded:
        return "-"
    failed = [r["dut"] for r in recorded if not r["passed"]]
    if not failed:
        return f"PASS {len(recorded)}/{len(recorded)}"
    return f"FAIL {len(failed)}/{len(recorded)}: {', '.join(failed)}"
