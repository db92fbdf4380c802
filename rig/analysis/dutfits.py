"""The post-run fits of one DUT, and of many DUTs on two cores.

    with SessionFits(session_path, models, robust) as fits:
        results = fits.fit("dut1")                  # [DutFit per model], its calibration files written
    for dut, results in fitted_duts(session_path, models, robust, duts, started):
        ...                                          # as each DUT's fits end (any order)

A DUT's fits read nothing but the session (its recorded plan and station, its samples), so they can run
in another process. With HELPER_MIN_FITS fits or more and two cores, a helper process (spawned: the
rig's process has hardware threads, which a fork would copy mid-flight) takes DUTs from the end of the
list while this process fits them from the front; they meet in the middle. Whatever the helper cannot do
(it failed to start, or died) is fitted here. A DutFit is plain data, the same from either process: the
calibration, its file, and what the cross-covariance needs of its budget (rig/analysis/crosscov.py).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from rig import __version__
from rig.core.errors import ERRORS

HELPER_MIN_FITS = 16  # below this a helper's start-up (about a second) costs more than it saves
IN_FLIGHT = 2  # DUTs handed to the helper at a time: it never idles, and never holds many


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
            return [DutFit(dut, "-", error=str(exc))]
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
        return [self._written(dut, model, result, len(prepared.ds)) for model, result in fitted.items()]

    def _calibrate(self, prepared, model: str):
        try:
            return self.fitter.calibrate_budgeted(prepared, model, robust=self.robust,
                                                  software_version=__version__)
        except ERRORS as exc:
            return exc

    def _written(self, dut: str, model: str, result, rows: int) -> DutFit:
        from calib import calfile
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


# --- many DUTs ----------------------------------------------------------------------------------------
_HELPER: SessionFits | None = None


def _start_helper(session_path: str, models: tuple[str, ...], robust: bool) -> None:
    global _HELPER
    _HELPER = SessionFits(session_path, models, robust)


def _helper_fit(dut: str) -> list[DutFit]:
    assert _HELPER is not None, "the helper process was not started with the session"
    return _HELPER.fit(dut)


def fitted_duts(session_path: str | Path, models: tuple[str, ...], robust: bool, duts: list[str],
                started: Callable[[str], None]) -> Iterator[tuple[str, list[DutFit]]]:
    """(dut, its fits) for every DUT as they end; `started(dut)` is told as each DUT's fits begin."""
    with SessionFits(session_path, models, robust) as here:
        helper = _helper(session_path, models, robust, len(duts) * len(models))
        if helper is None:
            for dut in duts:
                started(dut)
                yield dut, here.fit(dut)
            return
        with helper:
            yield from _shared_out(here, helper, list(duts), started)


def _helper(session_path, models, robust, fits: int) -> ProcessPoolExecutor | None:
    if fits < HELPER_MIN_FITS or (os.cpu_count() or 1) < 2 or os.environ.get("MAGRIG_POSTRUN_HELPER") == "0":
        return None
    try:
        return ProcessPoolExecutor(1, mp_context=get_context("spawn"), initializer=_start_helper,
                                   initargs=(str(session_path), tuple(models), robust))
    except OSError:  # no process to be had: every fit here
        return None


def _shared_out(here: SessionFits, helper: ProcessPoolExecutor, duts: list[str],
                started: Callable[[str], None]) -> Iterator[tuple[str, list[DutFit]]]:
    """This process fits from the front, the helper from the back; a DUT the helper fails is fitted here."""
    inflight: dict[Future, str] = {}
    helper_ok = True
    while duts or inflight:
        while helper_ok and len(inflight) < IN_FLIGHT and len(duts) > 1:
            dut = duts.pop()
            started(dut)
            try:
                inflight[helper.submit(_helper_fit, dut)] = dut
            except RuntimeError:  # the pool broke before this submit
                helper_ok = False
                duts.append(dut)
        if duts:
            dut = duts.pop(0)
            started(dut)
            yield dut, here.fit(dut)
        elif inflight:
            wait(inflight, return_when=FIRST_COMPLETED)
        for future in [f for f in inflight if f.done()]:
            dut = inflight.pop(future)
            try:
                yield dut, future.result()
            except Exception:  # noqa: BLE001 - the helper died or failed: this DUT is fitted here instead
                helper_ok = False
                yield dut, here.fit(dut)
