"""After a completed run: fit every model of the plan for every DUT from the session's own data, state
each calibration's uncertainty (rig/budget/run_inputs.py), write the calibration files beside the session,
and judge each DUT against the plan's acceptance limits."""

from __future__ import annotations

from typing import Any

from rig import config as cfg
from rig.session.events import Kind, Reason


def accept_session(session, plan: cfg.Plan, station: cfg.Station, fits: list[dict],
                   live_summaries: dict[str, str]) -> list:
    """PASS/FAIL per DUT, as each DUT's fits judged it (rig/analysis/dutfits.py, acceptance.py): stored in
    the session, written as a CSV beside it, shown in the live view's summaries."""
    from rig.analysis import acceptance

    judged = {f["dut"]: f["verdict"] for f in fits if f.get("verdict") is not None}
    if all(dut.name in judged for dut in station.duts):
        verdicts = [judged[dut.name] for dut in station.duts]
    else:  # fits made without the recorded plan: judged from the session on disk
        verdicts = acceptance.judge_session(session.path, plan, station, fits)
    session.record_acceptance(acceptance.rows(verdicts))
    acceptance.write_summary_csv(acceptance.summary_csv_path(session.path), session.path.name, station.name,
                                 verdicts)
    for v in verdicts:
        session.log_event(Kind.ACCEPTANCE, v.line(), code=Reason.ACCEPTED if v.passed else Reason.REJECTED,
                          device=v.dut, level="INFO" if v.passed else "WARNING")
        live_summaries[v.dut] = f"{v.verdict} " + live_summaries.get(v.dut, "")
    return verdicts


def fit_session(session, plan: cfg.Plan, station: cfg.Station, progress=None, helper=None) -> list[dict]:
    """Fit each of the plan's models for each DUT from the session's own dataset, the way `rig refit` and
    `rig refit-all` fit it (rig/analysis/sessionfit.py); write one calibration file per DUT and model next
    to the session and record each fit in it; the DUTs' shared inputs in the cross-covariance file beside
    them (rig/analysis/crosscov.py). Where a DUT's T24 linearity in temperature fails, a T36 is fitted too
    (unless the plan fits it already) and both record the choice between them
    (rig/analysis/tempchoice.py). Many DUTs are fitted on two cores (rig/analysis/fithelper.py).
    `progress(dut, model, done, total)` is told as each DUT's fits begin; the session records it too
    (rig/analysis/fitprogress.py). `helper`: the fit helper started with the run, if any
    (fithelper.run_helper). The entries come in the station's DUT order."""
    from rig.analysis.crosscov import CrossCovariance
    from rig.analysis.fithelper import fitted_duts
    from rig.analysis.fitprogress import FitProgress

    models = tuple(plan.fit.models)
    duts = [dut.name for dut in station.duts]
    shared = CrossCovariance()
    tell = FitProgress(session, len(duts) * len(models), progress)

    def started(dut: str) -> None:
        for model in models:
            tell(dut, model)

    kept: dict[str, list[dict]] = {}
    for dut, fits in fitted_duts(session.path, models, bool(plan.fit.robust), duts, started, helper):
        kept[dut] = [_keep(session, fit, shared) for fit in fits]
    tell.finished(shared)
    return [entry for dut in duts for entry in kept[dut]]


def seal_sources(session_path, fits: list[dict]) -> None:
    """Once the run has closed its session (nothing more is written to it): the session's sha256 in every
    calibration file the run wrote (`source.sha256`, left empty by the fits, which ran while the session was
    still written), so that each file cites the file its `source.path` names as it stays. A file that cannot
    be rewritten, or a session whose log a reader kept from being folded in, keeps no hash and the reason is
    logged: never a wrong one."""
    import logging

    from calib.io import calfile
    from calib.io.digest import sha256_file
    from rig.core.errors import ERRORS
    from rig.session.reader import wal_bytes

    log = logging.getLogger("magrig.postrun")
    if wal_bytes(session_path):  # a reader kept the log from being folded in: the file is not the session
        log.warning("%s: still has a write-ahead log; its calibrations cite it without a hash", session_path)
        return
    digest = sha256_file(session_path)
    for entry in fits:
        cal, path = entry.get("calibration"), entry.get("path")
        if cal is None or path is None:
            continue
        cal.source["sha256"] = digest
        try:
            calfile.save(cal, path)
        except ERRORS as exc:
            log.warning("%s: source.sha256 not written: %s", path, exc)


def _keep(session, fit, shared) -> dict[str, Any]:
    """A fit's record in the session (its file is written already), or its failure logged."""
    entry: dict[str, Any] = {"dut": fit.dut, "model": fit.model, "verdict": fit.verdict}
    if fit.error is not None:
        entry["error"] = fit.error
        if fit.model != "-":
            session.log_event(Kind.FIT_FAILED, f"{fit.dut} {fit.model}: {fit.error}", code=Reason.FIT_FAILED,
                              level="WARNING", device=fit.dut, model=fit.model)
        return entry
    cal = fit.calibration
    shared.add(fit.dut, fit.model, fit.labels, fit.shared)
    rms = cal.stats.get("rms_after_nt")
    session.record_fit(fit.dut, fit.model, cal.to_dict(), residual_rms_nt=rms)
    entry.update(path=fit.path, rms_nt=rms, calibration=cal, n=fit.rows)
    return entry
