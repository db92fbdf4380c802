"""The live view of one session file, kept up to date from the file alone, read-only.

    hub = Hub()
    live = hub.subscribe(path)         # a watcher thread polls the file's size and times every POLL_S
    message = live.message(cursor)     # what this client has not seen yet (all of it the first time)
    live.wait(cursor, timeout_s)       # until there is something new
    hub.unsubscribe(live)

A commit shows as a change of the session's write-ahead log (or of the file itself, or of the run that
holds its lock); only then is the file opened, through rig.session.reader.SessionReader, and only what is new
is read: points that became done (and their samples, for each DUT's running T24 fit), events after the last
one seen, temperature rows after the last time seen. The campaign process is never waited for: a reader beside
SQLite's writer costs the writer nothing.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rig.analysis.livefit import LiveFit
from rig.core.errors import ERRORS
from rig.session.inbox import running_pid
from rig.session.reader import SessionReader

log = logging.getLogger("magrig.web")

POLL_S = 0.5  # how often a watched session's files are looked at (a stat each)
FIRST_EVENTS = 300  # events a new page gets; it keeps the newest as more arrive
IDLE_STOP_S = 5.0  # a watcher with no page left stops after this


@dataclass
class Cursor:
    """What one client has been sent."""

    version: int = 0
    telemetry: int = 0
    events: int = 0
    done: int = 0


def _stat(path: Path) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size


class LiveSession:
    def __init__(self, path: Path):
        self.path = path
        self.cond = threading.Condition()
        self.version = 0
        self.signature: tuple | None = None
        self.error: str | None = None
        self.static: dict | None = None
        self.fits: dict[str, LiveFit] = {}
        self.done: set[str] = set()
        self.done_order: list[str] = []
        self.telemetry: list[list] = []  # [t, setpoint_c, closed_loop_c, air_c, {dut: temp_c}]
        self.events: list[dict] = []
        self.last_event_id = 0
        self.last_temperature_row = 0
        self.reading = threading.Lock()  # the watcher and a new page's first look must not read at once
        self.summary: dict = {}
        self.seen: list[tuple[float, int]] = []  # (wall time, points done) when a change was seen
        self.subscribers = 0
        self.thread: threading.Thread | None = None

    # --- reading ------------------------------------------------------------------------------------
    def _signature(self) -> tuple:
        return (_stat(self.path), _stat(Path(f"{self.path}-wal")), running_pid(self.path))

    def refresh(self) -> bool:
        """Read what is new if the files changed; True when something was read."""
        with self.reading:
            signature = self._signature()
            if signature == self.signature:
                return False
            try:
                with SessionReader(self.path) as reader:
                    self._read(reader)
            except (*ERRORS, OSError, ValueError) as exc:  # mid-checkpoint, or the run just ended: next time
                with self.cond:
                    self.error = str(exc)
                return False
            with self.cond:
                self.signature = signature
                self.error = None
                self.version += 1
                self.cond.notify_all()
            return True

    def _read(self, reader: SessionReader) -> None:
        info = reader.info()
        points = reader.points()
        if self.static is None:
            self.static = _static(info, points)
            self.fits = {}
        new = [p["id"] for p in points if p["state"] == "done" and p["id"] not in self.done]
        samples = reader.samples_of(new) if new else []
        events = reader.events(self.last_event_id)
        temperatures = reader.temperatures(self.last_temperature_row)
        verdicts = {r["dut"]: r["verdict"] for r in reader.acceptance()}
        pid = running_pid(self.path)
        with self.cond:
            self._feed_fits(samples)
            self.done.update(new)
            self.done_order += new
            self.telemetry += [[r["t"], r["setpoint_c"], r["closed_loop_c"], r["air_c"], r["duts"]]
                               for r in temperatures]
            if temperatures:
                self.last_temperature_row = temperatures[-1]["row"]
            self.events += [_event(e) for e in events]
            if events:
                self.last_event_id = events[-1].id
            if new or not self.seen:
                self.seen = (self.seen + [(time.time(), len(self.done))])[-50:]
            self.summary = self._summary(info, points, verdicts, pid)

    def _feed_fits(self, samples: list[dict]) -> None:
        by_dut: dict[str, list[dict]] = {}
        for s in samples:
            if not s["flags"] and s["temp"] is not None:
                by_dut.setdefault(s["dut"], []).append(s)
        for dut, rows in by_dut.items():
            fit = self.fits.setdefault(dut, LiveFit(self.static["temp_ref_c"]))
            fit.add(np.array([[r["hx"], r["hy"], r["hz"]] for r in rows], float),
                    np.array([r["temp"] for r in rows], float),
                    np.array([[r["bx"], r["by"], r["bz"]] for r in rows], float))

    def _summary(self, info: dict, points: list[dict], verdicts: dict, pid: int | None) -> dict:
        done = [p for p in points if p["state"] == "done"]
        left = [p for p in points if p["state"] != "done"]
        current = left[0] if (left and pid is not None) else None
        last_temps = self.telemetry[-1][4] if self.telemetry else {}
        duts = sorted(set(self.fits) | set(last_temps) | set(verdicts) | set(self.static["duts"]))
        return {
            "session": self.path.name,
            "plan": info["plan_name"],
            "station": info["station_name"],
            "simulated": bool(info["simulated"]) and all(info["simulated"].values()),
            "run": _run_state(info, pid),
            "progress": {
                "done": len(done), "planned": len(points),
                "failed": sum(p["state"] == "failed" for p in points),
                "current": None if current is None else {
                    "id": current["id"], "setpoint_c": current["setpoint_c"],
                    "target": json.loads(current["target_json"] or "null")},
                "eta_run_s": _eta_run_s(done, len(left), info["started"]),
                "eta_wall_s": self._eta_wall_s(len(left)) if pid is not None else None,
                "postrun": self._postrun() if pid is not None and not left else None,
            },
            "duts": [self._dut(d, last_temps.get(d), verdicts.get(d)) for d in duts],
            "t0": info["started"],
        }

    def _postrun(self) -> str | None:
        """What the post-run fits last recorded (rig/analysis/fitprogress.py): which DUT and model."""
        return next((e["message"] for e in reversed(self.events) if e["kind"] == "postrun"), None)

    def _dut(self, name: str, temp_c, verdict: str | None) -> dict:
        """A recorded verdict, or before it (the run judges at its end) what the running fit says: its
        RMS beyond the plan's fit limit, or beyond its held-out limit (a held-out RMS is seldom below the
        fit's own), is a FAIL coming."""
        figures = self.fits[name].figures() if name in self.fits else {"n": 0, "rms_nt": None}
        if verdict is None and self.static["acceptance"]:
            rms = figures["rms_nt"]
            over = [f"{rms:.1f} nT > {limit:g} nT {what} limit" for what, limit in self.static["limits_nt"]
                    if rms is not None and rms > limit]
            verdict = f"likely FAIL: running fit RMS {over[0]}" if over else "pending (judged at the end)"
        return {"name": name, "temp_c": temp_c, "n": figures["n"], "rms_nt": figures["rms_nt"],
                "verdict": verdict or "-"}

    def _eta_wall_s(self, left: int) -> float | None:
        """At the pace this server has seen points arrive (at least two observations apart)."""
        if len(self.seen) < 2 or left == 0:
            return None
        (t0, n0), (t1, n1) = self.seen[0], self.seen[-1]
        return None if n1 <= n0 else (t1 - t0) / (n1 - n0) * left

    # --- clients --------------------------------------------------------------------------------------
    def message(self, cursor: Cursor) -> dict:
        """Everything `cursor` has not seen (a first message holds the whole state); advances it."""
        with self.cond:
            first = cursor.version == 0
            events = self.events[-FIRST_EVENTS:] if first else self.events[cursor.events:]
            msg = {"reset": first, "version": self.version, "summary": self.summary, "error": self.error,
                   "telemetry": self.telemetry[cursor.telemetry:], "events": events,
                   "new_points": self.done_order[cursor.done:]}
            cursor.version, cursor.telemetry = self.version, len(self.telemetry)
            cursor.events, cursor.done = len(self.events), len(self.done_order)
        return msg

    def wait(self, cursor: Cursor, timeout_s: float, stopping: threading.Event) -> bool:
        """Until the state moved past what `cursor` has seen (True) or `timeout_s` passed (False)."""
        with self.cond:
            return self.cond.wait_for(lambda: self.version != cursor.version or stopping.is_set(),
                                      timeout_s) and not stopping.is_set()


def _static(info: dict, points: list[dict]) -> dict:
    """What never changes during a run: the DUTs, the live fit's reference temperature (as the run's own
    live display takes it) and the plan's acceptance limits on the fit and held-out RMS, if any."""
    from rig import config as cfg
    from rig.core.yamlload import load_model

    acceptance, limits, duts = False, [], []
    with contextlib.suppress(*ERRORS, ValueError):
        plan = load_model(cfg.Plan, "recorded plan", info["plan_text"])
        if plan.acceptance is not None:
            acceptance = True
            limits = [(what, limit) for what, limit in (("fit", plan.acceptance.max_rms_nt),
                                                        ("held-out", plan.acceptance.max_heldout_rms_nt))
                      if limit is not None]
    with contextlib.suppress(*ERRORS, ValueError):
        duts = [d.name for d in load_model(cfg.Station, "recorded station", info["station_text"]).duts]
    temps = [p["setpoint_c"] for p in points] or [25.0]
    return {"temp_ref_c": float(np.mean(temps)), "acceptance": acceptance, "limits_nt": limits, "duts": duts}


def _run_state(info: dict, pid: int | None) -> dict:
    """running (a live process holds the lock), or how the run ended as the session recorded it."""
    if pid is not None:
        state = "running"
    elif info["exit_status"] is None:
        state = "not running"  # killed, or never started: nothing recorded how it ended
    elif info["exit_code"] == "operator_pause":
        state = "paused"
    else:
        state = info["exit_status"]
    return {"state": state, "pid": pid, "exit_status": info["exit_status"],
            "exit_reason": info["exit_reason"], "exit_code": info["exit_code"],
            "completed": bool(info["completed"])}


def _eta_run_s(done: list[dict], left: int, started: float) -> float | None:
    """On the run's clock: the mean time from one point's end to the next so far, times the points left
    (a resume restarts a simulated clock: steps backwards are left out)."""
    ends = sorted(p["finished"] for p in done if p["finished"] is not None)
    steps = [b - a for a, b in zip([started, *ends], ends, strict=False) if b > a]
    return float(np.mean(steps)) * left if steps and left else None


def _event(e) -> dict:
    return {"id": e.id, "t": e.t, "level": e.level, "kind": e.kind, "code": e.code.value,
            "message": e.message, "point": e.point_id, "device": e.device}


def warm_up() -> None:
    """What a first live view needs that is slow the first time in a process (the plan models, the
    compiled Gram kernel of the running fit: about a second): done ahead, so the first points a page
    waits for are not late by it."""
    from rig import config  # noqa: F401 - imported for its cost only

    fit = LiveFit(20.0)
    fit.add(np.eye(3) * 5e4, np.array([10.0, 20.0, 30.0]), np.eye(3) * 5e4)
    fit.figures()


class Hub:
    """One LiveSession per watched file, shared by every page watching it; a thread per file polls it."""

    def __init__(self, poll_s: float = POLL_S):
        self.poll_s = poll_s
        self.lock = threading.Lock()
        self.sessions: dict[Path, LiveSession] = {}
        self.stopping = threading.Event()
        threading.Thread(target=warm_up, daemon=True, name="warm up").start()

    def subscribe(self, path: Path) -> LiveSession:
        with self.lock:
            live = self.sessions.get(path)
            if live is None:
                live = self.sessions[path] = LiveSession(path)
            live.subscribers += 1
            if live.thread is None:
                live.thread = threading.Thread(target=self._watch, args=(live,), daemon=True,
                                               name=f"watch {path.name}")
                live.thread.start()
        live.refresh()  # a first state for the new page (the watcher may be mid-sleep)
        return live

    def unsubscribe(self, live: LiveSession) -> None:
        with self.lock:
            live.subscribers -= 1

    def _watch(self, live: LiveSession) -> None:
        idle_since: float | None = None
        while not self.stopping.wait(self.poll_s):
            with self.lock:
                if live.subscribers > 0:
                    idle_since = None
                elif idle_since is None:
                    idle_since = time.monotonic()
                elif time.monotonic() - idle_since > IDLE_STOP_S:
                    live.thread = None
                    del self.sessions[live.path]
                    return
            try:
                live.refresh()
            except Exception:  # a bug here must not end the watch silently
                log.exception("watching %s", live.path)

    def stop(self) -> None:
        self.stopping.set()
        with self.lock:
            sessions = list(self.sessions.values())
        for live in sessions:
            with live.cond:
                live.cond.notify_all()
