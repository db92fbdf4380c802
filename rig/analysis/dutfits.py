"""The post-run fits of one DUT (many DUTs on two cores: rig/analysis/fithelper.py).

    with SessionFits(session_path, models, robust) as fits:
        results = fits.fit("dut1")                  # [DutFit per model], its calibration files written

A DUT's fits read nothing but the session (its recorded plan and station, its samples), so they can run
in another process. They run while the run still writes the session, so their files cite it without a
hash; the run gives them the session's once it has closed it (rig/analysis/postrun.py seal_sources). A
DutFit is plain data, the same from either process: the calibration, its file, and what the
cross-covariance needs of its budget (rig/analysis/crosscov.py).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rig import __version__
from rig.core.errors import ERRORS


@dataclass
class DutFit:
    """One model fitted to one DUT: its calibration (None when the fit failed: `error` says why), the
    file written, its budget's shared inputs [(name, covariance, jacobian)] with the parameter labels, and
    the process that fitted it."""

    dut: str
    model: str
    calibration: Any = None
    error: str | None = None
    path: Path | None = None
    rows: int = 0
    labels: list[str] = field(default_factory=list)
    shared: list[tuple[str, Any, Any]] = field(default_factory=list)
    pid: int = field(default_factory=os.getpid)
    verdict: Any = None  # rig.analysis.acceptance.Verdict of the DUT (on each of its fits), or None


class SessionFits:
    """What one process needs to fit a session's DUTs: the session open, its fitter built once."""

    def __init__(self, session_path: str | Path, models: tuple[str, ...], robust: bool):
        from rig.analysis.sessionfit import SessionFitter
        from rig.session.reader import SessionReader

        self.session_path, self.models, self.robust = Path(session_path), tuple(models), robust
        self.reader = SessionReader(self.session_path)
        try:
            self.fitter = SessionFitter.of(self.reader)
        except BaseException:
            self.reader.close()
            raise

    def close(self) -> None:
        self.reader.close()

    def __enter__(self) -> SessionFits:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def fit(self, dut: str) -> list[DutFit]:
        """Every model of the plan for `dut`, and where its T24 linearity in temperature fails a T36 too
        (rig/analysis/tempchoice.py); each calibration's file written beside the session."""
        from rig.analysis.tempchoice import share_choice, wants_t36

        try:
            ds = self.reader.dataset(dut)
        except ERRORS as exc:
            return [DutFit(dut, "-", error=str(exc), verdict=self._failed_verdict(dut, str(exc)))]
        ds.source["sha256"] = None  # the run still writes the session: its hash once closed (seal_sources)
        prepared = self.fitter.prepare(ds)
        fitted: dict[str, Any] = {}
        for model in self.models:
            fitted[model] = self._calibrate(prepared, model)
        t24 = fitted.get("t24")
        if isinstance(t24, tuple) and wants_t36(t24[0]):
            if "t36" not in fitted:
                fitted["t36"] = self._calibrate(prepared, "t36")
            if isinstance(fitted["t36"], tuple):
                share_choice(t24[0], fitted["t36"][0])
        written = [self._written(dut, model, result, len(prepared.ds)) for model, result in fitted.items()]
        verdict = self._verdict(dut, prepared, written)
        for fit in written:
            fit.verdict = verdict
        return written

    def _verdict(self, dut: str, prepared, written: list[DutFit]):
        """The DUT judged on the plan's acceptance limits, None where the plan has none."""
        plan = self.fitter.plan
        if plan is None or plan.acceptance is None:
            return None
        from rig.analysis.acceptance import judge_dut

        fitted = {f.model: f.calibration for f in written if f.calibration is not None}
        errors = {f.model: f.error for f in written if f.error is not None}
        return judge_dut(plan, dut, self._dut_type(dut), prepared.ds, fitted, errors, prepared.lag)

    def _failed_verdict(self, dut: str, why: str):
        """A DUT whose data cannot be read fails, where the plan has acceptance limits."""
        plan = self.fitter.plan
        if plan is None or plan.acceptance is None:
            return None
        from rig.analysis.acceptance import judge_dut

        return judge_dut(plan, dut, self._dut_type(dut), None, {}, {m: why for m in self.models})

    def _dut_type(self, dut: str) -> str:
        station = self.fitter.inputs.station
        return next((d.device_type for d in station.duts if d.name == dut), "")

    def _calibrate(self, prepared, model: str):
        try:
            return self.fitter.calibrate_budgeted(prepared, model, robust=self.robust,
                                                  software_version=__version__)
        except ERRORS as exc:
            return exc

    def _written(self, dut: str, model: str, result, rows: int) -> DutFit:
        from calib.io import calfile
        from rig.core.paths import calibration_file

        if isinstance(result, Exception):
            return DutFit(dut, model, error=str(result))
        cal, budget = result
        try:
            path = calibration_file(self.session_path, dut, model)
            calfile.save(cal, path)
        except ERRORS as exc:
            return DutFit(dut, model, error=str(exc))
        labels, shared = shared_inputs(budget)
        return DutFit(dut, model, calibration=cal, path=path, rows=rows, labels=labels, shared=shared)


def shared_inputs(budget) -> tuple[list[str], list[tuple[str, Any, Any]]]:
    """(parameter labels, [(shared input's name, its covariance, the parameters' jacobian to it)]) of a
    calib Budget's linear part; nothing without one."""
    linear = getattr(budget, "linear", None)
    if linear is None:
        return [], []
    return list(budget.parameter_labels), [(c.source.shared, c.source.covariance, c.jacobian)
                                           for c in linear.contributions
                                           if c.source is not None and c.source.shared]
