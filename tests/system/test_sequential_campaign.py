"""Sequential design on the simulated station: decided sweep by sweep, stopped at the targets, and resumed
after an abort or a kill -9 at any moment with every point taken exactly once."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from calib.io import calfile
from rig.config.loading import load_campaign
from rig.run.campaign import run_campaign
from rig.schedules.compile import compile_plan
from tests.system.campaign_helpers import SIM_STATION, killed_at, query, run_rig, session_counts

pytestmark = pytest.mark.system

TARGETS = {"S": 1e-3, "K": 1e-4, "b": 25.0, "kb": 1.5}
DIRECTIONS = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
              [1, 1, 1], [-1, -1, 1], [1, -1, -1], [-1, 1, -1]]
SAMPLES = 4
SHORT_H = 0.6  # a resume test's campaign: stopped by its duration, well after its abort or kill


def seq_plan(tmp_path, name: str = "seq", hours: float = 2.0) -> str:
    """A narrow sequential campaign: 18 .. 26 degC, a check at 22, 6 of 10 directions a sweep; nothing known
    of the DUTs before the run (it characterises them on its first leg), each end held until every DUT is
    within a quarter degree of it (settle_s makes a sweep a minute of the campaign clock: few points)."""
    plan = {
        "name": name,
        "temperatures": {"mode": "sequential", "range_c": [18, 26], "rate_c_per_min": 1.0, "checks_c": [22],
                         "fields_per_sweep": 6, "max_duration_h": hours},
        "fields": {"kind": "directions", "magnitude_nt": 50000, "directions": DIRECTIONS},
        "samples_per_point": SAMPLES,
        "settle_s": 5.0,
        "fit": {"models": ["t24"]},
        "stop_when": TARGETS,
    }
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return str(path)


def decisions(session) -> list[dict]:
    return [{**json.loads(d), "after_point": a}
            for a, d in query(session, "SELECT after_point, decision_json FROM decisions ORDER BY seq")]


def check_every_point_once(session, campaign) -> None:
    """The planned points are the first sweep and every decision's sweep, each done once, nothing else."""
    counts = session_counts(session)
    assert counts["completed"] and counts["done"] == counts["planned"]
    assert counts["orphan_samples"] == 0
    duts = [d.name for d in campaign.station.duts]
    planned = [r[0] for r in query(session, "SELECT id FROM points ORDER BY idx")]
    assert counts["per_point_dut"] == {(p, d): SAMPLES for p in planned for d in duts}
    first = [p.id for p in compile_plan(campaign.plan, campaign.station)]
    assert planned[: len(first)] == first
    sweeps = [d for d in decisions(session) if not d["stop"]]
    assert len(planned) == len(first) + sum(len(d["picks"]) for d in sweeps)
    for d in sweeps:  # each decision came after the last point of the sweep before it
        after = planned.index(d["after_point"])
        nxt = planned[after + 1]
        assert nxt.startswith(f"L{d['leg']:02d}-S{d['sweep']:04d}-")


def test_a_sequential_campaign_decides_each_sweep_and_stops_at_its_targets(tmp_path):
    campaign = load_campaign(seq_plan(tmp_path), SIM_STATION)
    session = tmp_path / "s.session"
    outcome = run_campaign(campaign=campaign, session_path=session)
    result = outcome.result
    assert result.status == "completed" and result.code == "targets_met", result.reason
    check_every_point_once(session, campaign)
    made = decisions(session)
    assert made[-1]["stop"] and "meets its targets" in made[-1]["reason"]
    legs = {d["leg"]: d["to_c"] for d in made if not d["stop"]}
    assert 22.0 in legs.values()  # the model check's interior temperature was visited
    # no prior: the run characterised the DUTs on its first leg, then planned with what it measured (each
    # estimate recorded with its decision); the simulated mounts lag by 300 and 450 s
    assert made[0]["kind"] == "characterise" and made[0]["estimates"] == {}
    final = made[-1]["estimates"]
    assert final["mmc0"]["lag_s"] == pytest.approx(300.0, rel=0.1)
    assert final["serial0"]["lag_s"] == pytest.approx(450.0, rel=0.1)
    assert {e["source"] for e in final.values()} == {"measured by this run"}
    assert any(d.get("replanned") for d in made)
    for dut, (low, high) in made[-1]["reached_c"].items():  # both ends reached at the DUTs, not in the air
        assert low <= 18.25 and high >= 25.75, dut
    for fit in outcome.fits:  # the calibrations meet the targets the run stopped at
        cal = calfile.load(fit["path"])
        assert cal.stats["linearity"]["testable"]  # the check temperature lets the model check see a curve
        se = cal.std_errors
        for group, key in (("S", "S"), ("K", "K"), ("b", "b_nt"), ("kb", "kb_nt_per_c")):
            assert np.max(se[key]) <= TARGETS[group] * 1.001, (fit["dut"], group)
    kinds = query(session, "SELECT kind, count(*) FROM events GROUP BY kind")
    assert dict(kinds)["decision"] == sum(not d["stop"] for d in made)
    assert "already complete" in run_campaign(session_path=session, resume=True).result.reason


class _AbortAfter:
    """A display hook: abort the run once `decided` decisions exist, `extra` points later."""

    def __init__(self, decided: int, extra: int):
        self.decided, self.extra, self.runner, self.seen = decided, extra, None, None

    def __call__(self, status, runner):
        self.runner = runner
        runner.on_point.append(self.on_point)
        return None

    def on_point(self, point_id: str) -> None:
        n = len(self.runner.session.decisions())
        if n >= self.decided and self.seen is None:
            self.seen = point_id
            self.left = self.extra
        if self.seen is not None:
            if self.left == 0:
                self.runner.engine.request_abort("test: abort here")
            self.left -= 1


@pytest.mark.parametrize("extra", [0, 3], ids=["at-a-sweep-end", "mid-sweep"])
def test_abort_anywhere_then_resume_takes_every_point_once(tmp_path, extra):
    campaign = load_campaign(seq_plan(tmp_path, hours=SHORT_H), SIM_STATION)
    session = tmp_path / "a.session"
    hook = _AbortAfter(decided=4, extra=extra)
    first = run_campaign(campaign=campaign, session_path=session, display_factory=hook)
    assert first.result.status == "aborted"
    before = decisions(session)
    done_before = {r[0] for r in query(session, "SELECT id FROM points WHERE state = 'done'")}
    planned_before = query(session, "SELECT count(*) FROM points")[0][0]
    assert len(done_before) < planned_before  # the decided sweep is planned, not all taken
    last_t = query(session, "SELECT max(t) FROM samples")[0][0]
    resumed = run_campaign(session_path=session, resume=True)
    assert resumed.result.status == "completed", resumed.result.reason
    check_every_point_once(session, campaign)
    after = decisions(session)
    assert after[: len(before)] == before  # nothing decided before was decided again
    retaken = query(session, "SELECT DISTINCT point_id FROM samples WHERE t > ?", last_t)
    assert not {r[0] for r in retaken} & done_before


def test_kill_9_during_a_sequential_campaign_then_resume(tmp_path):
    plan = seq_plan(tmp_path, "k", hours=SHORT_H)
    session = tmp_path / "k.session"
    killed_at(session, plan, SIM_STATION, "decision:3")
    before = session_counts(session)
    assert before["status"] is None and before["done"] < before["planned"] or not before["completed"]
    assert len(decisions(session)) == 3
    resumed = run_rig("run", "--resume", str(session), "--no-live", timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    check_every_point_once(session, load_campaign(plan, SIM_STATION))
    assert query(session, "SELECT count(*) FROM events WHERE kind = 'stale_lock'")[0][0] == 1


def test_a_designed_plan_aborted_in_a_leg_resumes_without_a_stability_wait(tmp_path):
    """Designed legs (rig/schedules/designed.py) start ramping from wherever the air is, also on a resume."""
    plan = {"name": "legs",
            "temperatures": {"mode": "designed", "rate_c_per_min": 3.0,
                             "legs": [{"to_c": 18, "sweeps": 4}, {"to_c": 22, "sweeps": 3, "check": True},
                                      {"to_c": 26, "sweeps": 4}]},
            "fields": {"kind": "directions", "magnitude_nt": 50000, "directions": DIRECTIONS[:6]},
            "samples_per_point": SAMPLES, "settle_s": 0.2, "fit": {"models": ["t24"]}}
    path = tmp_path / "legs.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    campaign = load_campaign(path, SIM_STATION)
    points = compile_plan(campaign.plan, campaign.station)
    session = tmp_path / "legs.session"

    def abort_in_leg_2(status, runner):
        def on_point(point_id):
            if point_id == "L02-S002-F03":
                runner.engine.request_abort("test: abort in leg 2")
        runner.on_point.append(on_point)

    assert run_campaign(campaign=campaign, session_path=session,
                        display_factory=abort_in_leg_2).result.status == "aborted"
    assert session_counts(session)["done"] == [p.id for p in points].index("L02-S002-F03") + 1
    resumed = run_campaign(session_path=session, resume=True)
    assert resumed.result.status == "completed", resumed.result.reason
    counts = session_counts(session)
    assert counts["completed"] and counts["done"] == counts["planned"] == len(points)
    duts = [d.name for d in campaign.station.duts]
    assert counts["per_point_dut"] == {(p.id, d): SAMPLES for p in points for d in duts}
    assert query(session, "SELECT count(*) FROM events WHERE kind = 'stable'")[0][0] == 0
