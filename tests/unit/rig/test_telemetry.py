"""The temperatures a run logs for the cockpit: a row per EVERY_S of the run's clock, written with the
next point or on their own once the oldest has waited FLUSH_S; read back in order and after a given
row; sessions from before the table read as having none."""

from __future__ import annotations

from types import SimpleNamespace

from drivers.chamber import ChamberReading
from drivers.clock import SimClock
from rig.session.reader import SessionReader
from rig.session.temperature_log import EVERY_S, FLUSH_S, TemperatureLog
from rig.session.writer import Session


def new_session(path):
    points = [SimpleNamespace(id="T01-F01", index=0, temp_index=1, setpoint_c=25.0, field_index=1,
                              target={"field_nt": [1.0, 0.0, 0.0]})]
    return Session.create(path, plan_text="p", station_text="s", plan_name="p", station_name="s",
                          points=points, simulated={"chamber": True}, clock=SimClock())


def reading(t: float, air_c: float, closed_loop_c: float | None = None) -> ChamberReading:
    return ChamberReading(t, air_c, 60.0, False, False, closed_loop_c=closed_loop_c)


def rows_of(path) -> list[dict]:
    with SessionReader(path) as reader:
        return reader.temperatures()


def test_a_row_per_interval_written_in_batches_during_a_wait(tmp_path):
    path = tmp_path / "s.session"
    with new_session(path) as session:
        log = TemperatureLog(session)
        for i in range(10):  # a poll every 10 s for 90 s: rows at 0, 30, 60 and 90 s
            log.note(reading(1000.0 + 10 * i, 20.0 + i, closed_loop_c=21.0 + i),
                     {"dut1": 19.0 + i, "dut2": None})
            assert len(rows_of(path)) == (0 if 10 * i < FLUSH_S else 4)
        for i in range(10, 13):
            log.note(reading(1000.0 + 10 * i, 20.0 + i), {"dut1": 1.0})
        assert len(rows_of(path)) == 4 + 1 and len(log.pending) == 0  # 120 s: the 2nd batch (one row)
    rows = rows_of(path)
    assert [r["t"] - 1000.0 for r in rows] == [0.0, EVERY_S, 2 * EVERY_S, 3 * EVERY_S, 4 * EVERY_S]
    assert rows[1]["air_c"] == 23.0 and rows[1]["closed_loop_c"] == 24.0 and rows[1]["setpoint_c"] == 60.0
    assert rows[1]["duts"] == {"dut1": 22.0, "dut2": None}
    with SessionReader(path) as reader:
        assert [r["t"] for r in reader.temperatures(after_row=rows[1]["row"])] == [r["t"] for r in rows[2:]]


def test_rows_ride_along_with_the_next_point(tmp_path):
    path = tmp_path / "s.session"
    with new_session(path) as session:
        log = TemperatureLog(session)
        log.note(reading(0.0, 20.0), {"dut1": 19.0})
        log.note(reading(EVERY_S, 21.0), {"dut1": 19.5})
        session.record_point("T01-F01", [], temperatures=log.take())
        assert log.pending == []
    assert [r["air_c"] for r in rows_of(path)] == [20.0, 21.0]


def test_a_session_without_the_table_has_no_temperatures(tmp_path):
    path = tmp_path / "s.session"
    new_session(path).close()
    assert rows_of(path) == []


def test_a_batch_that_cannot_be_written_does_not_end_the_run(tmp_path, caplog):
    path = tmp_path / "s.session"
    session = new_session(path)
    session.close()  # every write now fails, as on a full disk
    log = TemperatureLog(session)
    for t in (0.0, 30.0, 60.0, 90.0, 120.0, 240.0, 360.0):  # two batches: 0..120 s, 240 and 360 s
        log.note(reading(t, 20.0), {})
    assert log.lost == 7 and log.pending == []
    assert sum("could not record temperatures" in r.getMessage() for r in caplog.records) == 1
