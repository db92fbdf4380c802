"""The temperatures a run logs for the cockpit: at most one row per EVERY_S of the run's clock, read back
in order and after a given row; sessions from before the table read as having none."""

from __future__ import annotations

from types import SimpleNamespace

from drivers.chamber import ChamberReading
from drivers.clock import SimClock
from rig.reader import SessionReader
from rig.store import Session
from rig.telemetry import EVERY_S, TemperatureLog


def new_session(path):
    points = [SimpleNamespace(id="T01-F01", index=0, temp_index=1, setpoint_c=25.0, field_index=1,
                              target={"field_nt": [1.0, 0.0, 0.0]})]
    return Session.create(path, plan_text="p", station_text="s", plan_name="p", station_name="s",
                          points=points, simulated={"chamber": True}, clock=SimClock())


def reading(t: float, air_c: float, closed_loop_c: float | None = None) -> ChamberReading:
    return ChamberReading(t, air_c, 60.0, False, False, closed_loop_c=closed_loop_c)


def test_one_row_per_interval_of_the_run_clock(tmp_path):
    path = tmp_path / "s.session"
    with new_session(path) as session:
        log = TemperatureLog(session)
        for i in range(10):  # a poll every 10 s for 90 s: rows at 0, 30, 60 and 90 s
            log.note(reading(1000.0 + 10 * i, 20.0 + i, closed_loop_c=21.0 + i),
                     {"dut1": 19.0 + i, "dut2": None})
    with SessionReader(path) as reader:
        rows = reader.temperatures()
        assert [r["t"] - 1000.0 for r in rows] == [0.0, EVERY_S, 2 * EVERY_S, 3 * EVERY_S]
        assert rows[1]["air_c"] == 23.0 and rows[1]["closed_loop_c"] == 24.0 and rows[1]["setpoint_c"] == 60.0
        assert rows[1]["duts"] == {"dut1": 22.0, "dut2": None}
        assert [r["t"] for r in reader.temperatures(after_row=rows[1]["row"])] == [rows[2]["t"], rows[3]["t"]]


def test_a_session_without_the_table_has_no_temperatures(tmp_path):
    path = tmp_path / "s.session"
    new_session(path).close()
    with SessionReader(path) as reader:
        assert reader.temperatures() == []


def test_a_row_that_cannot_be_written_does_not_end_the_run(tmp_path, caplog):
    path = tmp_path / "s.session"
    session = new_session(path)
    session.close()  # every write now fails, as on a full disk
    log = TemperatureLog(session)
    log.note(reading(0.0, 20.0), {})
    log.note(reading(100.0, 20.0), {})
    assert log.lost == 2
    assert sum("could not record temperatures" in r.getMessage() for r in caplog.records) == 1
