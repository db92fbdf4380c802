"""stop_when on a designed plan: targets met early do not stop the run before every DUT's temperature has
come within the plan's band of both ends of its range (rig/schedules/tasks.py TargetsWatch): the watch
yields ReadTargets, then an Event and a RequestStop, and touches nothing else."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from calib.design.targets import check_targets
from calib.models.gram import GramAccumulator
from rig.config.plan import Plan
from rig.engine.commands import Event, ReadTargets, RequestStop
from rig.schedules.tasks import TargetsWatch

PLAN = {"name": "legs", "temperatures": {"mode": "designed", "rate_c_per_min": 1.0,
                                         "legs": [{"to_c": 10, "sweeps": 2}, {"to_c": 40, "sweeps": 2}]},
        "fields": {"kind": "cube24", "magnitude_nt": 50000}, "samples_per_point": 2,
        "fit": {"models": ["t24"]}, "stop_when": {"S": 1.0, "b": 1e6}}


def _met_accumulator() -> GramAccumulator:
    """A T24 fit far better than the loose targets: 200 noiseless readings over 10 .. 40 degC."""
    rng = np.random.default_rng(3)
    h = rng.normal(0, 30000, (200, 3))
    temps = rng.uniform(10, 40, 200)
    acc = GramAccumulator(25.0)
    acc.add(h, temps, h + rng.normal(0, 1.0, (200, 3)))
    return acc


def _run(watch: TargetsWatch, point_id: str, temp_c: float) -> list:
    """The commands the watch yields after a point, each answered as the engine and the runner would."""
    gen, yielded, reply = watch.after(point_id, {"dut1": temp_c}), [], None
    acc = _met_accumulator()
    try:
        while True:
            command = gen.send(reply)
            yielded.append(command)
            read = isinstance(command, ReadTargets)
            reply = {"dut1": check_targets(acc, command.targets)} if read else None
    except StopIteration:
        return yielded


def test_targets_met_short_of_an_end_do_not_stop_a_designed_plan():
    plan = Plan.model_validate(PLAN)
    points = [SimpleNamespace(id=f"L0{leg}-S001-F01", temp_index=leg) for leg in (1, 2)]
    watch = TargetsWatch(plan, points)
    assert _run(watch, "L01-S001-F01", 10.2) == []  # at the low end
    assert _run(watch, "L02-S001-F01", 36.0) == []  # 4 degC short of the high end: the targets alone are met
    commands = _run(watch, "L02-S001-F01", 39.6)  # within the band (0.5) of 40
    assert [type(c) for c in commands] == [ReadTargets, Event, RequestStop]
    assert "targets met" in commands[-1].message and commands[1].message == commands[-1].message
