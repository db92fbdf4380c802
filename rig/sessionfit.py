"""After a completed run: fit every model of the plan for every DUT from the session's own data, write
the calibration files beside the session, and judge each DUT against the plan's acceptance limits."""

from __future__ import annotations

from typing import Any

from rig import __version__
from rig import config as cfg
from rig.errors import ERRORS
from rig.events import Kind, Reason


def accept_session(session, plan: cfg.Plan, station: cfg.Station, fits: list[dict],
                   live_summaries: dict[str, str]) -> list:
    """PASS/FAIL per DUT (rig/acceptance.py): stored in the session, written as a CSV beside it, shown in
    the live view's summaries."""
    from rig import acceptance

    verdicts = acceptance.judge_session(session.path, plan, station, fits)
    session.record_acceptance(acceptance.rows(verdicts))
    acceptance.write_summary_csv(acceptance.summary_csv_path(session.path), session.path.name, station.name,
                                 verdicts)
    for v in verdicts:
        session.log_event(Kind.ACCEPTANCE, v.line(), code=Reason.ACCEPTED if v.passed else Reason.REJECTED,
                          device=v.dut, level="INFO" if v.passed else "WARNING")
        live_summaries[v.dut] = f"{v.verdict} " + live_summaries.get(v.dut, "")
    return verdicts


def fit_session(session, plan: cfg.Plan, station: cfg.Station) -> list[dict]:
    """Fit each of the plan's models for each DUT from the session's own dataset; write one calibration
    file per DUT and model next to the session and record each fit in it."""
    import calib
    from calib import calfile
    from rig.outputs import calibration_file
    from rig.reader import read_dataset

    out = []
    for dut in station.duts:
        try:
            ds = read_dataset(session.path, dut.name)
        except ERRORS as exc:
            out.append({"dut": dut.name, "model": "-", "error": str(exc)})
            continue
        lag = None
        if plan.moving:  # a ramp shows each DUT's thermal lag: fit the element's temperature
            from rig.lagfit import lag_corrected

            ds, lag = lag_corrected(ds)
        for model in plan.fit.models:
            entry: dict[str, Any] = {"dut": dut.name, "model": model}
            try:
                cal = calib.fit(ds, model, robust=plan.fit.robust, software_version=__version__)
            except ERRORS as exc:
                entry["error"] = str(exc)
                session.log_event(Kind.FIT_FAILED, f"{dut.name} {model}: {exc}", code=Reason.FIT_FAILED,
                                  level="WARNING", device=dut.name, model=model)
                out.append(entry)
                continue
            if lag is not None:
                from rig.lagfit import annotate

                annotate(cal, lag)
            if model == "t24":  # the model check the plan's interior temperatures are for
                check_linearity(cal, ds)
            try:
                path = calibration_file(session.path, dut.name, model)
            except ERRORS as exc:
                entry["error"] = str(exc)
                out.append(entry)
                continue
            calfile.save(cal, path)
            rms = cal.stats.get("rms_after_nt")
            session.record_fit(dut.name, model, cal.to_dict(), residual_rms_nt=rms)
            entry.update(path=path, rms_nt=rms, calibration=cal, n=len(ds))
            out.append(entry)
    return out


def check_linearity(cal, ds) -> None:
    """T24's linearity in temperature (calib/linearity.py) in the calibration's stats; a warning when it
    does not hold."""
    from calib.linearity import linearity

    check = linearity(ds.h_nt, ds.temp_c, ds.ref_nt)
    cal.stats["linearity"] = check
    if check["holds"] is False:
        cal.stats["warnings"] = [*cal.stats.get("warnings", []), check["message"]]
