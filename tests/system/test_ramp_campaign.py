"""Continuous-ramp campaigns on the simulated station: end to end with the lag-corrected fit, stop when
good enough, kill -9 in the middle of a ramp then resume, and the lag of a simulated DUT recovered."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from calib.io import calfile
from calib.thermal.lag import estimate_lag
from drivers.clock import SimClock
from drivers.sim.world import DutTruth, World
from rig.config.loading import load_campaign
from rig.run.campaign import run_campaign
from rig.schedules.compile import compile_plan
from tests.system.campaign_helpers import (
    SIM_STATION,
    events,
    final_snapshots,
    killed_at,
    query,
    run_rig,
    session_counts,
)

pytestmark = pytest.mark.system


def ramp_plan(tmp_path, *, samples=3, stop_when=None, name="ramp") -> str:
    """A narrow, fast ramp: 20 -> 30 -> 20 degC at 5 degC/min, the 6 axis directions."""
    plan = {
        "name": name,
        "temperatures": {"mode": "ramp", "range_c": [20, 30], "rate_c_per_min": 5.0,
                         "stability": {"band_c": 0.5, "rate_c_per_min": 0.3, "dwell_s": 60}},
        "fields": {"kind": "directions", "magnitude_nt": 50000,
                   "directions": [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]},
        "samples_per_point": samples,
        "settle_s": 1.0,
        "fit": {"models": ["t24"]},
    }
    if stop_when:
        plan["stop_when"] = stop_when
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return str(path)


def sample_temps(session, dut: str, point_prefix: str) -> np.ndarray:
    rows = query(session, "SELECT temp_c FROM samples WHERE dut = ? AND point_id LIKE ? ORDER BY t", dut,
                 point_prefix + "%")
    return np.array([r[0] for r in rows])


def test_a_small_ramp_runs_end_to_end_and_fits_with_the_lag(tmp_path):
    campaign = load_campaign(ramp_plan(tmp_path), SIM_STATION)
    points = compile_plan(campaign.plan, campaign.station)
    session = tmp_path / "r.session"
    outcome = run_campaign(campaign=campaign, session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    counts = session_counts(session)
    assert counts["done"] == counts["planned"] == len(points)
    duts = [d.name for d in campaign.station.duts]
    assert counts["per_point_dut"] == {(p.id, d): 3 for p in points for d in duts}
    up, down = sample_temps(session, "mmc0", "R1U"), sample_temps(session, "mmc0", "R1D")
    assert up[-1] - up[0] > 2 and down[-1] < down.max() - 0.3  # it moved during the sweeps
    assert np.unique(np.round(up, 2)).size > 30  # no steps: every sample its own temperature
    for fit in outcome.fits:
        assert "error" not in fit, fit
        # the lag was sought and its outcome stated: these probes read their element's own temperature,
        # so a lag is either found with its standard error or said not identifiable, by chance
        # (tests/system/test_ramp_campaign.py's lagging-sensor test recovers a real one)
        cal = calfile.load(fit["path"])
        lag = cal.stats["thermal_lag"]
        assert lag["message"]
        assert (lag["tau_s"] is None) == (lag["tau_se_s"] is None) == ("not identifiable" in lag["message"])
        # and the file says what tau then is: the probe's reading corrected by that lag, or as it is
        assert cal.tau_source["lag_corrected_s"] == (lag["tau_s"] if lag["applied"] else None)
        assert ("lag_model" in cal.tau_source) == bool(lag["applied"])
    assert final_snapshots(session)["coils"][-1]["enabled"] == [False, False, False]
    # rig refit of the ramp session applies the lag too, unless told not to
    for flag, expected in (("--lag", True), ("--no-lag", False)):
        out = tmp_path / f"refit{flag}.yaml"
        done = run_rig("refit", str(session), "--dut", "mmc0", flag, "-o", str(out))
        assert done.returncode == 0, done.stderr
        assert ("thermal_lag" in calfile.load(out).stats) is expected


def test_stop_when_good_enough_ends_the_ramp_early_with_its_reason(tmp_path):
    campaign = load_campaign(ramp_plan(tmp_path, stop_when={"S": 5e-3, "b": 100}), SIM_STATION)
    points = compile_plan(campaign.plan, campaign.station)
    session = tmp_path / "s.session"
    outcome = run_campaign(campaign=campaign, session_path=session)
    assert outcome.result.status == "completed" and outcome.result.code == "targets_met"
    counts = session_counts(session)
    assert counts["completed"] and 0 < counts["done"] < len(points)
    assert counts["done"] % 6 == 0  # stopped at the end of a sweep
    codes = query(session, "SELECT kind, code FROM events WHERE code = 'targets_met'")
    assert ("run", "targets_met") in codes
    assert all("error" not in f for f in outcome.fits)
    resumed = run_campaign(session_path=session, resume=True)
    assert "already complete" in resumed.result.reason


def test_kill_9_in_the_middle_of_a_ramp_then_resume_goes_on_without_duplicates(tmp_path):
    plan = ramp_plan(tmp_path, samples=4)
    session = tmp_path / "k.session"
    killed_at(session, plan, SIM_STATION, "point:40")  # well into the up leg
    before = session_counts(session)
    assert before["status"] is None and before["done"] == 40 < before["planned"]
    done_before = {r[0] for r in query(session, "SELECT id FROM points WHERE state = 'done'")}
    last_t = query(session, "SELECT max(t) FROM samples")[0][0]

    resumed = run_rig("run", "--resume", str(session), "--no-live")
    assert resumed.returncode == 0, resumed.stderr
    campaign = load_campaign(plan, SIM_STATION)
    points = compile_plan(campaign.plan, campaign.station)
    after = session_counts(session)
    assert after["completed"] and after["planned"] == after["done"] == len(points)
    assert after["per_point_dut"] == {(p.id, d.name): 4 for p in points for d in campaign.station.duts}
    assert after["orphan_samples"] == 0
    # the points recorded before the kill were not taken again
    retaken = query(session, "SELECT DISTINCT point_id FROM samples WHERE t > ?", last_t)
    assert not {r[0] for r in retaken} & done_before
    # the resumed run went on with the ramp: no second trip to the range start and its stability wait
    kinds = [k for k, _ in events(session)]
    assert kinds.count("stable") == 1 and "stale_lock" in kinds


def test_the_lag_of_a_simulated_temperature_sensor_is_recovered():
    """A TMP117-like reading lagging the element by 150 s (sensor_lag_s) on a 2 degC/min up-and-down
    ramp: calib.thermal.lag finds the lag within a few standard errors and the right direction."""
    clock = SimClock()
    world = World(clock, air_c=0.0, ramp_c_per_min=2.0)
    rng = np.random.default_rng(3)
    truth = DutTruth.random(rng, noise_nt=10.0, thermal_lag_s=400.0)
    truth.sensor_lag_s = 150.0
    world.add_dut("d", truth)
    dirs = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                     [1, 1, 1], [-1, -1, 1], [1, -1, -1], [-1, 1, -1]], float)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t, h, temp, ref = [], [], [], []
    world.set_coil_currents([0, 0, 0])
    for setpoint in (40.0, 0.0):
        world.set_chamber_setpoint(setpoint)
        for _ in range(140):
            for d in dirs:
                world.set_coil_currents(d * 50_000 / 50_000.0)
                clock.sleep(2.0)
                t.append(clock.now())
                ref.append(world.lab_field_nt())
                h.append(0.5 * (world.dut_raw_nt("d", 1) - world.dut_raw_nt("d", -1)))
                temp.append(world.dut_temp_c("d"))
    res = estimate_lag(np.array(t), np.array(h), np.array(temp), np.array(ref), direction="auto")
    assert res.identifiable and res.direction == "sensor_lags", res.message
    assert abs(res.tau_s - 150.0) < max(4 * res.tau_se_s, 15.0), res.message
