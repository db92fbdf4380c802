"""The one way a session's DUT is calibrated: the post-run fit (rig/analysis/postrun.py), `rig refit
SESSION`, `rig refit-all` (rig/fleet/refit.py) and the report's data all go through here, so they give
the same calibration from the same session.

    fitter = SessionFitter.of(reader)                # what the session says of its reference chain and plan
    prepared = fitter.prepare(ds)                    # references with the run's best ambient; lag-corrected
    cal = fitter.calibrate(prepared, "t24", robust=None, software_version=__version__)

`reader` is a rig.session.reader.SessionReader, or anything with its `path`, `info()`, `points()`,
`events()`, `snapshot(name)` and `point_references()` (the fleet's copies of a session's tables:
rig/fleet/refit.py). Options left as None are the session's recorded plan's (robust).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rig.core.errors import ERRORS, ConfigError


@dataclass
class Prepared:
    """One DUT's data as every fit of the session sees it, and what was done to it."""

    ds: Any  # calib.dataset.Dataset
    ambient: dict | None = None  # the run's ambient model the references were remade with
    lag: dict | None = None  # the thermal lag estimate: applied on a moving schedule, else judged only
    checks: list | None = None  # T24's model checks of the readings as taken (before a correction)


@dataclass
class SessionFitter:
    inputs: Any  # rig.budget.run_inputs.RunInputs, or None when the recorded plan or station cannot be read
    measurand: Any = None  # rig.analysis.measurand.SessionMeasurand: what every calibration states of it

    @classmethod
    def of(cls, reader) -> SessionFitter:
        from rig.analysis.measurand import SessionMeasurand
        from rig.budget.run_inputs import RunInputs

        try:
            inputs = RunInputs.of_session(reader)
        except ConfigError:
            inputs = None
        return cls(inputs, SessionMeasurand.of(reader, None if inputs is None else inputs.station))

    @property
    def plan(self):
        return None if self.inputs is None else self.inputs.plan

    @property
    def moving(self) -> bool:
        """The plan sampled while the temperature moved: each DUT's thermal lag is estimated and applied."""
        return self.plan is not None and self.plan.moving

    def prepare(self, ds, *, lag: bool = True) -> Prepared:
        """The references made with the run's best ambient (rig/reference/ambient.py) where the session
        allows, on a moving schedule the element's temperature (rig/analysis/lagfit.py), and the readings
        taken to the DUT's mean thermal state where T24's checks find a thermal hysteresis
        (rig/budget/hysteresis.py)."""
        from rig.budget.hysteresis import corrected

        ambient = None
        if self.inputs is not None:
            ds, ambient = self.inputs.refined(ds)
        info = None
        if lag and self.moving:
            from rig.analysis.lagfit import lag_corrected

            ds, info = lag_corrected(ds)
        elif lag and self.judges_lag:  # taken with the DUTs stable: the lag is judged, not applied
            from rig.analysis.lagfit import lag_estimated

            info = lag_estimated(ds)
        ds, checks = corrected(ds, self.thermal_direction(ds))
        return Prepared(ds, ambient, info, checks)

    @property
    def judges_lag(self) -> bool:
        """The plan's acceptance judges each DUT's thermal lag (acceptance.max_lag_s)."""
        acceptance = None if self.plan is None else self.plan.acceptance
        return acceptance is not None and acceptance.max_lag_s is not None

    def thermal_direction(self, ds):
        """+1 heating, -1 cooling, 0 unknown for every sample: from the run's temperature log where the
        session has one (rig/budget/modelerror.py); None without sample times."""
        from rig.budget.modelerror import thermal_direction

        if self.inputs is not None:
            return self.inputs.thermal_direction(ds.source.get("dut", ""), ds)
        if ds.columns.get("t") is None or ds.temp_c is None:
            return None
        return thermal_direction(ds.columns["t"], ds.temp_c)

    def robust(self, robust: bool | None) -> bool:
        return robust if robust is not None else bool(self.plan is not None and self.plan.fit.robust)

    def calibrate(self, prepared: Prepared, model: str, *, robust: bool | None = None,
                  software_version: str = "unknown", budget: bool = True, **fit_options):
        """calib.fit with the session's options, then what every session calibration carries: its measurand
        (rig/analysis/measurand.py), the lag estimate, T24's model checks (and, where its linearity in
        temperature fails, the choice of T24 or T36: rig/analysis/tempchoice.py), the ambient used and (with
        `budget`) the uncertainty budget."""
        return self.calibrate_budgeted(prepared, model, robust=robust, software_version=software_version,
                                       budget=budget, **fit_options)[0]

    def calibrate_budgeted(self, prepared: Prepared, model: str, *, robust: bool | None = None,
                           software_version: str = "unknown", budget: bool = True, **fit_options):
        """(calibration, its calib Budget or None): `calibrate`, and the budget itself for what the DUTs
        share (rig/analysis/crosscov.py)."""
        import calib
        from rig.budget.modelerror import record_model_checks

        ds = prepared.ds
        cal = calib.fit(ds, model, robust=self.robust(robust), software_version=software_version,
                        **fit_options)
        if self.measurand is not None:
            self.measurand.state(cal, ds.source.get("dut", ""), prepared.lag)
        if prepared.lag is not None:
            from rig.analysis.lagfit import annotate

            annotate(cal, prepared.lag)
        if model == "t24":  # the model checks the plan's interior temperatures and two magnitudes are for
            from rig.analysis.tempchoice import record_temperature_model

            check_linearity(cal, ds)
            if prepared.checks is not None:  # the DUT as it was measured, before a hysteresis correction
                cal.stats["model_checks"] = prepared.checks
            else:
                record_model_checks(cal, ds, self.thermal_direction(ds))
            record_temperature_model(cal, ds)  # where its linearity in temperature fails: T24 or T36
        if prepared.ambient is not None:
            cal.stats["ambient"] = prepared.ambient
        stated = state_uncertainty(self.inputs, ds.source.get("dut", ""), ds, cal) if budget else None
        return cal, stated


def state_uncertainty(inputs, dut: str, ds, cal):
    """The calibration's uncertainty budget (without a reference chain: the fit's statistical part); a
    budget that cannot be made is a warning in its stats, never a lost calibration. Returns the calib
    Budget (None without one)."""
    from calib.uncertainty.montecarlo import statistical_only
    from rig.budget.run_inputs import uncertainty_section

    try:
        if inputs is None:
            cal.uncertainty = statistical_only(ds, cal)
            cal.uncertainty["notes"] = ["the session's recorded plan or station cannot be read: the "
                                        "reference's own uncertainty is not in this budget"]
            return None
        stated = inputs.budget(dut, ds, cal)
        cal.uncertainty = uncertainty_section(stated, cal)
        return stated
    except (*ERRORS, ValueError, ArithmeticError, IndexError, np.linalg.LinAlgError) as exc:
        cal.stats["warnings"] = [*cal.stats.get("warnings", []), f"no uncertainty budget: {exc}"]
        return None


def check_linearity(cal, ds) -> None:
    """T24's linearity in temperature (calib/checks/linearity.py) in the calibration's stats; a warning when
    it does not hold."""
    from calib.checks.linearity import linearity

    check = linearity(ds.h_nt, ds.temp_c, ds.ref_nt)
    cal.stats["linearity"] = check
    if check["holds"] is False:
        cal.stats["warnings"] = [*cal.stats.get("warnings", []), check["message"]]
