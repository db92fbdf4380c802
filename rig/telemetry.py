"""The temperatures the cockpit plots against time: the chamber's set point, its air and each DUT's
temperature, stored in the session (table `temperatures`) while the campaign watches the chamber.

    log = TemperatureLog(session)           # rig/campaign.py, one per run
    log.note(chamber_reading, dut_temps_c)  # at every chamber check; stores at most one row per EVERY_S

Between points the run can wait for hours (ramps, stability): without these rows the plot would stay
empty all that time. One small transaction per EVERY_S of the run's clock costs the run nothing it
would notice; a row that cannot be written is left out (said once), never the end of the run.
"""

from __future__ import annotations

import logging
import sqlite3

from rig.errors import SessionError

log = logging.getLogger("magrig.telemetry")

EVERY_S = 30.0  # on the run's clock


class TemperatureLog:
    def __init__(self, session, every_s: float = EVERY_S):
        self.session = session
        self.every_s = every_s
        self.last_t: float | None = None
        self.lost = 0

    def note(self, reading, dut_temps_c: dict[str, float | None]) -> None:
        """A chamber reading (drivers.chamber.ChamberReading) and the DUT temperatures last read."""
        if self.last_t is not None and reading.t - self.last_t < self.every_s:
            return
        self.last_t = reading.t
        try:
            self.session.record_temperatures(reading.t, reading.setpoint_c, reading.closed_loop_c,
                                             reading.air_c, dict(dut_temps_c))
        except (SessionError, sqlite3.Error) as exc:
            self.lost += 1
            if self.lost == 1:
                log.warning("could not record temperatures for the cockpit: %s", exc)
