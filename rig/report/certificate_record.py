"""What a DUT's calibration certificate is made from, read once, and what refuses one.

    recorded = session_record(SESSION)           # the session's share, once for all its DUTs
    record = gather(SESSION, "dut3", recorded)   # the DUT's: its calibration files, its identity...

The session gives the plan and station as recorded (with their `lab:`, `customer:`, `received:`,
`condition:` and `duts[].serial`: rig/config/lab.py), the reference chain, the points, the verdicts and
the events; beside it, the DUT's calibration files, each read as written (its keys, format 3's measurand
keys among them, and its sha256).

A certificate is refused (CertificateRefused, one line naming the file and what is missing) for a
calibration that states no uncertainty (no `uncertainty:` section), one whose `uncertainty.missing`
lists inputs without a stated uncertainty, and one without a reference chain (fitted from a CSV's
reference columns, not from this session). What a certificate should state and the files do not (the
laboratory's keys, the item's serial, the customer, the date of receipt, the condition) does not refuse
it: `missing_items` names each, and every page says so.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from calib.calibration import Calibration
from calib.io import calfile
from calib.io.digest import sha256_bytes
from rig.config.lab import LAB_ITEMS
from rig.core.errors import DataError, SessionError
from rig.core.paths import calibration_file
from rig.reference.chain_record import SNAPSHOT
from rig.session.events import Kind, Reason

CERTIFIED_MODELS = ("t24", "t36", "p12", "scalar")  # the plan's models, and a T36 the post-run fits added


class CertificateRefused(DataError):
    """A calibration a certificate cannot be issued for; the message names the file and what it lacks."""


@dataclass(frozen=True)
class CalFile:
    """One calibration file as written: its keys (`raw`, format 3's measurand keys among them), the
    Calibration calib reads from them, and the sha256 of its bytes."""

    model: str
    path: Path
    sha256: str
    raw: dict
    cal: Calibration

    @property
    def uncertainty(self) -> dict:
        return self.cal.uncertainty or {}


def read_calibration(path: Path, model: str) -> CalFile:
    data = path.read_bytes()
    cal = calfile.load(path)  # its checks and its one-line errors
    raw = json.loads(data) if path.suffix.lower() == ".json" else yaml.safe_load(data)
    return CalFile(model, path, sha256_bytes(data), raw, cal)


def refusal(cal_file: CalFile, session: Path, dut: str) -> str | None:
    """Why no certificate can state this calibration (None: it can), in one line naming the file."""
    name, u, source = cal_file.path, cal_file.cal.uncertainty, cal_file.cal.source or {}
    if source.get("kind") != "session":
        return (f"{name}: no reference chain: it was fitted from {source.get('kind') or 'an unstated source'}"
                f" ({source.get('path', 'no path')}), not from a session's reference fields: a certificate "
                "states results traceable through the session's chain only")
    if Path(str(source.get("path", ""))).name != session.name or source.get("dut", dut) != dut:
        return (f"{name}: fitted from {source.get('path')} DUT {source.get('dut')}, not from "
                f"{session.name} DUT {dut}")
    if u is None:
        return (f"{name}: no uncertainty: section: a certificate states every result with its expanded "
                "uncertainty; fit it again from the session (rig refit) to budget it")
    missing = u.get("missing") or []
    if missing:
        said = "; ".join(f"{m.get('source', '?')} ({m.get('key', '?')}): {m.get('why', '')}".rstrip(": ")
                         for m in missing)
        return f"{name}: uncertainty.missing: inputs with no stated uncertainty: {said}"
    return None


def session_record(session: str | Path) -> dict:
    """What every certificate of a session states alike, read once for all its DUTs: the session's
    information, reference chain, sha256, points, verdicts and events, and its recorded plan and station
    parsed."""
    from rig.budget.run_inputs import RunInputs
    from rig.session.reader import SessionReader

    session = Path(session)
    with SessionReader(session) as reader:
        info = reader.info()
        run = RunInputs.of_session(reader)  # the recorded plan and station, the chain's inputs
        chain = reader.snapshot(SNAPSHOT) or {}
        all_points = reader.points()
        points = [p for p in all_points if p["state"] == "done"]
        record = {"duts": reader.duts(), "sha256": reader.sha256, "acceptance": reader.acceptance(),
                  "setpoints_c": sorted({round(p["setpoint_c"], 2) for p in points}),
                  "targets": len({p["target_json"] for p in points}), "points": len(points),
                  "points_planned": len(all_points), "events": reader.events(),
                  "failed_points": [p["id"] for p in all_points if p["state"] == "failed"], "run": run}
    com = run.station.field_source.commissioned  # as the run used it (its sealed record)
    commissioning = None if com is None else {
        "created_utc": com.record.created_utc,
        "reference_magnetometer": com.record.reference_magnetometer.model_dump()}
    return record | {"session": session, "info": info, "chain": chain, "plan": run.plan,
                     "station": run.station, "commissioning_record": commissioning}


@dataclass
class Record:
    """Everything a DUT's certificate states: the session's record and the DUT's own."""

    session: Path
    dut: str
    recorded: dict
    identity: dict
    ds: object  # the DUT's samples (calib Dataset) as recorded
    cals: dict[str, CalFile]
    verdicts: list[dict] = field(default_factory=list)

    # the session's record (session_record), by name
    info = property(lambda self: self.recorded["info"])
    plan = property(lambda self: self.recorded["plan"])
    station = property(lambda self: self.recorded["station"])
    chain = property(lambda self: self.recorded["chain"])  # the reference chain as the run recorded it
    commissioning_record = property(lambda self: self.recorded["commissioning_record"])
    events = property(lambda self: self.recorded["events"])
    run = property(lambda self: self.recorded["run"])  # rig/budget/run_inputs.py RunInputs
    session_sha256 = property(lambda self: self.recorded["sha256"])

    @property
    def stem(self) -> str:
        return self.session.name.removesuffix(".session")

    @property
    def config(self):
        return self.station.dut(self.dut)

    @property
    def simulated(self) -> list[str]:
        """The devices of the run that were simulated (the session records it per device)."""
        return [name for name, sim in (self.info.get("simulated") or {}).items() if sim]

    @property
    def certificate_id(self) -> str:
        """Unique per session, DUT and calibration files: a refit makes a new one."""
        digest = sha256_bytes("".join(c.sha256 for c in self.cals.values()).encode())
        return f"{self.stem}/{self.dut}/{digest[:8]}"

    @property
    def serial(self) -> tuple[str | None, str]:
        """(the item's serial number, who states it): the station's `duts[].serial`, else the serial the
        device reported of itself; (None, ...) when neither."""
        if self.config.serial:
            return self.config.serial, "the station (duts[].serial)"
        reported = self.identity.get("serial_number") or self.identity.get("serial")
        return (str(reported), "as the device reports it") if reported else (None, "")

    def missing_items(self) -> list[str]:
        """The 7.8.2.1 items this certificate cannot state, as the files' keys name them."""
        lab = self.station.lab
        out = [key for attr, key in LAB_ITEMS.items() if lab is None or not getattr(lab, attr)]
        if self.serial[0] is None:
            out.append(f"duts[{self.dut}].serial")
        plan = self.plan
        out += [key for key in ("customer", "received", "condition") if getattr(plan, key) is None]
        return out


def gather(session: str | Path, dut: str, recorded: dict | None = None) -> Record:
    """The DUT's record; CertificateRefused for a calibration no certificate can state."""
    from rig.session.reader import SessionReader

    session = Path(session)
    recorded = recorded or session_record(session)
    if dut not in recorded["duts"]:
        raise SessionError(f"{session}: no DUT named {dut!r} (DUTs: {', '.join(recorded['duts'])})")
    cals = {}
    for model in dict.fromkeys([*recorded["plan"].fit.models, *CERTIFIED_MODELS]):
        path = calibration_file(session, dut, model)
        if path.is_file():
            cals[model] = read_calibration(path, model)
    if not cals:
        raise DataError(f"{session}: DUT {dut} has no calibration file beside the session (the run's "
                        "post-run fits write them): nothing to certify")
    for cal_file in cals.values():
        if (why := refusal(cal_file, session, dut)) is not None:
            raise CertificateRefused(why)
    with SessionReader(session) as reader:
        identity = reader.snapshot(dut) or {}
        ds = reader.dataset(dut)
    return Record(session, dut, recorded, identity, ds, cals,
                  [r for r in recorded["acceptance"] if r["dut"] == dut])


# The events that depart from the procedure as planned (ISO/IEC 17025:2017 7.8.2.1 n): holds and
# retakes, faults, pauses and resumes, the rig's warnings and errors, fits that failed, a stale lock; and
# a resumed run, a device that would not go safe.
DEVIATION_KINDS = (Kind.HOLD, Kind.FAULT, Kind.REQUEST, Kind.PAUSE, Kind.RESUME, Kind.WARNING, Kind.ERROR,
                   Kind.FIT_FAILED, Kind.STALE_LOCK)
DEVIATION_REASONS = (Reason.RESUMED, Reason.SAFE_STATE_FAILED)


def deviations(record: Record) -> list[list[str]]:
    """[what, how often, at which points (the first few), the first message] per kind, reason and
    device; the run's end when it did not complete, points that failed and samples left out."""
    groups: dict[tuple, list] = {}
    for event in record.events:
        if event.kind in DEVIATION_KINDS or event.code in DEVIATION_REASONS:
            what = f"{event.kind}: {event.code.label}" + (f" ({event.device})" if event.device else "")
            groups.setdefault((what,), []).append(event)
    rows = []
    for (what,), events in groups.items():
        points = list(dict.fromkeys(e.point_id for e in events if e.point_id))
        shown = ", ".join(points[:5]) + (f" and {len(points) - 5} more" if len(points) > 5 else "")
        rows.append([what, str(len(events)), shown or "-", events[0].message[:200]])
    info = record.info
    if info.get("exit_status") != "completed":
        rows.append(["run's end", "1", "-", f"{info.get('exit_status')}: {info.get('exit_reason')}"])
    failed = record.recorded.get("failed_points") or []
    if failed:
        rows.append(["points not taken", str(len(failed)), ", ".join(failed[:5]), "given up after retakes"])
    for model, cal_file in record.cals.items():
        left_out = cal_file.cal.stats.get("n_outliers") or 0
        if left_out:
            rows.append([f"{model.upper()}: samples left out", str(left_out), "-",
                         "flagged as outliers by the robust fit (the plan's fit.robust)"])
    return rows
