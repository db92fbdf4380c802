"""The post-run fits' progress, never silent: which DUT and which model is being fitted, told to the
terminal (a callback of rig/run/display.py) for every fit and recorded in the session as events
(Kind.POSTRUN) for the cockpit, at most one every RECORD_EVERY_S of wall time so that 64 DUTs x 3 models
do not cost 192 transactions; the first and the last are always recorded."""

from __future__ import annotations

import time

from rig.core.errors import ERRORS
from rig.session.events import Kind, Reason

RECORD_EVERY_S = 1.0


class FitProgress:
    def __init__(self, session, total: int, progress=None, clock=time.monotonic):
        self.session, self.total, self.progress, self.clock = session, total, progress, clock
        self.done = 0
        self.last_recorded: float | None = None
        self.started = clock()

    def __call__(self, dut: str, model: str) -> None:
        """Before fitting `model` to `dut`."""
        if self.progress is not None:
            self.progress(dut, model, self.done, self.total)
        now = self.clock()
        if self.last_recorded is None or now - self.last_recorded >= RECORD_EVERY_S:
            self.last_recorded = now
            self.session.log_event(Kind.POSTRUN, f"post-run fits: {dut} {model} ({self.done + 1} of "
                                   f"{self.total})", code=Reason.FITTING, device=dut, model=model,
                                   done=self.done, total=self.total)
        self.done += 1

    def finished(self, shared) -> None:
        """After the last fit: the cross-covariance file written (rig/analysis/crosscov.py), and said."""
        try:
            path = shared.write(self.session.path)
        except ERRORS as exc:
            self.session.log_event(Kind.WARNING, f"post-run fits: {exc}", code=Reason.LOGGED, level="WARNING")
            path = None
        wall = self.clock() - self.started
        where = "" if path is None else f"; the DUTs' shared inputs in {path.name}"
        self.session.log_event(Kind.POSTRUN, f"post-run fits done: {self.total} in {wall:.1f} s{where}",
                               code=Reason.FITTING, done=self.total, total=self.total)
        if self.progress is not None:
            self.progress(None, None, self.total, self.total)
