"""What a report is made from: a session file, or a calibration file plus the CSV it was fitted on.

Both roads end in `ReportInputs`: one Dataset per DUT, what the session knows about each temperature step
(settle time, stability, failed points), flagged samples, session-level warnings and provenance.
"""

from __future__ import annotations

import datetime as dt
import json
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calib.io.digest import sha256_file as sha256_of
from calib.io.digest import sha256_text
from rig import __version__
from rig.analysis.judged import judged_for_dut
from rig.core.errors import DataError, SessionError
from rig.session.events import Event, Kind, Reason

MAX_LISTED = 5  # how many point ids a warning names before "and N more"


@dataclass
class StepInfo:
    """One temperature step as the session recorded it."""

    temp_index: int
    setpoint_c: float
    points_planned: int = 0
    points_done: int = 0
    points_failed: int = 0
    settle_s: float | None = None
    stable: bool | None = None  # True: a point was taken after the DUTs were stable; False: never stable
    settle_timeouts: int = 0  # holds because a DUT was not stable within max_wait_s


@dataclass
class DutInput:
    name: str
    dataset: object  # calib.dataset.Dataset
    calibration: object | None = None  # a given calib.Calibration (from a file); None: fit here
    flagged: dict[str, list[str]] = field(default_factory=dict)  # flag -> point ids of flagged samples
    flagged_rows: Counter = field(default_factory=Counter)  # flag -> number of samples
    # the uncertainty budget to show (calib/uncertainty/montecarlo.py) and whose it is: the given
    # calibration's, or that of the session's own calibration of this DUT
    uncertainty: dict | None = None
    uncertainty_of: str = ""
    origin: str = ""  # where the calibration shown comes from (its file, its sha256), in words
    others: list = field(default_factory=list)  # the run's other calibrations (rig/report/recorded.py)
    compare_models: tuple[str, ...] | None = None  # the models re-fitted for the comparison (None: all)
    compare_robust: bool = True  # the comparison's fits: robust or not


@dataclass
class ReportInputs:
    title: str
    duts: list[DutInput]
    steps: dict[int, StepInfo] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    provenance: list[tuple[str, str]] = field(default_factory=list)
    acceptance: list[dict] = field(default_factory=list)  # its verdicts (rig/analysis/acceptance.py)
    session: Path | None = None  # the session file reported on (its DUTs' certificates are written beside)


def utc(t: float | None) -> str:
    if t is None:
        return "-"
    return dt.datetime.fromtimestamp(t, dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def _duration(start: float | None, end: float | None) -> str:
    if start is None or end is None:
        return "not finished"
    return f"{(end - start) / 3600:.2f} h"


def listed(items: list[str]) -> str:
    """`a, b, c` or `a, b, c, d, e and 7 more`."""
    head = ", ".join(items[:MAX_LISTED])
    return head if len(items) <= MAX_LISTED else f"{head} and {len(items) - MAX_LISTED} more"


# ---------------------------------------------------------------------------------------------- session


def from_session(path: str | Path, dut: str | None = None) -> ReportInputs:
    """Everything the report needs from one session file (read-only)."""
    from rig.analysis.sessionfit import SessionFitter
    from rig.report.recorded import recorded_calibrations
    from rig.session.reader import SessionReader, runs_on_simulated_clock, simulated_text

    path = Path(path)
    with SessionReader(path) as reader:
        summary = reader.summary()
        names = [dut] if dut else summary["duts"]
        if not names:
            raise SessionError(f"{path}: the session holds no samples yet; nothing to report")
        info, points, events, snapshots = reader.info(), reader.points(), reader.events(), reader.snapshots()
        acceptance = [r for r in reader.acceptance() if r["dut"] in names]
        fitter = SessionFitter.of(reader)  # the data as the run's fits saw it (run's ambient, lag)
        recorded = {name: recorded_calibrations(reader, name) for name in names}
        duts = [_session_dut(reader, name, fitter, recorded[name]) for name in names]
    steps = _steps(points, events)
    warnings = _session_warnings(summary, points, events, steps)
    warnings += [f"{name}: {r.warning}" for name in names for r in recorded[name].values() if r.warning]
    session_hash = sha256_of(path)
    warnings += [f"{d.name}: {line}" for d in duts if d.calibration is not None
                 for line in source_mismatch(d.calibration, path, session_hash)]
    started = utc(info.get("wall_started") or info["started"])
    sim_clock = runs_on_simulated_clock(info["simulated"])
    provenance = [
        ("station", f"{info['station_name']} ({info['station_path'] or 'path not recorded'}): "
                    + simulated_text(info["simulated"]) + ("; on a simulated clock" if sim_clock else "")),
        ("session", f"{path.name} (started {started}, wall clock)"),
        ("session file sha256", f"{session_hash} (what its calibrations cite as source.sha256)"),
        ("station text sha256", sha256_text(info["station_text"])),
        ("plan", f"{info['plan_name']} ({info['plan_path'] or 'path not recorded'})"),
        ("plan text sha256", sha256_text(info["plan_text"])),
        ("operator", info["operator"] or "-"),
        (
            "run",
            f"{started} to {utc(info.get('wall_ended') or info['ended'])} (wall clock); "
            f"{_duration(info['started'], info['ended'])} on the "
            f"{'simulated clock' if sim_clock else 'run clock'}; "
            f"exit {info['exit_status'] or 'not recorded'}"
            + (f" ({info['exit_reason']})" if info["exit_reason"] else ""),
        ),
        (
            "points",
            f"{summary['points_done']} done of {summary['points_planned']} planned, "
            f"{summary['points_failed']} failed",
        ),
        *_devices(snapshots),
        ("recorded with", f"magrig {info['software_version']}"),
        ("report made with", f"magrig {__version__}"),
    ]
    title = f"Calibration report: {info['station_name']} / {info['plan_name']} ({path.name})"
    return ReportInputs(title, duts, steps, warnings, provenance, acceptance, session=path)


def source_mismatch(cal, path: Path, file_hash: str) -> list[str]:
    """A line when the calibration does not cite the file it comes from by that file's sha256 (a file
    written before format version 3 hashed its session while the run still wrote it), else none."""
    cited = (cal.source or {}).get("sha256")
    if cited == file_hash:
        return []
    said = "cites no sha256" if not cited else f"cites sha256 {str(cited)[:12]}..."
    return [f"the {cal.model.upper()} calibration {said} for its source {cal.source.get('path', '-')}, but "
            f"{path.name} hashes {file_hash[:12]}..."]


def _session_dut(reader, name: str, fitter, recorded: dict) -> DutInput:
    """One DUT of a session: its data as the run's fits saw it, and the calibration of the plan's judged
    model the run wrote (else, before the run's fits, none: the report fits one itself)."""
    plan = fitter.plan
    ds = fitter.prepare(reader.dataset(name)).ds
    _, rows = reader.sample_rows(name)
    flagged, flagged_rows = collect_flags((r["flags"], r["point"]) for r in rows if r["flags"])
    planned = plan.judged_model if plan is not None else next(iter(recorded), None)
    judged = judged_for_dut(planned, {m: r.calibration for m, r in recorded.items()})  # T36 where chosen
    shown = recorded.get(judged)
    compare = tuple(plan.fit.models) if plan is not None else None
    robust = plan.fit.robust if plan is not None else True
    d = DutInput(name, ds, None if shown is None else shown.calibration, flagged, flagged_rows,
                 compare_models=compare, compare_robust=robust)
    if shown is not None:
        what = f"the run's {judged.upper()} calibration"
        why = ("the model the plan judges" if judged == planned else
               f"judged instead of the plan's {planned.upper()}: {judged.upper()} validated better on "
               "held-out blocks of this session's data")
        d.origin = f"{what} ({why}): {shown.file_text()}"
        d.uncertainty, d.uncertainty_of = shown.calibration.uncertainty, what
        d.others = [r for m, r in recorded.items() if m != judged]
    return d


def _devices(snapshots: list[dict]) -> list[tuple[str, str]]:
    """One provenance row per device, from its first snapshot: model, firmware, serial number."""
    rows: dict[str, str] = {}
    for snap in snapshots:
        try:
            d = json.loads(snap["describe_json"])
        except ValueError:
            continue
        if snap["device"] in rows or not isinstance(d, dict) or "model" not in d:
            continue
        parts = [str(d["model"])] + [
            f"{k.replace('_', ' ')} {d[k]}" for k in ("firmware", "serial_number") if k in d
        ]
        rows[snap["device"]] = ", ".join(parts)
    return [(f"device {name}", text) for name, text in rows.items()]


def _waited_s(settle_json: str | None) -> float | None:
    """Seconds the step waited for thermal stability, from a point's settle statistics (the campaign
    records them once the DUTs are stable: {"target_c", "waited_s", "duts": {...}})."""
    try:
        d = json.loads(settle_json or "{}")
    except ValueError:
        return None
    value = d.get("waited_s") if isinstance(d, dict) else None
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _timeout_holds(events: list[Event]) -> list[Event]:
    """Holds raised because a DUT was not stable within max_wait_s (the engine retakes the point)."""
    return [e for e in events if e.kind == Kind.HOLD and e.code == Reason.STABILITY_TIMEOUT]


def _hold_label(e: Event) -> str:
    """`T03-F01 (dut1: settle timeout)`: from the event's point, device and code."""
    what = f"{e.device}: {e.code.label}" if e.device else e.code.label
    return f"{e.point_id or 'no point'} ({what})"


def _steps(points: list[dict], events: list[Event]) -> dict[int, StepInfo]:
    steps: dict[int, StepInfo] = {}
    step_of_point = {p["id"]: p["temp_index"] for p in points}
    for p in points:
        s = steps.setdefault(p["temp_index"], StepInfo(p["temp_index"], p["setpoint_c"]))
        s.points_planned += 1
        s.points_done += p["state"] == "done"
        s.points_failed += p["state"] == "failed"
        waited = _waited_s(p["settle_json"]) if p["state"] == "done" else None
        if waited is not None:
            s.settle_s = max(s.settle_s or 0.0, waited)
            s.stable = True
    for e in _timeout_holds(events):
        if e.point_id in step_of_point:
            s = steps[step_of_point[e.point_id]]
            s.settle_timeouts += 1
            if s.stable is None:
                s.stable = False
    return steps


def _session_warnings(summary: dict, points: list[dict], events: list[Event], steps: dict) -> list[str]:
    out = []
    if not summary["completed"]:
        out.append(
            f"not every planned point was taken: {summary['points_done']} of {summary['points_planned']} "
            "done; "
            f"run exit status {summary['exit_status'] or 'not recorded'}"
            + (f" ({summary['exit_reason']})" if summary["exit_reason"] else "")
        )
    failed = [p for p in points if p["state"] == "failed"]
    if failed:
        out.append(
            f"{len(failed)} point(s) failed: " + listed([f"{p['id']} ({p['reason']})" for p in failed])
        )
    for s in steps.values():
        if s.stable is False:
            out.append(
                f"temperature step {s.temp_index} ({s.setpoint_c:g} °C) did not reach stability "
                f"({s.settle_timeouts} settle timeout(s)); none of its points was taken"
            )
    timeouts = _timeout_holds(events)
    if timeouts:
        out.append(f"{len(timeouts)} settle timeout(s): " + listed([_hold_label(e) for e in timeouts]))
    holds = [e for e in events if e.kind == Kind.HOLD and e.code != Reason.STABILITY_TIMEOUT]
    if holds:
        out.append(f"{len(holds)} hold(s) during the run: " + listed([_hold_label(e) for e in holds]))
    return out


# ---------------------------------------------------------------------------------------------- cal + CSV


def from_calibration(
    cal_path: str | Path, data_path: str | Path | None, dut: str | None = None
) -> ReportInputs:
    """A calibration file and the CSV it was fitted on (the CSV contract: hx,hy,hz[,temp][,bx,by,bz])."""
    from calib.io import calfile, csvio

    cal_path = Path(cal_path)
    cal = calfile.load(cal_path)
    if data_path is None:
        raise DataError(
            f"{cal_path}: a calibration file needs the data it was fitted on: add --data DATA.csv"
        )
    data_path = Path(data_path)
    # read the CSV as the calibration was fitted on it (the same defaults `rig apply` uses)
    ds = csvio.read_csv(
        data_path,
        raw_unit=cal.source.get("raw_unit") or "nT",
        counts_per_unit=cal.source.get("counts_per_unit") or None,
        columns=csvio.parse_column_map(cal.source.get("column_map") or None),
    )
    rows_total = len(ds)
    ds, flagged, flagged_rows = _drop_flagged(ds)
    name = dut or cal.source.get("dut") or data_path.stem
    warnings = []
    fitted_hash = cal.source.get("sha256")
    data_hash = ds.source.get("sha256") or sha256_of(data_path)
    if fitted_hash and fitted_hash != data_hash:
        warnings.append(
            f"{data_path.name} (sha256 {data_hash[:12]}...) is not the file the calibration was "
            f"fitted on (sha256 {str(fitted_hash)[:12]}...): the residuals are on other data"
        )
    provenance = [
        ("calibration file", f"{cal_path.name} (model {cal.model}, fitted {cal.created_utc or '-'})"),
        ("calibration file sha256", sha256_of(cal_path)),
        ("calibration fitted on", f"{cal.source.get('path', '-')} (sha256 {fitted_hash or '-'})"),
        (
            "data file",
            f"{data_path.name}: {rows_total} rows, {len(ds)} judged"
            + (f" ({rows_total - len(ds)} flagged left out)" if rows_total > len(ds) else ""),
        ),
        ("data file sha256", data_hash),
        ("fitted with", f"magrig {cal.software_version}"),
        ("report made with", f"magrig {__version__}"),
    ]
    title = f"Calibration report: {name} ({cal_path.name} on {data_path.name})"
    origin = (f"the {cal.model.upper()} calibration given in the calibration file {cal_path.name} "
              f"(sha256 {sha256_of(cal_path)})")
    return ReportInputs(title, [DutInput(name, ds, cal, flagged, flagged_rows, cal.uncertainty,
                                         "the calibration file's", origin)], {}, warnings, provenance)


def _drop_flagged(ds):
    """Rows with a non-empty `flags` column (as `rig export --include-flagged` writes) are not judged."""
    flags = ds.columns.get("flags")
    if flags is None:
        return ds, {}, Counter()
    text = np.asarray(flags).astype(str)
    bad = np.array([t.strip() not in ("", "nan") for t in text])
    points = np.asarray(ds.columns.get("point", np.arange(len(ds)).astype(str)))
    flagged, counts = collect_flags(zip(text[bad], points[bad], strict=True))
    return (ds.subset(~bad) if bad.any() else ds), flagged, counts


def collect_flags(flagged_rows) -> tuple[dict[str, list[str]], Counter]:
    """From (comma-separated flags, point id) of flagged samples: flag -> point ids, flag -> sample count."""
    points: dict[str, dict[str, None]] = defaultdict(dict)  # ordered sets
    counts: Counter = Counter()
    for flags, point in flagged_rows:
        for flag in filter(None, str(flags).split(",")):
            counts[flag] += 1
            points[flag][str(point)] = None
    return {flag: list(ids) for flag, ids in points.items()}, counts
