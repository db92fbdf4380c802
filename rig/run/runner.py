"""The campaign runner: the handlers the engine calls for each command a schedule's tasks yield
(rig/engine/commands.py; the tasks: rig/schedules/tasks.py). StartRamp and AwaitAir are rig/run/ramping.py's.

A point's samples: `samples` readings from every DUT with each DUT's temperature and the reference field
of that very sample, stored in one transaction with the stability statistics of the wait before it and
whatever a schedule decided from its rows.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from rig import config as cfg
from rig.analysis.livefit import LiveFit, LiveSummaries
from rig.core.errors import ERRORS
from rig.core.points import Point
from rig.devices.build import Rig
from rig.devices.interleave import read_all
from rig.engine.commands import (
    Checkpoint,
    Collected,
    CollectPoint,
    Hold,
    MoveField,
    ReadTargets,
    RunView,
    SetChamber,
    Settle,
    WaitStable,
)
from rig.engine.executor import Engine, RunStatus
from rig.engine.frozen import FrozenReadings
from rig.engine.stability import OFFSET, STABLE, TIMEOUT, StabilityCriteria, StabilityDetector
from rig.fieldsources.fieldmaths import reference_for
from rig.run.ramping import RampHandlers
from rig.session.events import Kind, Reason
from rig.session.rows import SampleRow
from rig.session.temperature_log import TemperatureLog

log = logging.getLogger("magrig.campaign")


def poll_interval_s(criteria: StabilityCriteria) -> float:
    """Temperature poll while waiting for stability: 4 samples per dwell window (5 span it, 12 the three
    dwells the detector's asymptote compares), between 2 and 60 s. The temperatures it judges move on the
    scale of minutes (DUT lags behind the air of 5-15 min, dwells of 2-5 min), so more samples add no
    information, only bus traffic (64 probes a poll on a big station) and a detector fed twice as often;
    a stable DUT is seen at most one interval after it is."""
    return min(60.0, max(2.0, criteria.dwell_s / 4.0))


class CampaignRunner:
    def __init__(self, rig: Rig, plan: cfg.Plan, points: list[Point], session,
                 status: RunStatus | None = None):
        self.rig = rig
        self.plan = plan
        self.points = points
        self.session = session
        self.status = status or RunStatus()
        self.engine: Engine | None = None
        self.source = rig.station.field_source  # the field source's config: how to drive and read it
        # a measured ambient / site field: the reference is made once it is measured (measure_site_field)
        self.reference = None if self.source.needs_measurement() else reference_for(rig.station)
        self.site = None  # rig.reference.sitefield.SiteFieldMonitor when the field source needs a measurement
        self.settled_c: dict[str, float] = {}  # where each DUT settled there (its place may be off the air)
        temps = [p.setpoint_c for p in points] or [25.0]
        self.live = {name: LiveFit(float(np.mean(temps))) for name in rig.duts}
        self.live_summaries = LiveSummaries(self.live)  # each solved when read (the live view), not per point
        self.on_point: list = []  # callbacks(point_id) after each stored point (the display)
        self.frozen = FrozenReadings()  # a stuck temperature sensor must not pass for a stable DUT
        self.temperatures = TemperatureLog(session)  # what the cockpit plots between points
        self.ramping = RampHandlers(self)

    # --- handlers ---------------------------------------------------------------------------------
    def handlers(self) -> dict:
        return {SetChamber: self.set_chamber, WaitStable: self.wait_stable, MoveField: self.move_field,
                Settle: self.settle, CollectPoint: self.collect_point, Checkpoint: self.checkpoint,
                ReadTargets: self.read_targets, **self.ramping.handlers()}

    def set_chamber(self, cmd: SetChamber) -> None:
        chamber = self.rig.chamber
        if cmd.ramp_c_per_min is not None and getattr(chamber, "ramps_setpoint", False):
            chamber.set_ramp_rate(cmd.ramp_c_per_min)
        chamber.set(cmd.temp_c)
        self.status.thermal = f"chamber -> {cmd.temp_c:g} degC"

    def check_chamber(self):
        """The chamber's reading, noted for the live view and the cockpit; Hold on an alarm, a sensor
        fault or a chamber off its course."""
        reading = self.rig.chamber.read()
        self.status.chamber_c = reading.air_c
        self.temperatures.note(reading, self.status.dut_temps_c)
        if reading.fault:
            code = (Reason.CHAMBER_ALARM if reading.alarm else
                    Reason.CHAMBER_SENSOR if reading.input_error else Reason.CHAMBER_OFF_COURSE)
            raise Hold(f"chamber {reading.problem}", code=code, device=self.rig.chamber.name)
        return reading

    def _dut_temps(self) -> dict[str, float | None]:
        """Each DUT's temperature from its temp source: every source read once, their conversions
        overlapped (devices/interleave.py) as a sample's are, not one after the other."""
        sources = {source.name: source for source in self.rig.temp_sources.values()}
        got = read_all(sources, self.rig.clock)
        return {dut: got[source.name].temp_c for dut, source in self.rig.temp_sources.items()}

    def wait_stable(self, cmd: WaitStable) -> dict:
        """Poll the DUT temperatures until all are stable; Hold on alarm or at the hard maximum wait."""
        clock = self.rig.clock
        detectors = {dut: StabilityDetector(cmd.target_c, cmd.criteria) for dut in self.rig.duts}
        poll_s = poll_interval_s(cmd.criteria)
        start = clock.now()
        while True:
            self.check_chamber()
            temps = self._dut_temps()
            t = clock.now()
            for dut, temp_c in temps.items():
                if temp_c is None:
                    raise Hold(f"{dut}: its temperature source gives no temperature",
                               code=Reason.NO_TEMPERATURE, device=dut)
                detectors[dut].add(t, temp_c)
            self._check_frozen(t, temps)
            self.status.dut_temps_c = dict(temps)
            states = {dut: d.state for dut, d in detectors.items()}
            self.status.thermal = ", ".join(
                f"{dut} {d.state} ({d.last_temp_c:.2f} C, {d.rate_c_per_min:+.2f} C/min, "
                f"in band {d.in_band_s:.0f} s)" for dut, d in detectors.items())
            if all(s == STABLE for s in states.values()):
                waited = t - start
                self.settled_c = {dut: d.level_c for dut, d in detectors.items()}
                self.engine.event(Kind.STABLE, f"stable at {cmd.target_c:g} degC after {waited:.0f} s",
                                  code=Reason.STABLE, temps=temps, settled_c=self.settled_c)
                if self.site is not None:  # the step's first point: ambient re-checked, Hold on drift
                    self.site.recheck(self.engine.event, cmd.target_c)
                    self.reference = reference_for(self.rig.station, self.site.in_use.vector_nt)
                return {"target_c": cmd.target_c, "waited_s": waited,
                        "duts": {dut: {"temp_c": d.last_temp_c, "rate_c_per_min": d.rate_c_per_min,
                                       "in_band_s": d.in_band_s, "settled_c": d.level_c,
                                       "offset_c": d.offset_c} for dut, d in detectors.items()}}
            off = {dut: d for dut, d in detectors.items() if d.state == OFFSET}
            if off:
                where = "; ".join(f"{dut} settled at {d.level_c:.2f} degC, {d.offset_c:+.2f} degC from "
                                  f"the set point {cmd.target_c:g}" for dut, d in off.items())
                limit = cmd.criteria.max_offset_c
                raise Hold(f"{where}: more than stability.max_offset_c {limit:g} (its place in the chamber "
                           "or its sensor)", code=Reason.TEMP_OUT_OF_BAND, device=", ".join(off))
            late = [dut for dut, s in states.items() if s == TIMEOUT]
            if late:
                raise Hold(f"{', '.join(late)} not stable at {cmd.target_c:g} degC within "
                           f"max_wait_s {cmd.criteria.max_wait_s:g} s", code=Reason.STABILITY_TIMEOUT,
                           device=", ".join(late))
            self.engine.wait(poll_s, poll_s)

    def _check_frozen(self, t: float, temps: dict[str, float | None]) -> None:
        """Hold when a DUT's temperature source shows the very same value while the air moves."""
        for dut, temp_c in temps.items():
            source = self.rig.temp_sources[dut].name
            if temp_c is not None and (problem := self.frozen.add(source, t, temp_c, self.status.chamber_c)):
                raise Hold(problem, code=Reason.DEVICE_FAULT, device=source)

    def move_field(self, cmd: MoveField) -> None:
        self.rig.field_source.set(self.reference.command(cmd.target))

    def settle(self, cmd: Settle) -> None:
        self.rig.field_source.wait_settled(self.source.settle_timeout_s())
        self.engine.wait(cmd.seconds, max(cmd.seconds, 1e-3))

    def _reference_now(self) -> dict[str, tuple[float, ...]]:
        """{DUT: the reference field where it sits}, from what the field source reports now (readback
        currents / angles)."""
        setting = self.reference.readback(self.rig.field_source.read())
        return self.reference.fields_nt(setting, self.rig.duts)

    def collect_point(self, cmd: CollectPoint) -> Collected:
        point: Point = cmd.point
        started = self.rig.clock.now()
        self.check_chamber()
        rows: list[SampleRow] = []
        beside = {s.beside: s.name for s in self.rig.station.temperature_sensors}
        together = self._sample_devices()
        for _ in range(point.samples):
            ref_nt = self._reference_now()
            got = read_all(together, self.rig.clock)  # conversions overlap (devices/interleave.py)
            sensors = {name: got[name].temp_c for name in self.rig.temp_sensors}
            samples = {dut: got[dut] for dut in self.rig.duts}
            for dut, dev in self.rig.duts.items():
                sample = samples[dut]
                if self.rig.temp_sources[dut] is dev:  # its own sensor; a probe beside it is kept too
                    temp_c, other_c = sample.temp_c, sensors.get(beside.get(dut, ""))
                else:
                    temp_c, other_c = sensors[self.rig.temp_sources[dut].name], sample.temp_c
                if temp_c is None:
                    raise Hold(f"{dut}: its temperature source gives no temperature",
                               code=Reason.NO_TEMPERATURE, device=dut)
                settled = self.settled_c.get(dut, point.setpoint_c)  # where this DUT settled
                if cmd.temp_band_c is not None and abs(temp_c - settled) > cmd.temp_band_c:
                    raise Hold(f"{dut} temperature {temp_c:.2f} degC left {settled:.2f} +- "
                               f"{cmd.temp_band_c:g} degC during point {point.id}",
                               code=Reason.TEMP_OUT_OF_BAND, device=dut)
                rows.append(SampleRow.from_field_sample(dut, sample, ref_nt[dut], temp_c=temp_c,
                                                        ref_temp_c=other_c))
                self.status.dut_temps_c[dut] = temp_c
        self.check_chamber()
        self._feed_live(rows)
        decision = cmd.decide(point, rows, self.run_view()) if cmd.decide is not None else None
        stats = {**(cmd.stability or {}), "reference": self.reference.record()}
        self.session.record_point(point.id, rows, stats, started=started,
                                  temperatures=self.temperatures.take(), decision=decision)
        return Collected({r.dut: r.temp_c for r in rows}, decision)

    def run_view(self) -> RunView:
        return RunView(self.rig.clock.now(), self.status.chamber_c, self.session.info()["started"],
                       len(self.session.decisions()), tuple(self.status.point_durations_s))

    def read_targets(self, cmd: ReadTargets) -> dict:
        from calib.design.targets import check_targets

        return {dut: check_targets(live.acc, cmd.targets) for dut, live in self.live.items()}

    def _sample_devices(self) -> dict[str, Any]:
        """The DUTs and the temperature sensors, read as one: each probe right after the DUT it sits beside,
        so that on a switched I2C bus it shares its DUT's channel selection."""
        by_dut: dict[str, list[str]] = {}
        for s in self.rig.station.temperature_sensors:
            by_dut.setdefault(s.beside, []).append(s.name)
        order = [name for dut in self.rig.duts for name in (dut, *by_dut.pop(dut, []))]
        order += [name for names in by_dut.values() for name in names]
        devices = {**self.rig.duts, **self.rig.temp_sensors}
        return {name: devices[name] for name in order}

    def _feed_live(self, rows: list[SampleRow]) -> None:
        by_dut: dict[str, list[SampleRow]] = {}
        for r in rows:
            if not r.flags:
                by_dut.setdefault(r.dut, []).append(r)
        for dut, live in self.live.items():
            mine = by_dut.get(dut, [])
            live.add(np.array([r.field_nt for r in mine]).reshape(-1, 3),
                     np.array([r.temp_c for r in mine], float),
                     np.array([r.ref_field_nt for r in mine]).reshape(-1, 3))

    def preload_live(self, session_path) -> None:
        """On resume: start the live fits from what the session already holds."""
        from rig.session.reader import SessionReader

        with SessionReader(session_path) as reader:
            for dut, live in self.live.items():
                try:
                    ds = reader.dataset(dut)
                except ERRORS:
                    continue
                live.add(ds.h_nt, ds.temp_c, ds.ref_nt)

    def checkpoint(self, cmd: Checkpoint) -> None:
        log.info("point %s recorded", cmd.point_id)
        for callback in self.on_point:
            callback(cmd.point_id)
