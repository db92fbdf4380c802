"""stop_when on a designed plan: targets met early do not stop the run before every DUT's temperature has
come within the plan's band of both ends of its range (rig/schedules/moving_tasks.py StopWhen)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from calib.models.gram import GramAccumulator
from rig.config.plan import Plan
from rig.schedules.moving_tasks import StopWhen

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


def _runner(plan: Plan):
    points = [SimpleNamespace(id=f"L0{leg}-S001-F01", temp_index=leg) for leg in (1, 2)]
    stops: list[str] = []
    engine = SimpleNamespace(event=lambda *a, **k: None,
                             request_stop=lambda message, code: stops.append(message))
    runner = SimpleNamespace(plan=plan, points=points, live={"dut1": SimpleNamespace(acc=_met_accumulator())},
                             status=SimpleNamespace(dut_temps_c={}), engine=engine)
    return runner, stops


def test_targets_met_short_of_an_end_do_not_stop_a_designed_plan():
    plan = Plan.model_validate(PLAN)
    runner, stops = _runner(plan)
    stop = StopWhen(runner)
    runner.status.dut_temps_c["dut1"] = 10.2  # at the low end
    stop("L01-S001-F01")
    runner.status.dut_temps_c["dut1"] = 36.0  # 4 degC short of the high end: the targets alone are met
    stop("L02-S001-F01")
    assert stops == []
    runner.status.dut_temps_c["dut1"] = 39.6  # within the band (0.5) of 40
    stop("L02-S001-F01")
    assert len(stops) == 1 and "targets met" in stops[0]
