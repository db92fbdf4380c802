"""After a completed run: fit every model of the plan for every DUT from the session's own data, state
each calibration's uncertainty (rig/reference/budget.py), write the calibration files beside the session, and
judge
each DUT against the plan's acceptance limits."""

from __future__ import annotations

from typing import Any

from rig import __version__
from rig import config as cfg
from rig.core.errors import ERRORS
from rig.session.events import Kind, Reason


def accept_session(session, plan: cfg.Plan, station: cfg.Station, fits: list[dict],
                   live_summaries: dict[str, str]) -> list:
    """PASS/FAIL per DUT (rig/analysis/acceptance.py): stored in the session, written as a CSV beside it,
    shown in
    the live view's summaries."""
    from rig.analysis import acceptance

    verdicts = acceptance.judge_session(session.path, plan, station, fits)
    session.record_acceptance(acceptance.rows(verdicts))
    acceptance.write_summary_csv(acceptance.summary_csv_path(session.path), session.path.name, station.name,
                                 verdicts)
    for v in verdicts:
        session.log_event(Kind.ACCEPTANCE, v.line(), code=Reason.ACCEPTED if v.passed else Reason.REJECTED,
                          device=v.dut, level="INFO" if v.passed else "WARNING")
        live_summaries[v.dut] = f"{v.verdict} " + live_summaries.get(v.dut, "")
    return verdicts


def fit_session(session, plan: cfg.Plan, station: cfg.Station, progress=None) -> list[dict]:
    """Fit each of the plan's models for each DUT from the session's own dataset, the way `rig refit` and
    `rig refit-all` fit it (rig/analysis/sessionfit.py); write one calibration file per DUT and model next
    to the session and record each fit in it; the DUTs' shared inputs in the cross-covariance file beside
    them (rig/analysis/crosscov.py). Where a DUT's T24 linearity in temperature fails, a T36 is fitted too
    (unless the plan fits it already) and both record the choice between them
    (rig/analysis/tempchoice.py). `progress(dut, model, done, total)` is told before each fit; the
    session records it too (rig/analysis/fitprogress.py)."""
    from rig.analysis.crosscov import CrossCovariance
    from rig.analysis.fitprogress import FitProgress
    from rig.analysis.sessionfit import SessionFitter
    from rig.analysis.tempchoice import share_choice, wants_t36
    from rig.session.reader import SessionReader

    out = []
    with SessionReader(session.path) as reader:
        fitter = SessionFitter.of(reader)
        datasets = [(dut, _dataset(reader, dut.name)) for dut in station.duts]
    shared = CrossCovariance()
    tell = FitProgress(session, len(station.duts) * len(plan.fit.models), progress)
    for dut, ds in datasets:
        if isinstance(ds, Exception):
            out.append({"dut": dut.name, "model": "-", "error": str(ds)})
            continue
        prepared = fitter.prepare(ds)
        fitted: dict[str, Any] = {}  # model: (calibration, budget), or the error that stopped its fit
        for model in plan.fit.models:
            tell(dut.name, model)
            fitted[model] = _calibrate(fitter, prepared, model, plan.fit.robust)
        t24 = fitted.get("t24")
        if isinstance(t24, tuple) and wants_t36(t24[0]):  # T24's linearity in temperature failed
            if "t36" not in fitted:
                fitted["t36"] = _calibrate(fitter, prepared, "t36", plan.fit.robust)
            if isinstance(fitted["t36"], tuple):
                share_choice(t24[0], fitted["t36"][0])
        for model, result in fitted.items():
            out.append(_keep(session, dut.name, model, result, shared, len(prepared.ds)))
    tell.finished(shared)
    return out


def _calibrate(fitter, prepared, model: str, robust: bool):
    """(calibration, its budget), or the project error that stopped the fit."""
    try:
        return fitter.calibrate_budgeted(prepared, model, robust=robust, software_version=__version__)
    except ERRORS as exc:
        return exc


def _keep(session, dut: str, model: str, result, shared, n: int) -> dict[str, Any]:
    """A fit's file beside the session and its record in it, or its failure logged."""
    from calib import calfile
    from rig.core.paths import calibration_file

    entry: dict[str, Any] = {"dut": dut, "model": model}
    try:
        if isinstance(result, Exception):
            raise result
        cal, budget = result
        shared.add(dut, model, budget)
        path = calibration_file(session.path, dut, model)
    except ERRORS as exc:
        entry["error"] = str(exc)
        session.log_event(Kind.FIT_FAILED, f"{dut} {model}: {exc}", code=Reason.FIT_FAILED,
                          level="WARNING", device=dut, model=model)
        return entry
    calfile.save(cal, path)
    rms = cal.stats.get("rms_after_nt")
    session.record_fit(dut, model, cal.to_dict(), residual_rms_nt=rms)
    entry.update(path=path, rms_nt=rms, calibration=cal, n=n)
    return entry


def _dataset(reader, dut: str):
    """One DUT's dataset, or the project error that stopped reading it."""
    try:
        return reader.dataset(dut)
    except ERRORS as exc:
        return exc
