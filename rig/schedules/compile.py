"""A plan compiled against its station: the deterministic list of points a campaign collects.

    points = compile_plan(plan, station)       # [Point], in the order they are taken
    report = check_plan(plan, station)         # limits checked without hardware; raises LimitError
    report.summary_lines()                     # what `rig check` prints (sizes, duration, warnings)

The plan's temperature schedule is one of (SCHEDULES, chosen by the plan's `temperatures:`):
- steps (rig/schedules/steps.py): every field at each stable setpoint; `T03-F07`, `T03-O07`;
- a continuous ramp (rig/schedules/ramp.py): legs x sweeps x fields; `R1U-S003-F07`;
- a designed schedule (rig/schedules/designed.py, written by `rig design`): legs to chosen
  temperatures, each held for its sweeps; `L02-S003-F07`;
- a sequential schedule (rig/schedules/sequential.py, run by rig/schedules/sequential_run.py): only the
  first sweep is known before the run, each further sweep is decided after the one before and recorded
  in the session; `L02-S0003-F07`.
Each kind's points run as tasks (TASKS, rig/schedules/tasks.py): generators that yield engine commands.
The plan check asks the schedule once for its points, limits and duration, then applies what every plan
shares (rig/schedules/check.py): the field source's limits, the T24 design, the duration bound,
stop_when; and the reference chain's (rig/reference/checks.py): commissioning, non-uniformity at the DUT
positions.
For coils the target is the total field (lab frame, nT) the coils must make, ambient included; for a
turntable it is (az_deg, el_deg).
"""

from __future__ import annotations

from rig.config import (
    Campaign,
    DesignedTemperatures,
    Plan,
    RampTemperatures,
    SequentialTemperatures,
    Station,
    Temperatures,
)
from rig.core.errors import ConfigError
from rig.core.points import Point, RampPoint, point_id
from rig.planning.pace import (
    MAX_DURATION_S,
    MAX_FIELDS,
    MAX_POINTS,
    MAX_SAMPLES_PER_DUT,
    MAX_TEMPERATURES,
    field_targets,
    format_duration,
)
from rig.reference.checks import reference_lines
from rig.schedules.check import (
    PlanCheck,
    check_duration,
    check_field_limits,
    located_errors,
    plan_error,
    stop_when_line,
    t24_design_problem,
)
from rig.schedules.designed import LegSchedule
from rig.schedules.ramp import RampSchedule
from rig.schedules.sequential import SequentialSchedule
from rig.schedules.sequential_run import SequentialTasks
from rig.schedules.steps import StepSchedule
from rig.schedules.tasks import MovingTasks, StepTasks

SCHEDULES = {Temperatures: StepSchedule, RampTemperatures: RampSchedule, DesignedTemperatures: LegSchedule,
             SequentialTemperatures: SequentialSchedule}
Schedule = StepSchedule | RampSchedule | LegSchedule | SequentialSchedule
# the tasks each kind's points run as (rig/schedules/tasks.py): generators of engine commands, nothing else
TASKS = {Temperatures: StepTasks, RampTemperatures: MovingTasks, DesignedTemperatures: MovingTasks,
         SequentialTemperatures: SequentialTasks}


def schedule_for(plan: Plan, station: Station) -> Schedule:
    """The plan's temperature schedule, with the field source's targets expanded (bounded first)."""
    n_fields = plan.fields.count()
    if n_fields > MAX_FIELDS:
        raise plan_error(ConfigError, plan, ("fields",), f"{n_fields} field targets; at most {MAX_FIELDS}")
    return SCHEDULES[type(plan.temperatures)](plan, station, field_targets(plan, station))


def compile_plan(plan: Plan, station: Station) -> list[Point]:
    return schedule_for(plan, station).points()


def tasks_for(plan: Plan, station: Station, points: list[Point]) -> StepTasks | MovingTasks | SequentialTasks:
    """The plan's points as engine tasks: `.tasks()` for the engine; a sequential schedule's also
    `.preload(session_path)` for a resume (it decides from every row so far)."""
    return TASKS[type(plan.temperatures)](plan, station, points)


def check_campaign(campaign: Campaign) -> PlanCheck:
    """check_plan with its errors naming the plan or station file, key and line."""
    with located_errors(campaign):
        return check_plan(campaign.plan, campaign.station)


def check_plan(plan: Plan, station: Station) -> PlanCheck:
    """Validate `plan` against `station` without touching hardware. Raises LimitError naming the limit."""
    schedule = schedule_for(plan, station)
    own = schedule.check()
    warnings: list[str] = []
    source_lines = check_field_limits(plan, station, own.points, warnings)
    design_points = own.points if own.design_points is None else own.design_points
    if "t24" in plan.fit.models and design_points:
        problem = t24_design_problem(design_points, station)
        if problem:
            warnings.append(problem)
    check_duration(plan, own.breakdown_s, own.duration_keys)
    duration_s = sum(own.breakdown_s.values())
    lines = [*own.lines, *source_lines, *reference_lines(plan, station, warnings)]
    if plan.stop_when and own.stop_when_line:
        lines.append(stop_when_line(plan, duration_s))
    return PlanCheck(
        points=own.points,
        n_temperatures=own.n_temperatures,
        n_fields=len(schedule.targets),
        n_duts=len(station.duts),
        samples_per_dut=len(own.points) * plan.samples_per_point,
        duration_s=duration_s,
        breakdown_s=own.breakdown_s,
        source_lines=lines,
        warnings=warnings,
        temperatures_word=own.temperatures_word,
        prediction=own.prediction,
        size_line=own.size_line,
    )


__all__ = [
    "MAX_DURATION_S", "MAX_FIELDS", "MAX_POINTS", "MAX_SAMPLES_PER_DUT", "MAX_TEMPERATURES", "SCHEDULES",
    "PlanCheck", "Point", "RampPoint", "check_campaign", "check_plan", "compile_plan", "format_duration",
    "located_errors", "point_id", "schedule_for",
]
