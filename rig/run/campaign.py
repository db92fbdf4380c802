"""A campaign run: the session, its lock, the rig, the engine, the schedule's tasks and the runner's
handlers, then the post-run fits, whatever happens in between.

    outcome = run_campaign(campaign=load_campaign(plan_path), session_path=path)   # or resume=True
    outcome.result.status, outcome.result.reason, outcome.fits

What run_campaign does with the pieces:
    schedule = tasks_for(plan, station, points)     # rig/schedules/compile.py TASKS: generators only
    runner = CampaignRunner(rig, plan, points, session, status=RunStatus())   # the handlers
    engine = Engine(runner.handlers(), devices=rig.devices(), clock=rig.clock, session=session, ...)
    runner.engine = engine
    engine.run(schedule.tasks(), done_ids=session.done_point_ids())
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from drivers.clock import Clock
from rig import config as cfg
from rig.analysis import postrun
from rig.analysis.fithelper import run_helper
from rig.core.errors import ERRORS, ConfigError, SessionError
from rig.core.points import Point
from rig.devices.build import Rig, open_rig
from rig.engine.commands import COMPLETED
from rig.engine.executor import Engine, RunResult, RunStatus
from rig.fieldsources.base import SETTLE_TIMEOUT_S
from rig.fieldsources.fieldmaths import reference_for
from rig.reference import chain_record, sitefield
from rig.run.notify import watching
from rig.run.runner import CampaignRunner
from rig.schedules.compile import check_campaign, tasks_for
from rig.schedules.sequential import decided_points
from rig.session.events import Kind, Reason
from rig.session.inbox import Inbox
from rig.session.lock import SessionLock
from rig.session.reader import simulated_text

log = logging.getLogger("magrig.campaign")

# --- a whole run: session, lock, rig, engine, fits ------------------------------------------------
@dataclass
class RunOutcome:
    session_path: Path
    result: RunResult
    fits: list[dict] = field(default_factory=list)  # {dut, model, path, rms_nt, error}
    stale_lock_pid: int | None = None
    wall_s: float = 0.0
    verdicts: list = field(default_factory=list)  # rig.analysis.acceptance.Verdict per DUT
    judged_model: str | None = None  # the calibration the plan judges (Plan.judged_model)


def load_from_session(path: str | Path, info: dict | None = None) -> tuple[cfg.Plan, cfg.Station]:
    """The plan and the station exactly as the session recorded them, with the commissioning its run
    started with (a resume never rereads files). Refused when the plan or station file at its recorded
    path no longer matches the recorded text: the operator edited it and would expect the edit to apply."""
    from rig.session.reader import SessionReader, recorded_files_changed

    with SessionReader(path) as reader:
        info = reader.info() if info is None else info
        chain = reader.snapshot(chain_record.SNAPSHOT)
    changed = recorded_files_changed(info)
    if changed:
        raise SessionError(f"{path}: cannot resume: {'; '.join(changed)}. A resume runs the recorded plan "
                           "and station: restore the file(s), or start a new session")
    return chain_record.recorded_plan_and_station(path, info, chain)


def recorded_campaign(path: str | Path, info: dict) -> cfg.Campaign:
    """The session's recorded plan and station as a Campaign, its errors naming `SESSION (recorded plan)`."""
    plan, station = load_from_session(path, info)
    return cfg.Campaign(plan, station, Path(f"{path} (recorded plan)"), Path(f"{path} (recorded station)"),
                        info["plan_text"], info["station_text"])


def checked_points(campaign: cfg.Campaign) -> list[Point]:
    """The campaign's points after every limit `rig check` applies (chamber setpoints and ramps, coil
    currents, table angles, sizes, duration); a refusal names the file, key and line. A run calls it
    before any device is opened."""
    return check_campaign(campaign).points


def run_campaign(
    *,
    campaign: cfg.Campaign | None = None,
    session_path: str | Path,
    resume: bool = False,
    prompt=None,
    display_factory=None,
    clock: Clock | None = None,
    hold_wait_s: float = 60.0,
    max_retakes: int = 3,
    on_rig=None,
) -> RunOutcome:
    """Run (or resume) a campaign into `session_path`, then fit the plan's models for each DUT.

    New run: `campaign` gives plan and station. Resume: both come from the session itself.
    `display_factory(status, runner)` returns a context manager (the live display) or None;
    `on_rig(rig)` sees the connected rig before the run (benchmarks instrument it, tests inject faults)."""
    from rig.session.reader import SessionReader
    from rig.session.writer import Session

    wall0 = time.perf_counter()
    session_path = Path(session_path)
    if resume:
        with SessionReader(session_path) as reader:
            info, summary = reader.info(), reader.summary()
        if info["completed"]:  # nothing to take, nothing to fit again
            done = RunResult(COMPLETED, "the session is already complete; nothing to do",
                             summary["points_done"], Reason.COMPLETED)
            return RunOutcome(session_path, done, wall_s=time.perf_counter() - wall0)
        campaign = recorded_campaign(session_path, info)
    assert campaign is not None
    plan, station = campaign.plan, campaign.station
    points = checked_points(campaign)  # before open_rig: nothing has moved yet
    if not station.field_source.needs_measurement():
        reference_for(station)  # a stated site field that cannot be evaluated stops us here
    # a resume finds the reference calibration files beside the station file the session recorded
    calibrations = sitefield.reference_calibrations(station, None if resume else campaign,
                                                   info if resume else None)
    lock = SessionLock(session_path)
    lock.acquire()
    try:
        rig = open_rig(station, plan, clock)  # connects and makes every device safe FIRST
        try:
            check_temp_sources(rig)
            station.field_source.prepare(rig.field_source)  # e.g. home a table that lost its home
            if on_rig is not None:
                on_rig(rig)
            if resume:
                session = Session.open(session_path, clock=rig.clock)
                points = points + decided_points(plan, station, session.decisions(), len(points))
                points = resumable_points(session, points)
            else:
                session = Session.create_for(session_path, campaign, points, clock=rig.clock,
                                             operator=os.environ.get("USER"))
            with session, watching(session, plan, station):  # word to the operator: rig/run/notify.py
                outcome = _run_in_session(rig, plan, points, session, lock, prompt, display_factory,
                                          hold_wait_s, max_retakes, resume, calibrations)
            postrun.seal_sources(session_path, outcome.fits)  # the session is whole: its files cite it
        finally:
            rig.close()
    finally:
        lock.release()
    outcome.wall_s = time.perf_counter() - wall0
    return outcome


def record_final_state(rig: Rig, session) -> None:
    """After the engine's final safe_state: what the chamber and the field source report, as snapshots
    named "<device> final" (the evidence that the run ended with coils at 0 A / table stopped and the
    chamber at its safe setpoint)."""
    with contextlib.suppress(*ERRORS):
        rig.field_source.wait_settled(SETTLE_TIMEOUT_S)  # readbacks follow the safe setpoints
    for dev in (rig.chamber, rig.field_source):
        try:
            reading = dataclasses.asdict(dev.read())
        except Exception as exc:  # a dead link: say so instead of claiming anything
            reading = {"error": str(exc)}
        session.record_snapshot(f"{dev.name} final", reading)


def check_temp_sources(rig: Rig) -> None:
    """Every DUT needs a temperature with every sample: refuse a station whose source gives none."""
    for dut, source in rig.temp_sources.items():
        if source.read().temp_c is None:
            where = "its own sensor" if source is rig.duts[dut] else f"sensor {source.name}"
            raise ConfigError(f"station {rig.station.name}: DUT {dut} takes its temperature from {where}, "
                              "which reports none; mount a TMP117 beside it (temperature_sensors) and name "
                              "it in the DUT's temp_source")


def resumable_points(session, points: list[Point]) -> list[Point]:
    """The points to resume with, in the order the session planned them: the same points taken in another
    order (a session begun before its plan's fields were shuffled per step) go on in the recorded one."""
    planned = session.planned_point_ids()
    if planned == [p.id for p in points]:
        return points
    by_id = {p.id: p for p in points}
    if sorted(planned) != sorted(by_id):
        raise SessionError(f"{session.path}: the recorded plan no longer compiles to the recorded points; "
                           "cannot resume")
    return [dataclasses.replace(by_id[pid], index=k) for k, pid in enumerate(planned)]


def _run_in_session(rig, plan, points, session, lock, prompt, display_factory, hold_wait_s, max_retakes,
                    resume, calibrations=None) -> RunOutcome:
    if lock.stale_pid is not None:
        session.log_event(Kind.STALE_LOCK, f"previous run (pid {lock.stale_pid}) died without finishing; "
                          "hardware made safe, lock taken over", code=Reason.STALE_LOCK, level="WARNING",
                          pid=lock.stale_pid)
    session.log_event(Kind.START, ("resumed" if resume else "started") + " with every device made safe; "
                      + simulated_text(rig.simulated), code=Reason.RESUMED if resume else Reason.STARTED,
                      simulated=rig.simulated)
    for dev in rig.devices():
        session.record_snapshot(dev.name, dev.describe())
    session.record_snapshot(chain_record.SNAPSHOT, chain_record.record(rig.station, calibrations))
    status = RunStatus()
    schedule = tasks_for(plan, rig.station, points)
    runner = CampaignRunner(rig, plan, points, session, status)
    if runner.source.needs_measurement():
        sitefield.measure_for_run(runner, session, calibrations or {})
    done = session.done_point_ids()
    if done:
        runner.preload_live(session.path)
        if hasattr(schedule, "preload"):  # a sequential schedule decides from every row so far
            schedule.preload(session.path)
    engine = Engine(runner.handlers(), devices=rig.devices(), clock=rig.clock, session=session,
                    prompt=prompt, max_retakes=max_retakes, hold_wait_s=hold_wait_s, status=status,
                    inbox=Inbox(session.path))
    runner.engine = engine
    display = display_factory(status, runner) if display_factory else None
    if prompt is not None and hasattr(display, "suspended"):
        engine.prompt = display.suspended(prompt)  # no live panel redrawing over the question
    # the post-run fits' helper process gets ready on the other core while the run goes on
    with run_helper(session.path, tuple(plan.fit.models), bool(plan.fit.robust), len(rig.duts)) as helper:
        with display or contextlib.nullcontext():
            result = engine.run(schedule.tasks(), done_ids=done)
        if runner.site is not None and result.status == COMPLETED:  # the field source is at its safe setting
            runner.site.check_at_end(session.log_event)
        record_final_state(rig, session)
        outcome = RunOutcome(session.path, result, stale_lock_pid=lock.stale_pid,
                             judged_model=plan.judged_model)
        if result.status == COMPLETED:
            outcome.fits = postrun.fit_session(session, plan, rig.station,
                                               progress=getattr(display, "fit_progress", None), helper=helper)
    if result.status == COMPLETED and plan.acceptance is not None:
        outcome.verdicts = postrun.accept_session(session, plan, rig.station, outcome.fits,
                                                     runner.live_summaries)
    return outcome
