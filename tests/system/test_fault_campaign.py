"""Campaigns on a station whose simulated devices misbehave (transport `faults:`): the rig retries,
holds and retakes, records every fault as an event naming the device and the reason, and ends safe."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rig.config.loading import load_campaign
from rig.run.campaign import run_campaign
from rig.schedules.compile import compile_plan
from rig.session.events import HOLD_REASONS, Reason
from tests.system.campaign_helpers import (
    DEMO_PLAN,
    REPO,
    SIM_STATION,
    final_snapshots,
    query,
    session_counts,
    small_plan,
)

pytestmark = pytest.mark.system

FAULTS_STATION = REPO / "configs" / "stations" / "sim-faults.yaml"
FAULT_CODES = {r.value for r in HOLD_REASONS} - {Reason.STABLE.value}


def demo_with_samples(tmp_path: Path, samples: int) -> Path:
    """The demo plan (every temperature, every direction) with fewer samples per point."""
    plan = yaml.safe_load(DEMO_PLAN.read_text())
    plan.pop("station")
    plan["samples_per_point"] = samples
    path = tmp_path / "demo-short.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return path


def station_with(tmp_path: Path, faults: dict[tuple, dict]) -> Path:
    """sim.yaml with `faults:` on some devices, keyed by their path, e.g. ("duts", 1)."""
    station = yaml.safe_load(SIM_STATION.read_text())
    for path, spec in faults.items():
        node = station
        for key in path:
            node = node[key]
        node["transport"]["faults"] = spec
    out = tmp_path / "station.yaml"
    out.write_text(yaml.safe_dump(station, sort_keys=False))
    return out


def fault_events(session: Path) -> list[tuple[str, str, str, str]]:
    """(kind, code, device, message) of every event coded as a device fault."""
    rows = query(session, "SELECT kind, code, device, message FROM events ORDER BY id")
    return [r for r in rows if r[1] in FAULT_CODES]


def assert_safe_at_the_end(session: Path) -> None:
    final = final_snapshots(session)
    assert final["coils"][-1]["enabled"] == [False, False, False]
    assert final["chamber"][-1]["setpoint_c"] == pytest.approx(25.0)
    safe = query(session, "SELECT code FROM events WHERE kind = 'safe_state' ORDER BY id")
    assert safe[-1][0] == Reason.ALL_SAFE


def test_one_fault_in_100_operations_everywhere_still_takes_every_point_once(tmp_path):
    campaign = load_campaign(demo_with_samples(tmp_path, 3), FAULTS_STATION)
    session = tmp_path / "faults.session"
    worlds = []
    outcome = run_campaign(campaign=campaign, session_path=session,
                           on_rig=lambda rig: worlds.append(rig.world))
    assert outcome.result.status == "completed", outcome.result.reason

    points = compile_plan(campaign.plan, campaign.station)
    duts = [d.name for d in campaign.station.duts]
    counts = session_counts(session)
    assert counts["planned"] == counts["done"] == len(points) == 4 * 26  # the demo: 4 steps x 26 fields
    assert counts["per_point_dut"] == {(p.id, d): 3 for p in points for d in duts}
    assert counts["orphan_samples"] == 0
    assert query(session, "SELECT count(*) FROM samples")[0][0] == 4 * 26 * len(duts) * 3  # none twice

    # every device met faults, every kind its protocol allows was played somewhere
    faults = worlds[0].faults
    assert set(faults) == {d.name for d in campaign.station.devices()}
    assert all(sum(f.fired.values()) > 0 for f in faults.values())
    assert {k for f in faults.values() for k in f.fired} == {"no_reply", "exception", "garbled", "nack"}

    # every fault injected while the engine ran is an event naming its device with a fault code
    (t_run,), (t_exit,) = (query(session, f"SELECT t FROM events WHERE kind = '{k}'")[0]
                           for k in ("run", "exit"))
    recorded = fault_events(session)
    for name, f in faults.items():
        injected = [kind for t, kind in f.history if t_run < t < t_exit]
        mine = [r for r in recorded if r[2] == name]
        assert injected and len(mine) >= len(injected), (name, len(mine), injected)
    assert_safe_at_the_end(session)


def test_an_unplugged_chamber_and_its_alarm_hold_the_run_which_then_completes(tmp_path):
    station = station_with(tmp_path, {  # while the DUTs settle at the first step, then at the second
        ("chamber",): {"unplug": {"after_s": 300, "for_s": 90}, "alarm": {"after_s": 2400, "for_s": 100}},
    })
    campaign = load_campaign(small_plan(tmp_path, samples=3), station)
    session = tmp_path / "hold.session"
    outcome = run_campaign(campaign=campaign, session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    counts = session_counts(session)
    assert counts["done"] == counts["planned"] == 12 and counts["orphan_samples"] == 0
    assert set(counts["per_point_dut"].values()) == {3}
    holds = query(session, "SELECT code, device FROM events WHERE kind = 'hold'")
    assert (Reason.CHAMBER_ALARM, "chamber") in holds
    assert (Reason.DEVICE_TIMEOUT, "chamber") in holds
    assert_safe_at_the_end(session)


def test_a_device_unplugged_for_good_ends_the_run_safe_with_its_name(tmp_path):
    station = station_with(tmp_path, {("temperature_sensors", 1): {"unplug": {"after_s": 1200}}})
    campaign = load_campaign(small_plan(tmp_path, samples=3), station)
    session = tmp_path / "gone.session"
    outcome = run_campaign(campaign=campaign, session_path=session, max_retakes=2)
    assert outcome.result.status == "aborted"
    assert "tmp1" in outcome.result.reason and "gave up after 2 retakes" in outcome.result.reason
    assert "no ACK" in outcome.result.reason
    assert_safe_at_the_end(session)


def test_a_stuck_temperature_sensor_is_not_taken_for_stable(tmp_path):
    station = station_with(tmp_path, {("temperature_sensors", 0): {"stuck_temperature": {"for_s": 700}}})
    campaign = load_campaign(small_plan(tmp_path, samples=3), station)
    session = tmp_path / "stuck.session"
    outcome = run_campaign(campaign=campaign, session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    holds = query(session, "SELECT code, device, message FROM events WHERE kind = 'hold'")
    assert holds and all(code == Reason.DEVICE_FAULT and device == "tmp0" for code, device, _ in holds)
    assert "frozen" in holds[0][2]
    assert session_counts(session)["done"] == 12


def test_a_sensor_stuck_for_good_ends_the_run_with_a_clear_message(tmp_path):
    station = station_with(tmp_path, {("temperature_sensors", 0): {"stuck_temperature": True}})
    campaign = load_campaign(small_plan(tmp_path, samples=3), station)
    outcome = run_campaign(campaign=campaign, session_path=tmp_path / "stuck.session", max_retakes=1)
    assert outcome.result.status == "aborted"
    assert "tmp0: temperature frozen" in outcome.result.reason
    assert_safe_at_the_end(tmp_path / "stuck.session")
