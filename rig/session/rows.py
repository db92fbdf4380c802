"""What a session stores per point, and how it goes into the file: the sample rows, the temperature rows of
the cockpit's plot, and a sequential schedule's decisions (their statements run inside the writer's
transactions, rig/session/writer.py)."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from rig.session.schema import DECISIONS_TABLE


@dataclass(frozen=True)
class SampleRow:
    """One recorded reading with the reference it is fitted against."""

    dut: str
    t: float
    field_nt: tuple[float, float, float]
    ref_field_nt: tuple[float, float, float]
    temp_c: float | None = None
    ref_temp_c: float | None = None
    counts: tuple[int, int, int] | None = None
    offset_nt: tuple[float, float, float] | None = None
    flags: frozenset[str] = field(default_factory=frozenset)

    @classmethod
    def from_field_sample(cls, dut: str, sample, ref_field_nt, *, temp_c: float | None = None,
                          ref_temp_c: float | None = None) -> SampleRow:
        """From a drivers.base.FieldSample; `temp_c` overrides the chip's own temperature."""
        return cls(
            dut=dut, t=sample.t, field_nt=tuple(map(float, sample.field_nt)),
            ref_field_nt=tuple(map(float, ref_field_nt)),
            temp_c=sample.temp_c if temp_c is None else temp_c, ref_temp_c=ref_temp_c,
            counts=None if sample.counts is None else tuple(map(int, sample.counts)),
            offset_nt=None if sample.offset_nt is None else tuple(map(float, sample.offset_nt)),
            flags=frozenset(sample.flags),
        )

    def as_params(self, point_id: str) -> tuple:
        """Values for INSERT_SAMPLE, as plain Python numbers (numpy scalars in, SQLite types out)."""
        c = (None,) * 3 if self.counts is None else map(int, self.counts)
        o = (None,) * 3 if self.offset_nt is None else map(float, self.offset_nt)
        return (point_id, self.dut, float(self.t), *map(float, self.field_nt), *c, *o,
                _opt_float(self.temp_c), _opt_float(self.ref_temp_c), *map(float, self.ref_field_nt),
                ",".join(sorted(self.flags)) if self.flags else "")


def _opt_float(value) -> float | None:
    return None if value is None else float(value)


@dataclass(frozen=True)
class TemperatureRow:
    """One line of the cockpit's temperature plot (rig/session/temperature_log.py): the chamber's set point
    (and its
    instantaneous one during a ramp), its air and each DUT's temperature."""

    t: float
    setpoint_c: float | None
    closed_loop_c: float | None
    air_c: float | None
    duts_c: dict[str, float | None]

    def as_params(self) -> tuple:
        return (float(self.t), _opt_float(self.setpoint_c), _opt_float(self.closed_loop_c),
                _opt_float(self.air_c), json.dumps({k: _opt_float(v) for k, v in self.duts_c.items()}))


TEMPERATURES_TABLE = ("CREATE TABLE IF NOT EXISTS temperatures (id INTEGER PRIMARY KEY, "
                      "t REAL NOT NULL, setpoint_c REAL, closed_loop_c REAL, air_c REAL, "
                      "duts_json TEXT NOT NULL DEFAULT '{}')")


INSERT_SAMPLE = (
    "INSERT INTO samples (point_id, dut, t, hx, hy, hz, cx, cy, cz, ox, oy, oz, temp_c, ref_temp_c, "
    "bx, by, bz, flags) VALUES (" + ",".join("?" * 18) + ")"
)


@dataclass(frozen=True)
class Decision:
    """What a sequential schedule decided after a point: its data (JSON-ready) and the points it adds
    (objects with id, index, temp_index, setpoint_c, field_index and target, like rig.core.points.Point)."""

    data: dict
    points: tuple = ()


def insert_temperatures(conn: sqlite3.Connection, rows: list[TemperatureRow]) -> None:
    if rows:
        conn.execute(TEMPERATURES_TABLE)
        conn.executemany("INSERT INTO temperatures (t, setpoint_c, closed_loop_c, air_c, duts_json) "
                         "VALUES (?, ?, ?, ?, ?)", [r.as_params() for r in rows])


def insert_points(conn: sqlite3.Connection, points: Iterable) -> None:
    conn.executemany(
        "INSERT INTO points (id, idx, temp_index, setpoint_c, field_index, target_json) "
        "VALUES (?, ?, ?, ?, ?, ?)",
        ((p.id, p.index, p.temp_index, p.setpoint_c, p.field_index, json.dumps(p.target)) for p in points),
    )


def record_decision(conn: sqlite3.Connection, point_id: str, decision: Decision, t: float) -> None:
    """The decision and its points, inside the caller's transaction (the table is made when first needed)."""
    conn.execute(DECISIONS_TABLE)
    conn.execute("INSERT INTO decisions (t, after_point, decision_json) VALUES (?, ?, ?)",
                 (t, point_id, json.dumps(decision.data, default=json_default)))
    insert_points(conn, decision.points)


def json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return str(value)
