"""After a completed run: fit every model of the plan for every DUT from the session's own data, state
each calibration's uncertainty (rig/reference/budget.py), write the calibration files beside the session, and
judge
each DUT against the plan's acceptance limits."""

from __future__ import annotations

from typing import Any

import numpy as np

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
    """Fit each of the plan's models for each DUT from the session's own dataset; write one calibration
    file per DUT and model next to the session and record each fit in it; the DUTs' shared inputs in the
    cross-covariance file beside them (rig/analysis/crosscov.py). `progress(dut, model, done, total)` is
    told before each fit; the session records it too (rig/analysis/fitprogress.py)."""
    import calib
    from calib import calfile
    from rig.analysis.crosscov import CrossCovariance
    from rig.analysis.fitprogress import FitProgress
    from rig.core.paths import calibration_file
    from rig.session.reader import each_dataset

    out = []
    inputs = run_inputs(session.path)
    shared = CrossCovariance()
    tell = FitProgress(session, len(station.duts) * len(plan.fit.models), progress)
    for dut, ds in each_dataset(session.path, station.duts):
        if isinstance(ds, Exception):
            out.append({"dut": dut.name, "model": "-", "error": str(ds)})
            continue
        # every reference with the run's best ambient (rig/reference/ambient.py)
        ds, ambient = refined(inputs, ds)
        lag = None
        if plan.moving:  # a ramp shows each DUT's thermal lag: fit the element's temperature
            from rig.analysis.lagfit import lag_corrected

            ds, lag = lag_corrected(ds)
        for model in plan.fit.models:
            tell(dut.name, model)
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
                from rig.analysis.lagfit import annotate

                annotate(cal, lag)
            if model == "t24":  # the model check the plan's interior temperatures are for
                check_linearity(cal, ds)
                record_checks(inputs, dut.name, ds, cal)
            if ambient is not None:
                cal.stats["ambient"] = ambient
            shared.add(dut.name, model, state_uncertainty(inputs, dut.name, ds, cal))
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
    tell.finished(shared)
    return out


def run_inputs(session_path):
    """What the session says of its reference chain (rig/reference/budget.py), read once for its DUTs; None
    when its
    recorded plan or station can no longer be read (a session of an older format, a foreign one)."""
    from rig.core.errors import ConfigError
    from rig.reference.budget import RunInputs
    from rig.session.reader import SessionReader

    with SessionReader(session_path) as reader:
        try:
            return RunInputs.of_session(reader)
        except ConfigError:
            return None


def refined(inputs, ds):
    """(ds, ambient info): the references made with the run's best ambient, where the session allows."""
    return (ds, None) if inputs is None else inputs.refined(ds)


def state_uncertainty(inputs, dut: str, ds, cal):
    """The calibration's uncertainty budget (without a reference chain: the fit's statistical part); a
    budget that cannot be made is a warning in its stats, never a lost calibration. Returns the calib
    Budget (None without one)."""
    from calib.uncertainty import statistical_only
    from rig.reference.budget import uncertainty_section

    try:
        if inputs is None:
            cal.uncertainty = statistical_only(ds, cal)
            cal.uncertainty["notes"] = ["the session's recorded plan or station cannot be read: the "
                                        "reference's own uncertainty is not in this budget"]
            return None
        budget = inputs.budget(dut, ds, cal)
        cal.uncertainty = uncertainty_section(budget)
        return budget
    except (*ERRORS, ValueError, ArithmeticError, IndexError, np.linalg.LinAlgError) as exc:
        cal.stats["warnings"] = [*cal.stats.get("warnings", []), f"no uncertainty budget: {exc}"]
        return None


def record_checks(inputs, dut: str, ds, cal) -> None:
    """T24's model checks (calib/checks.py) in the calibration's stats, the thermal direction of every
    sample from the run's temperature history (rig/reference/modelerror.py)."""
    from rig.reference.modelerror import record_model_checks, thermal_direction

    direction = thermal_direction(ds.columns["t"], ds.temp_c) if inputs is None else \
        inputs.thermal_direction(dut, ds)
    record_model_checks(cal, ds, direction)


def check_linearity(cal, ds) -> None:
    """T24's linearity in temperature (calib/linearity.py) in the calibration's stats; a warning when it
    does not hold."""
    from calib.linearity import linearity

    check = linearity(ds.h_nt, ds.temp_c, ds.ref_nt)
    cal.stats["linearity"] = check
    if check["holds"] is False:
        cal.stats["warnings"] = [*cal.stats.get("warnings", []), check["message"]]
