"""A session file written the way version 1 of the store wrote it (before typed events): its schema
verbatim, untyped events whose only reason is their wording. For the compatibility tests."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

APPLICATION_ID = 0x4D475247

V1_SCHEMA = """
CREATE TABLE session (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    plan_name TEXT NOT NULL, station_name TEXT NOT NULL,
    plan_text TEXT NOT NULL, station_text TEXT NOT NULL,
    plan_path TEXT, station_path TEXT,
    software_version TEXT NOT NULL, operator TEXT,
    simulated_json TEXT NOT NULL,          -- {device name: true if simulated}
    started REAL NOT NULL, ended REAL,     -- on the run's clock (simulated time in a simulation)
    wall_started REAL NOT NULL, wall_ended REAL,  -- wall-clock time, always
    exit_status TEXT, exit_reason TEXT,    -- e.g. completed / aborted / interrupted / failed
    completed INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE points (
    id TEXT PRIMARY KEY,                   -- T03-F07
    idx INTEGER NOT NULL UNIQUE,
    temp_index INTEGER NOT NULL, setpoint_c REAL NOT NULL,
    field_index INTEGER NOT NULL, target_json TEXT NOT NULL,
    state TEXT NOT NULL DEFAULT 'planned' CHECK (state IN ('planned', 'done', 'failed')),
    settle_json TEXT, reason TEXT,
    started REAL, finished REAL
);
CREATE TABLE samples (
    id INTEGER PRIMARY KEY,
    point_id TEXT NOT NULL REFERENCES points(id),
    dut TEXT NOT NULL, t REAL NOT NULL,
    hx REAL NOT NULL, hy REAL NOT NULL, hz REAL NOT NULL,      -- raw reading, nT
    cx INTEGER, cy INTEGER, cz INTEGER,                       -- raw counts
    ox REAL, oy REAL, oz REAL,                                -- SET/RESET bridge offset, nT
    temp_c REAL, ref_temp_c REAL,                             -- DUT temperature, reference sensor
    bx REAL NOT NULL, by REAL NOT NULL, bz REAL NOT NULL,     -- reference field, nT
    flags TEXT NOT NULL DEFAULT ''                            -- comma-separated, flagged rows are not fitted
);
CREATE INDEX samples_by_dut ON samples(dut, point_id);
CREATE TABLE snapshots (
    id INTEGER PRIMARY KEY, t REAL NOT NULL, device TEXT NOT NULL, describe_json TEXT NOT NULL
);
CREATE TABLE events (
    id INTEGER PRIMARY KEY, t REAL NOT NULL, level TEXT NOT NULL, device TEXT, kind TEXT NOT NULL,
    message TEXT NOT NULL, data_json TEXT NOT NULL DEFAULT '{}'
);
CREATE TABLE fits (
    id INTEGER PRIMARY KEY, t REAL NOT NULL, dut TEXT NOT NULL, model TEXT NOT NULL,
    calibration_json TEXT NOT NULL, residual_rms_nt REAL
);
"""

PLAN_TEXT = "name: old\n"
STATION_TEXT = "name: oldstation\n"
POINTS = [("T01-F01", 0, 1, 10.0, 1), ("T01-F02", 1, 1, 10.0, 2), ("T02-F01", 2, 2, 40.0, 1),
          ("T02-F02", 3, 2, 40.0, 2)]
# (kind, level, device, message, data) exactly as version 1 worded them
EVENTS = [
    ("start", "INFO", None, "started with every device made safe; simulated: {}", {}),
    ("run", "INFO", None, "4 of 4 points to take", {}),
    ("warning", "WARNING", "coils", "coils: read: try 1 of 3 failed", {"logger": "magrig.transport"}),
    ("hold", "INFO", None,
     "point T02-F01: dut1 not stable at 40 degC within max_wait_s 10800 s; retake 1 of 3",
     {"point_id": "T02-F01", "reason": "dut1 not stable at 40 degC within max_wait_s 10800 s"}),
    ("hold", "INFO", None, "point T02-F02: chamber alarm; retake 1 of 3",
     {"point_id": "T02-F02", "reason": "chamber alarm"}),
    ("pause", "INFO", None, "paused at point T02-F02 (not recorded yet)", {"point_id": "T02-F02"}),
    ("safe_state", "INFO", None, "all devices safe", {"failed": []}),
    ("exit", "INFO", None, "completed: all 4 points taken", {"status": "completed"}),
]


def write_v1_session(path: Path, samples_per_point: int = 4) -> None:
    """A completed version 1 session: 4 points of one DUT (dut1), the events above, one fit."""
    conn = sqlite3.connect(path, isolation_level=None)
    conn.execute("PRAGMA journal_mode = WAL")
    conn.execute("BEGIN")
    for statement in V1_SCHEMA.split(";"):
        if statement.strip():
            conn.execute(statement)
    conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
    conn.execute("PRAGMA user_version = 1")
    conn.execute(
        "INSERT INTO session (id, plan_name, station_name, plan_text, station_text, software_version, "
        "operator, simulated_json, started, ended, wall_started, wall_ended, exit_status, exit_reason, "
        "completed) VALUES (1, 'old', 'oldstation', ?, ?, '0.0.9', 'op', '{\"coils\": true}', 0, 100, "
        "1.7e9, 1.7e9 + 100, 'completed', 'all 4 points taken', 1)", (PLAN_TEXT, STATION_TEXT))
    for pid, idx, ti, setpoint, fi in POINTS:
        conn.execute("INSERT INTO points (id, idx, temp_index, setpoint_c, field_index, target_json, state, "
                     "settle_json) VALUES (?, ?, ?, ?, ?, '{}', 'done', ?)",
                     (pid, idx, ti, setpoint, fi, json.dumps({"waited_s": 600.0})))
        for k in range(samples_per_point):
            conn.execute("INSERT INTO samples (point_id, dut, t, hx, hy, hz, temp_c, bx, by, bz) "
                         "VALUES (?, 'dut1', ?, ?, ?, ?, ?, ?, ?, ?)",
                         (pid, idx * 10.0 + k, 1000.0 * fi, 2.0 * k, -3.0, setpoint, 1000.0 * fi, 0.0, 0.0))
    for i, (kind, level, device, message, data) in enumerate(EVENTS):
        conn.execute("INSERT INTO events (t, level, device, kind, message, data_json) "
                     "VALUES (?, ?, ?, ?, ?, ?)", (float(i), level, device, kind, message, json.dumps(data)))
    conn.execute("INSERT INTO fits (t, dut, model, calibration_json, residual_rms_nt) "
                 "VALUES (99, 'dut1', 't24', '{}', 12.5)")
    conn.execute("COMMIT")
    conn.close()
