"""Typed session events: what happened (`Kind`), why (`Reason`, stored as the event's code), at which
point, on which device.

The session stores kind and reason as their values; the message is for people only. Everything that
reads events (report, `rig sessions`, the run summary) decides on `kind` and `reason`, never on wording.

Sessions of schema version 1 stored only kind and message: `legacy_event` derives kind, reason and point
from the wording the engine used then (the only place that ever reads wording).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from enum import StrEnum

from rig.core.errors import (
    ERRORS,
    DeviceError,
    DeviceFault,
    DeviceNotFound,
    DeviceTimeout,
    LimitError,
    ProtocolError,
    SessionError,
)


class Kind(StrEnum):
    """What happened."""

    RUN = "run"  # the engine starts its step list
    START = "start"  # a run (or a resume) begins with every device safe
    STALE_LOCK = "stale_lock"  # a dead run's lock was taken over
    STABLE = "stable"  # the DUTs are thermally stable at a step
    HOLD = "hold"  # a point could not be taken as it was; it is retaken
    FAULT = "fault"  # what ended a run that did not complete
    REQUEST = "request"  # an operator's pause or abort from outside the run (the cockpit), with its source
    PAUSE = "pause"
    RESUME = "resume"
    SAFE_STATE = "safe_state"
    EXIT = "exit"
    FIT_FAILED = "fit_failed"
    ACCEPTANCE = "acceptance"  # a DUT's PASS/FAIL verdict against the plan's acceptance limits
    WARNING = "warning"  # a WARNING log record of the rig (transport retries...)
    ERROR = "error"  # an ERROR log record of the rig
    SITE_FIELD = "site_field"  # the ambient / site field measured by a reference magnetometer
    DECISION = "decision"  # a sequential schedule decided its next sweep (or to stop)
    NOTIFY = "notify"  # word to the operator about an event (or a stall): sent, held back or failed
    POSTRUN = "postrun"  # the post-run fits' progress: which DUT and model, how many done


class Reason(StrEnum):
    """Why it happened: the code the readers decide on."""

    # a point is held and retaken
    CHAMBER_ALARM = "chamber_alarm"
    CHAMBER_SENSOR = "chamber_sensor_error"
    CHAMBER_OFF_COURSE = "chamber_off_course"  # air faster than the ramp limit, or away from its set point
    NO_TEMPERATURE = "no_temperature"
    STABILITY_TIMEOUT = "settle_timeout"
    TEMP_OUT_OF_BAND = "temp_out_of_band"
    DEVICE_TIMEOUT = "device_timeout"
    PROTOCOL_ERROR = "protocol_error"
    DEVICE_NOT_FOUND = "device_not_found"
    DEVICE_FAULT = "device_fault"
    SITE_FIELD_DRIFT = "site_field_drift"  # the measured ambient moved beyond the station's limit
    # a run ends
    COMPLETED = "completed"
    TARGETS_MET = "targets_met"  # stop_when: every DUT's standard errors reached their targets
    TIME_BUDGET = "time_budget"  # a sequential schedule reached max_duration_h before its targets
    RETAKES_EXHAUSTED = "retakes_exhausted"
    LIMIT_REFUSED = "limit_refused"
    OPERATOR_ABORT = "operator_abort"
    TERMINATED = "terminated"  # SIGTERM
    STORE_FAILED = "store_failed"  # the session could not be written (full disk...)
    RUN_ERROR = "run_error"  # another error of the project's family
    SOFTWARE_ERROR = "software_error"  # an unexpected exception
    # everything else
    STARTED = "started"
    RESUMED = "resumed"
    OPERATOR_PAUSE = "operator_pause"
    OPERATOR_RESUME = "operator_resume"
    STABLE = "stable"
    DECIDED = "decided"  # the next sweep of a sequential schedule
    SITE_FIELD_MEASURED = "site_field_measured"  # at the start: the value every reference uses
    SITE_FIELD_CHECKED = "site_field_checked"  # re-checked at a temperature step, within its limit
    ALL_SAFE = "all_safe"
    SAFE_STATE_FAILED = "safe_state_failed"
    STALE_LOCK = "stale_lock"
    FIT_FAILED = "fit_failed"
    FITTING = "fitting"  # the post-run fits: a DUT's models are being fitted and budgeted
    ACCEPTED = "accepted"  # a DUT passed the plan's acceptance limits
    REJECTED = "rejected"  # ... or failed them
    LOGGED = "logged"  # a copied log record
    NOTIFIED = "notified"  # the operator was told (rig/run/notify.py)
    NOTIFY_HELD_BACK = "notify_held_back"  # not sent: one of its kind went out a moment ago
    NOTIFY_FAILED = "notify_failed"  # an address could not be reached
    UNKNOWN = "unknown"  # a version 1 event whose wording is not recognised

    @property
    def label(self) -> str:
        return self.value.replace("_", " ")


HOLD_REASONS = frozenset({
    Reason.CHAMBER_ALARM, Reason.CHAMBER_SENSOR, Reason.CHAMBER_OFF_COURSE, Reason.NO_TEMPERATURE,
    Reason.STABILITY_TIMEOUT,
    Reason.TEMP_OUT_OF_BAND, Reason.DEVICE_TIMEOUT, Reason.PROTOCOL_ERROR, Reason.DEVICE_NOT_FOUND,
    Reason.DEVICE_FAULT, Reason.SITE_FIELD_DRIFT,
})

# Exceptions to reasons, most specific first (looked up along the exception's class hierarchy).
_EXCEPTION_REASONS: dict[type, Reason] = {
    DeviceTimeout: Reason.DEVICE_TIMEOUT,
    ProtocolError: Reason.PROTOCOL_ERROR,
    DeviceNotFound: Reason.DEVICE_NOT_FOUND,
    DeviceFault: Reason.DEVICE_FAULT,
    DeviceError: Reason.DEVICE_FAULT,
    LimitError: Reason.LIMIT_REFUSED,
    SessionError: Reason.STORE_FAILED,
}


def code_of(exc: BaseException) -> Reason:
    """The reason code of an exception: its own `code` if it has one (a Hold), else by its class."""
    own = getattr(exc, "code", None)
    if isinstance(own, Reason):
        return own
    for cls in type(exc).__mro__:
        if cls in _EXCEPTION_REASONS:
            return _EXCEPTION_REASONS[cls]
    return Reason.RUN_ERROR if isinstance(exc, ERRORS) else Reason.SOFTWARE_ERROR


def device_of(exc: BaseException) -> str | None:
    device = getattr(exc, "device", None)
    return device if isinstance(device, str) else None


@dataclass(frozen=True)
class Event:
    """One stored event, as every reader sees it."""

    id: int
    t: float
    level: str
    kind: str  # a Kind value; kept as text so an event of a newer kind still reads
    code: Reason
    message: str
    point_id: str | None = None
    device: str | None = None
    data: dict = field(default_factory=dict)

    @property
    def is_hold(self) -> bool:
        return self.kind == Kind.HOLD


def _reason(value: str | None) -> Reason:
    try:
        return Reason(value)
    except ValueError:
        return Reason.UNKNOWN


def event_from_row(row: dict) -> Event:
    """An Event from a row of the events table (version 2: typed columns; version 1: see legacy_event)."""
    try:
        data = json.loads(row.get("data_json") or "{}")
    except ValueError:
        data = {}
    data = data if isinstance(data, dict) else {}
    if "code" not in row:
        return legacy_event(row, data)
    return Event(row["id"], row["t"], row["level"], row["kind"], _reason(row["code"]), row["message"],
                 row["point_id"], row["device"], data)


# --- version 1 sessions: their events carried only kind and wording ----------------------------------
_V1_POINT = re.compile(r"^point (\S+?):")  # "point T03-F01: ..." (holds) and "paused at point T03-F01"
_V1_HOLD_WORDING = [  # (pattern in the hold message, reason), as the engine and campaign worded them
    (re.compile(r"not stable at .* within max_wait_s"), Reason.STABILITY_TIMEOUT),
    (re.compile(r"chamber alarm"), Reason.CHAMBER_ALARM),
    (re.compile(r"chamber temperature input error"), Reason.CHAMBER_SENSOR),
    (re.compile(r"gives no temperature"), Reason.NO_TEMPERATURE),
    (re.compile(r"temperature .* left .* during point"), Reason.TEMP_OUT_OF_BAND),
    (re.compile(r"no reply|timed out|timeout", re.I), Reason.DEVICE_TIMEOUT),
]
_V1_KIND_REASONS = {
    Kind.START: Reason.STARTED, Kind.STALE_LOCK: Reason.STALE_LOCK, Kind.STABLE: Reason.STABLE,
    Kind.PAUSE: Reason.OPERATOR_PAUSE, Kind.RESUME: Reason.OPERATOR_RESUME,
    Kind.FIT_FAILED: Reason.FIT_FAILED,
    Kind.WARNING: Reason.LOGGED, Kind.ERROR: Reason.LOGGED, Kind.RUN: Reason.STARTED,
}


def legacy_event(row: dict, data: dict) -> Event:
    """A version 1 event: reason and point derived from the wording of that version."""
    kind, message = row["kind"], row["message"]
    point_id = data.get("point_id")
    if point_id is None and (m := _V1_POINT.search(message) or re.search(r"at point (\S+)", message)):
        point_id = m.group(1)
    reason = _V1_KIND_REASONS.get(kind, Reason.UNKNOWN)
    if kind == Kind.HOLD:
        reason = next((r for pattern, r in _V1_HOLD_WORDING if pattern.search(message)), Reason.DEVICE_FAULT)
    elif kind == Kind.SAFE_STATE:
        reason = Reason.SAFE_STATE_FAILED if data.get("failed") else Reason.ALL_SAFE
    elif kind == Kind.EXIT:
        reason = {"completed": Reason.COMPLETED, "aborted": Reason.OPERATOR_ABORT}.get(
            str(data.get("status")), Reason.RUN_ERROR)
        if "gave up after" in message:
            reason = Reason.RETAKES_EXHAUSTED
    return Event(row["id"], row["t"], row["level"], kind, reason, message, point_id, row.get("device"), data)
