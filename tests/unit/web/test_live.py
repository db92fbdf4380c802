"""The cockpit's live view of a session file: it reads only what is new since it last looked, gives each
client what that client has not seen, and its running fit is the run's own (rig/analysis/livefit.py)."""

from __future__ import annotations

import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from calib import synthetic
from drivers.chamber import ChamberReading
from drivers.clock import SimClock
from rig.analysis.livefit import LiveFit
from rig.session.events import Kind, Reason
from rig.session.rows import SampleRow, TemperatureRow
from rig.session.writer import Session
from rig.web.live import Cursor, LiveSession

REPO = Path(__file__).resolve().parents[3]
TEMPS_C = (0.0, 40.0)


@pytest.fixture
def writer(tmp_path):
    """A session with a real plan (acceptance: fit RMS at most 1 nT) being written point by point."""
    rng = np.random.default_rng(3)
    dirs = synthetic.coil_directions(14, rng)
    ds, _ = synthetic.t24_dataset(rng, temps_c=TEMPS_C, directions=dirs, samples_per_point=4, noise_nt=20.0)
    plan_text = (REPO / "configs/plans/demo.yaml").read_text() + "acceptance:\n  max_rms_nt: 1.0\n"
    station_text = (REPO / "configs/stations/sim.yaml").read_text()
    points = [SimpleNamespace(id=f"T{t + 1:02d}-F{f + 1:02d}", index=t * len(dirs) + f, temp_index=t + 1,
                              setpoint_c=TEMPS_C[t], field_index=f + 1, target={"field_nt": list(50000 * d)})
              for t in range(len(TEMPS_C)) for f, d in enumerate(dirs)]
    clock = SimClock()
    session = Session.create(tmp_path / "live.session", plan_text=plan_text, station_text=station_text,
                             plan_name="demo", station_name="sim", points=points,
                             simulated={"chamber": True}, clock=clock)

    def take(n: int) -> None:
        for p in [p for p in points if p.id not in session.done_point_ids()][:n]:
            clock.sleep(60.0)
            rows = [SampleRow("mmc0", clock.now(), tuple(ds.h_nt[i]), tuple(ds.ref_nt[i]),
                              float(ds.temp_c[i])) for i in range(p.index * 4, p.index * 4 + 4)]
            session.record_point(p.id, rows, temperatures=[
                TemperatureRow(clock.now(), p.setpoint_c, None, p.setpoint_c + 0.3, {"mmc0": 1.0})])

    session.take, session.ds = take, ds
    yield session
    session.close()


def test_each_client_gets_everything_once_then_only_what_is_new(writer):
    live = LiveSession(writer.path)
    writer.take(3)
    writer.log_event(Kind.STABLE, "stable at 0 degC", code=Reason.STABLE)
    assert live.refresh() and not live.refresh()  # nothing changed: the file is not even opened
    first, late = Cursor(), Cursor()
    msg = live.message(first)
    assert msg["reset"] and msg["new_points"] == ["T01-F01", "T01-F02", "T01-F03"]
    assert len(msg["telemetry"]) == 3 and [e["kind"] for e in msg["events"]] == ["stable"]
    writer.take(2)
    assert live.refresh()
    msg = live.message(first)
    assert not msg["reset"] and msg["new_points"] == ["T01-F04", "T01-F05"]
    assert len(msg["telemetry"]) == 2 and msg["events"] == []
    assert len(live.message(late)["new_points"]) == 5  # a page opened later gets it all
    assert live.message(first)["new_points"] == []


def test_the_running_fit_equals_the_runs_own_and_judges_the_plans_limit(writer):
    live = LiveSession(writer.path)
    writer.take(10)
    live.refresh()
    writer.take(100)  # the rest: both temperatures, so T24 can be identified
    live.refresh()
    own = LiveFit(float(np.mean(TEMPS_C)))
    own.add(writer.ds.h_nt, writer.ds.temp_c, writer.ds.ref_nt)
    dut = live.summary["duts"][0]
    assert dut["name"] == "mmc0" and dut["n"] == len(writer.ds)
    assert dut["rms_nt"] == pytest.approx(own.figures()["rms_nt"], rel=1e-9)
    assert dut["rms_nt"] > 1.0
    assert dut["verdict"] == f"likely FAIL: running fit RMS {dut['rms_nt']:.1f} nT > 1 nT fit limit"
    assert live.summary["duts"][1]["verdict"] == "pending (judged at the end)"  # serial0: no samples
    # every DUT of the station, sampled or not
    assert [d["name"] for d in live.summary["duts"]] == ["mmc0", "serial0"]


def test_a_run_holding_the_lock_is_running_with_its_current_point(writer):
    live = LiveSession(writer.path)
    writer.take(2)
    live.refresh()
    assert live.summary["run"]["state"] == "not running" and live.summary["progress"]["current"] is None
    Path(f"{writer.path}.lock").write_text(f"{os.getpid()}\n")
    assert live.refresh()  # the run's lock alone counts as a change
    progress = live.summary["progress"]
    assert live.summary["run"] == {**live.summary["run"], "state": "running", "pid": os.getpid()}
    assert progress["current"]["id"] == "T01-F03" and progress["done"] == 2
    assert progress["eta_run_s"] == pytest.approx(60.0 * (progress["planned"] - 2))
    writer.finish("aborted", "paused at T01-F03 at the request of web client 127.0.0.1",
                  code=Reason.OPERATOR_PAUSE)
    Path(f"{writer.path}.lock").unlink()
    live.refresh()
    assert live.summary["run"]["state"] == "paused"


def test_a_chamber_reading_row_is_what_the_plot_gets(writer):
    from rig.session.temperature_log import TemperatureLog

    live = LiveSession(writer.path)
    log = TemperatureLog(writer)
    log.note(ChamberReading(5.0, 21.5, 40.0, False, False, closed_loop_c=22.0), {"mmc0": 20.9})
    log.flush()
    live.refresh()
    assert live.message(Cursor())["telemetry"] == [[5.0, 40.0, 22.0, 21.5, {"mmc0": 20.9}]]
