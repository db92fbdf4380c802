"""Campaigns whose ambient (coils) or site field (turntable) is measured by a reference magnetometer: the
demo on sim-measured-ambient.yaml recovers the DUTs as well as with a stated ambient, the measurement
matches the simulated truth within its noise, a drifting world holds the run, and a measured ambient that
makes a point exceed the current limit stops the run before any field is set."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import numpy as np
import pytest
import yaml

from calib.io import calfile
from rig.config import load_station
from rig.config.loading import load_campaign
from rig.devices.simulated.world import dut_truths
from rig.run.campaign import run_campaign
from rig.session.events import Reason
from tests.helpers.statistics import assert_within_std_errors
from tests.system.campaign_helpers import (
    DEMO_PLAN,
    REPO,
    first_point_line,
    popen_rig,
    query,
    run_rig,
    session_counts,
    small_plan,
)

pytestmark = pytest.mark.system

STATION = REPO / "configs" / "stations" / "sim-measured-ambient.yaml"
REFERENCE_CAL = REPO / "configs" / "stations" / "sim-reference-cal.yaml"


def site_events(session: Path) -> list[tuple[str, dict, str]]:
    rows = query(session, "SELECT code, data_json, message FROM events WHERE kind = 'site_field' ORDER BY id")
    return [(code, json.loads(data or "{}"), message) for code, data, message in rows]


def station_variant(tmp_path: Path, change) -> Path:
    """sim-measured-ambient.yaml changed by `change(data)`, in tmp_path (its calibration made absolute)."""
    data = yaml.safe_load(STATION.read_text())
    data["reference_magnetometers"][0]["calibration"] = str(REFERENCE_CAL)
    change(data)
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_demo_with_a_measured_ambient_recovers_every_dut_within_its_standard_errors(tmp_path):
    session = tmp_path / "demo.session"
    proc = run_rig("run", str(DEMO_PLAN), "--station", str(STATION), "--session", str(session), "--no-live")
    assert proc.returncode == 0, proc.stderr
    counts = session_counts(session)
    assert counts["completed"] and counts["done"] == counts["planned"] == 4 * 26  # demo: 4 steps x 26 fields

    station = load_station(STATION)
    truth = np.asarray(station.sim.ambient_nt)
    assert station.field_source.ambient_nt == "measure"
    measured = site_events(session)
    codes = [code for code, _, _ in measured]
    assert codes == [Reason.SITE_FIELD_MEASURED] + [Reason.SITE_FIELD_CHECKED] * 5  # start, every step, end
    first = measured[0][1]
    se = np.asarray(first["std_error_nt"])
    assert first["n"] == 100 and np.all(se > 0) and np.all(se < 5)
    assert np.all(np.abs(np.asarray(first["vector_nt"]) - truth) < 4 * se + 1.0)  # + the 0.06 mG LSB

    found = {}
    for dut, t in dut_truths(station).items():
        cal = calfile.load(tmp_path / f"demo.{dut}.t24.yaml")
        for key, true in (("S", t.S), ("K", t.K), ("b_nt", t.b_nt), ("kb_nt_per_c", t.kb_nt_per_c)):
            found[f"{dut} {key}"] = (np.asarray(cal.params[key]) - true) / np.asarray(cal.std_errors[key])
    assert_within_std_errors(found)
    assert "sitefield" not in {d for (_, d) in counts["per_point_dut"]}  # not a DUT in the outputs
    assert not list(tmp_path.glob("demo.sitefield.*"))


def test_a_drifting_ambient_holds_the_run_at_a_temperature_step(tmp_path):
    def drifting(data):
        data["sim"]["ambient_drift_nt_per_h"] = [3000, 0, 0]  # 50 nT a minute: beyond 200 nT within a step

    campaign = load_campaign(small_plan(tmp_path, samples=2), station_variant(tmp_path, drifting))
    session = tmp_path / "drift.session"
    outcome = run_campaign(campaign=campaign, session_path=session, max_retakes=1, hold_wait_s=1.0)
    assert outcome.result.status == "aborted" and outcome.result.code == Reason.RETAKES_EXHAUSTED
    assert "ambient field" in outcome.result.reason and "limit 200 nT" in outcome.result.reason
    holds = query(session, "SELECT code, device FROM events WHERE kind = 'hold'")
    assert holds == [(Reason.SITE_FIELD_DRIFT.value, "sitefield")]
    drift = [data for code, data, _ in site_events(session) if code == Reason.SITE_FIELD_DRIFT]
    assert len(drift) == 2 and all(d["change_size_nt"] > d["limit_nt"] == 200 for d in drift)
    assert drift[0]["change_nt"][0] > 200 and abs(drift[0]["change_nt"][1]) < 10  # the drift's own axis
    assert session_counts(session)["done"] == 0  # no point was taken with a stale ambient


def test_a_measured_ambient_beyond_the_current_limit_stops_before_any_field(tmp_path):
    def strong(data):
        data["sim"]["ambient_nt"] = [0, 0, 62000]  # -z at 50 uT then needs 2.24 A, above max 2 A

    session = tmp_path / "strong.session"
    proc = run_rig("run", str(DEMO_PLAN), "--station", str(station_variant(tmp_path, strong)),
                   "--session", str(session), "--no-live")
    assert proc.returncode == 2, proc.stderr
    line = proc.stderr.strip()
    assert len(line.splitlines()) == 1 and "Traceback" not in line
    assert "the measured ambient" in line and "max_current_a 2 A" in line and "coil z" in line
    counts = session_counts(session)
    assert counts["status"] == "failed" and counts["done"] == 0
    assert query(session, "SELECT count(*) FROM samples")[0][0] == 0
    assert [code for code, _, _ in site_events(session)] == [Reason.SITE_FIELD_MEASURED]


def test_a_missing_reference_calibration_is_refused_in_one_located_line(tmp_path):
    def missing(data):
        data["reference_magnetometers"][0]["calibration"] = "no-such-cal.yaml"

    station = station_variant(tmp_path, missing)
    session = tmp_path / "s.session"
    proc = run_rig("run", str(small_plan(tmp_path, samples=2)), "--station", str(station),
                   "--session", str(session), "--no-live")
    assert proc.returncode == 2
    line = proc.stderr.strip()
    assert line.startswith(f"error: {station}: reference_magnetometers[0].calibration: ")
    assert "no-such-cal.yaml: calibration file not found" in line and "(line " in line
    assert not session.exists()


def test_a_turntable_with_a_reference_magnetometer_measures_the_site_field(tmp_path):
    site_truth = [18000.0, -1200.0, 46000.0]

    def table(data):
        data["sim"]["site_field_nt"] = site_truth
        data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"}, "rate_deg_s": 20,
                                "site_field": {"reference_magnetometer": "sitefield"}}

    plan = yaml.safe_load(small_plan(tmp_path, samples=3).read_text())
    plan["fields"] = {"kind": "grid", "az_deg": [0, 90, 180, 270], "el_deg": [0, 90, 180, -90]}
    plan["fit"] = {"models": ["t24"]}
    plan_path = tmp_path / "table.yaml"
    plan_path.write_text(yaml.safe_dump(plan, sort_keys=False))
    campaign = load_campaign(plan_path, station_variant(tmp_path, table))
    session = tmp_path / "table.session"
    outcome = run_campaign(campaign=campaign, session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    measured = site_events(session)
    assert [c for c, _, _ in measured] == [Reason.SITE_FIELD_MEASURED] + [Reason.SITE_FIELD_CHECKED] * 3
    first = measured[0][1]
    assert "site field" in measured[0][2]
    error = np.abs(np.asarray(first["vector_nt"]) - site_truth)
    assert np.all(error < 4 * np.asarray(first["std_error_nt"]) + 1.0)
    # every sample's reference is the measured site field turned into the table frame: |B| is its norm
    refs = np.array(query(session, "SELECT bx, by, bz FROM samples"))
    assert np.allclose(np.linalg.norm(refs, axis=1), np.linalg.norm(first["vector_nt"]), atol=1e-6)
    assert all(f.get("error") is None for f in outcome.fits)


def test_a_resumed_run_measures_again_with_the_calibration_beside_the_recorded_station(tmp_path):
    session = tmp_path / "resume.session"
    proc = popen_rig("run", str(small_plan(tmp_path, samples=5)), "--station", str(STATION),
                     "--session", str(session), "--no-live")
    first = first_point_line(proc)
    assert "done" in first, proc.stderr.read()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    resumed = run_rig("run", "--resume", str(session), "--no-live")  # calibration path relative to STATION
    assert resumed.returncode == 0, resumed.stderr
    assert session_counts(session)["completed"]
    measured = [code for code, _, _ in site_events(session) if code == Reason.SITE_FIELD_MEASURED]
    assert len(measured) == 2  # at the start, and at the start of the resumed run
