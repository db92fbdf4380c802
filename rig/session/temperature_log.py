"""The temperatures the cockpit plots against time: the chamber's set point, its air and each DUT's
temperature, stored in the session (table `temperatures`) while the campaign watches the chamber.

    log = TemperatureLog(session)           # rig/run/campaign.py, one per run
    log.note(chamber_reading, dut_temps_c)  # at every chamber check: a row per EVERY_S of the run's clock
    session.record_point(..., temperatures=log.take())   # the rows noted meanwhile ride along

Between points the run can wait for hours (ramps, stability): the rows noted meanwhile are written on
their own once the oldest has waited FLUSH_S, so the plot moves during a wait too. Each commit costs the
session's log a page and a sync, so rows are written in batches, and with a point whenever one is stored.
A batch that cannot be written is dropped (said once), never the end of the run.
"""

from __future__ import annotations

import logging
import sqlite3

from rig.core.errors import SessionError
from rig.session.rows import TemperatureRow

log = logging.getLogger("magrig.telemetry")

EVERY_S = 30.0  # a row per this much of the run's clock
FLUSH_S = 120.0  # rows wait at most this long (run's clock) for a point to carry them


class TemperatureLog:
    def __init__(self, session, every_s: float = EVERY_S, flush_s: float = FLUSH_S):
        self.session = session
        self.every_s = every_s
        self.flush_s = flush_s
        self.last_t: float | None = None
        self.pending: list[TemperatureRow] = []
        self.lost = 0

    def note(self, reading, dut_temps_c: dict[str, float | None]) -> None:
        """A chamber reading (drivers.chamber.ChamberReading) and the DUT temperatures last read."""
        if self.last_t is None or reading.t - self.last_t >= self.every_s:
            self.last_t = reading.t
            self.pending.append(TemperatureRow(reading.t, reading.setpoint_c, reading.closed_loop_c,
                                               reading.air_c, dict(dut_temps_c)))
        if self.pending and reading.t - self.pending[0].t >= self.flush_s:
            self.flush()

    def take(self) -> list[TemperatureRow]:
        """The rows not written yet, for the next point's transaction."""
        rows, self.pending = self.pending, []
        return rows

    def flush(self) -> None:
        rows = self.take()
        try:
            self.session.record_temperatures(rows)
        except (SessionError, sqlite3.Error) as exc:
            self.lost += len(rows)
            if self.lost == len(rows):
                log.warning("could not record temperatures for the cockpit: %s", exc)
