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
    them (rig/analysis/crosscov.py). `progress(dut, model, done, total)` is told before each fit; the
    session records it too (rig/analysis/fitprogress.py)."""
    from calib import calfile
    from rig.analysis.crosscov import CrossCovariance
    from rig.analysis.fitprogress import FitProgress
    from rig.analysis.sessionfit import SessionFitter
    from rig.core.paths import calibration_file
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
        for model in plan.fit.models:
            tell(dut.name, model)
            entry: dict[str, Any] = {"dut": dut.name, "model": model}
            try:
                cal, budget = fitter.calibrate_budgeted(prepared, model, robust=plan.fit.robust,
                                                        software_version=__version__)
                shared.add(dut.name, model, budget)
                path = calibration_file(session.path, dut.name, model)
            except ERRORS as exc:
                entry["error"] = str(exc)
                session.log_event(Kind.FIT_FAILED, f"{dut.name} {model}: {exc}", code=Reason.FIT_FAILED,
                                  level="WARNING", device=dut.name, model=model)
                out.append(entry)
                continue
            calfile.save(cal, path)
            rms = cal.stats.get("rms_after_nt")
            session.record_fit(dut.name, model, cal.to_dict(), residual_rms_nt=rms)
            entry.update(path=path, rms_nt=rms, calibration=cal, n=len(prepared.ds))
            out.append(entry)
    tell.finished(shared)
    return out


def _dataset(reader, dut: str):
    """One DUT's dataset, or the project error that stopped reading it."""
    try:
        return reader.dataset(dut)
    except ERRORS as exc:
        return exc
