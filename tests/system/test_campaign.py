"""End-to-end campaigns on the simulators: the demo recovers the injected parameters, the session holds
exactly the planned points and samples, and Ctrl-C / SIGTERM end the run safe and recorded."""

from __future__ import annotations

import signal

import numpy as np
import pytest
import yaml

from calib.io import calfile
from rig.config import load_station
from rig.config.loading import load_campaign
from rig.devices.simulated.world import dut_truths
from rig.run.campaign import run_campaign
from rig.schedules.compile import compile_plan
from tests.helpers.statistics import assert_within_std_errors
from tests.system.campaign_helpers import (
    DEMO_PLAN,
    SIM_STATION,
    events,
    final_snapshots,
    first_point_line,
    popen_rig,
    query,
    run_rig,
    session_counts,
    small_plan,
)

pytestmark = pytest.mark.system


def test_demo_campaign_recovers_every_dut_within_its_standard_errors(tmp_path):
    station = SIM_STATION
    session = tmp_path / "demo.session"
    proc = run_rig("run", str(DEMO_PLAN), "--station", str(station), "--session", str(session), "--no-live")
    assert proc.returncode == 0, proc.stderr
    assert "completed" in proc.stdout

    campaign = load_campaign(DEMO_PLAN, station)
    points = compile_plan(campaign.plan, campaign.station)
    counts = session_counts(session)
    duts = [d.name for d in campaign.station.duts]
    assert counts["planned"] == counts["done"] == len(points) == 4 * 26
    assert counts["completed"] and counts["status"] == "completed"
    expected = {(p.id, d): campaign.plan.samples_per_point for p in points for d in duts}
    assert counts["per_point_dut"] == expected

    truths = dut_truths(load_station(station))
    found = {}
    for dut, truth in truths.items():
        cal = calfile.load(tmp_path / f"demo.{dut}.t24.yaml")
        for key, true in (("S", truth.S), ("K", truth.K), ("b_nt", truth.b_nt),
                          ("kb_nt_per_c", truth.kb_nt_per_c)):
            found[f"{dut} {key}"] = (np.asarray(cal.params[key]) - true) / np.asarray(cal.std_errors[key])
        assert (tmp_path / f"demo.{dut}.p12.yaml").is_file()
    assert_within_std_errors(found)


def test_default_station_completes_a_run(tmp_path):
    session = tmp_path / "s.session"
    proc = run_rig("run", str(small_plan(tmp_path, samples=2)), "--session", str(session), "--no-live")
    assert proc.returncode == 0, proc.stderr
    assert session_counts(session)["completed"]


def test_a_dut_without_temperature_is_refused_in_one_line_before_any_session(tmp_path):
    data = yaml.safe_load(SIM_STATION.read_text())
    serial = next(d for d in data["duts"] if d["type"] == "serialmag")
    serial["temp_source"] = "self"
    station = tmp_path / "station.yaml"
    station.write_text(yaml.safe_dump(data, sort_keys=False))
    session = tmp_path / "s.session"
    proc = run_rig("run", str(small_plan(tmp_path, samples=2)), "--station", str(station),
                   "--session", str(session), "--no-live")
    assert proc.returncode == 2 and proc.stderr.startswith("error: ")
    assert "temp_source" in proc.stderr and "serialmag has no temperature sensor" in proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not session.exists() and not (tmp_path / "s.session.lock").exists()


@pytest.mark.parametrize("sig, reason", [(signal.SIGINT, "operator aborted"), (signal.SIGTERM, "SIGTERM")])
def test_interrupt_ends_with_coils_off_and_chamber_at_safe_setpoint(tmp_path, sig, reason):
    station = SIM_STATION
    session = tmp_path / "run.session"
    plan = small_plan(tmp_path, samples=20)
    proc = popen_rig("run", str(plan), "--station", str(station), "--session", str(session), "--no-live")
    first = first_point_line(proc)  # the first point is recorded: the run is in full swing
    assert "done" in first, proc.stderr.read()
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    assert "run not completed" in err and "--resume" in err

    counts = session_counts(session)
    assert counts["status"] == "aborted" and not counts["completed"]
    assert 1 <= counts["done"] < counts["planned"] and counts["orphan_samples"] == 0
    kinds = [k for k, _ in events(session)]
    assert kinds[-1] == "exit" and "safe_state" in kinds
    assert reason in dict(events(session))["exit"]
    final = final_snapshots(session)
    coils, chamber = final["coils"][-1], final["chamber"][-1]
    assert coils["setpoints_a"] == [0.0, 0.0, 0.0] and coils["enabled"] == [False, False, False]
    assert np.abs(coils["currents_a"]).max() < 1e-3
    assert chamber["setpoint_c"] == pytest.approx(load_station(station).chamber.limits.safe_setpoint_c)


def _coil_sim(rig):
    from drivers.sim.devices.coils import CoilSim

    return next(s for s in rig.built.sims if isinstance(s, CoilSim))


def test_a_device_fault_after_retries_holds_and_retakes_the_point(tmp_path):
    campaign = load_campaign(small_plan(tmp_path, samples=3), SIM_STATION)
    session = tmp_path / "fault.session"

    def busy_coils(rig):
        _coil_sim(rig).fail_next(3, code=6)  # "busy" three times: the transport's 3 tries all fail

    outcome = run_campaign(campaign=campaign, session_path=session, on_rig=busy_coils)
    assert outcome.result.status == "completed"
    counts = session_counts(session)
    assert counts["done"] == counts["planned"] == 12 and counts["orphan_samples"] == 0
    assert set(counts["per_point_dut"].values()) == {3}
    log = events(session)
    holds = [m for k, m in log if k == "hold"]
    first = compile_plan(campaign.plan, campaign.station)[0].id  # the fault came at the first move
    assert len(holds) == 1 and "coils" in holds[0] and f"point {first}:" in holds[0]
    assert any(k == "warning" and "try 1 of 3 failed" in m for k, m in log)  # retries reach the session


def test_a_persistent_chamber_alarm_aborts_after_the_retakes_and_ends_safe(tmp_path):
    campaign = load_campaign(small_plan(tmp_path, samples=3), SIM_STATION)
    session = tmp_path / "alarm.session"

    def alarm(rig):
        rig.world.chamber_alarm = True

    outcome = run_campaign(campaign=campaign, session_path=session, on_rig=alarm, max_retakes=2)
    assert outcome.result.status == "aborted"
    assert "chamber alarm" in outcome.result.reason and "gave up after 2 retakes" in outcome.result.reason
    assert len([k for k, _ in events(session) if k == "hold"]) == 2
    assert session_counts(session)["done"] == 0
    final = final_snapshots(session)
    assert final["coils"][-1]["enabled"] == [False, False, False]
    assert final["chamber"][-1]["setpoint_c"] == pytest.approx(25.0)
    assert not outcome.fits


def test_a_session_planned_in_another_order_resumes_in_its_own(tmp_path):
    """A session begun before its plan's fields were shuffled per step holds them in the listed order: a
    resume goes on in that order, not the one the plan compiles to now."""
    from drivers.clock import SimClock
    from rig.session.writer import Session

    campaign = load_campaign(small_plan(tmp_path, samples=2), SIM_STATION)
    listed = compile_plan(campaign.plan.model_copy(update={"field_order": "listed"}), campaign.station)
    assert [p.id for p in compile_plan(campaign.plan, campaign.station)] != [p.id for p in listed]
    session = tmp_path / "before.session"
    Session.create_for(session, campaign, listed, operator="op", clock=SimClock()).close()
    outcome = run_campaign(campaign=campaign, session_path=session, resume=True)
    assert outcome.result.status == "completed"
    done = query(session, "SELECT p.id FROM points p JOIN samples s ON s.point_id = p.id "
                          "GROUP BY p.id ORDER BY min(s.t)")
    assert [row[0] for row in done] == [p.id for p in listed]
