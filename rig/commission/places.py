"""`rig commission STATION.yaml --out DIR --position X,Y,Z`: the reference magnetometer measured at one more
place, added to the commissioning file `rig commission` wrote with it at its own place (the centre).

Off the centre the coil field depends on each loop's place, lean and turns, which the centre's matrix
cannot show (rig/fieldsources/coils/loops.py). With the reference moved to a place (the operator puts it
there; a simulated station puts it there, off by the reference's own position error), the same settings
are driven and the matrix as measured there is added to the file (`coils.places`); the loops are then
fitted to the centre's matrix and every place's (rig/fieldsources/coils/loopfit.py), and the file is
written again whole and sealed, with what the places leave unidentified. The ambient each place measured
gives the lab field's gradient (rig/fieldsources/coils/gradientfit.py). Every DUT's reference field then
comes from the fitted loops and the gradient between the reference and the DUT, and the budget's "coil
loops" and "ambient gradient" lines from their covariances.

Places that identify the loops: the centre and +-x, +-y, +-z at 60-80 mm (a shift across a loop's
axis shows at the places across it, a loop's lean and turns at the places along its pair's axis). Both
loops of a pair together can only scale or turn the pair, which the centre's matrix already fixes: those
never show, and need not. The reference's own place is known to its `position_tolerance_mm`: that part of
what every place shows alike cannot be told from the loops all shifted together (state a commissioning
jig's tolerance, e.g. 0.1 mm).

Refused, each with one line: no file from the reference's own place (commission without --position
first), one of another station or reference or whose reference calibration has changed, a file whose
own place is not the centre, a place outside the coil set, and a place within 1 mm of one measured.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import yaml

from calib.io.digest import sha256_file
from rig.commission.procedure import commissioning_inputs, drive, setting_records
from rig.config import commissioning_file
from rig.config.station import SAME_PLACE_MM
from rig.core.errors import ConfigError
from rig.devices.build import open_rig
from rig.reference.sitefield import ReferenceReader


def parse_position(text: str) -> tuple[float, float, float]:
    """"X,Y,Z" in mm; ConfigError naming --position otherwise."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(np.isfinite(values)):
        raise ConfigError(f"rig commission: --position {text!r}: give the place as X,Y,Z in mm, e.g. 70,0,0")
    return values  # type: ignore[return-value]


def commission_place(station_path: str | Path, out_dir: str | Path, position_mm, *, repeats: int = 2,
                     current_a: float | None = None, clock=None, on_rig=None,
                     now: dt.datetime | None = None) -> Path:
    """Measure at `position_mm`, add it to the file in `out_dir` and fit the loops again; its path."""
    _, station, ref_config, calibrations, target = commissioning_inputs(station_path, out_dir)
    source = station.field_source
    position = np.asarray(position_mm, float)
    where = f"rig commission: --position {_fmt(position)} mm"
    problem = source.commissioning_place_problem(position)
    if problem is not None:
        raise ConfigError(f"{where} {problem}")
    existing = _existing(target, station, station_path, ref_config)
    section = getattr(existing.record, source.commissioning_section).model_dump()
    for before in [existing.record.reference_magnetometer.position_mm,
                   *(p["position_mm"] for p in section.get("places", []))]:
        if np.linalg.norm(position - np.asarray(before, float)) < SAME_PLACE_MM:
            raise ConfigError(f"{where} is where {target} already measured ({_fmt(before)} mm, within "
                              f"{SAME_PLACE_MM:g} mm): give another place")
    moved = [r.model_copy(update={"position_mm": tuple(position)}) if r.name == ref_config.name else r
             for r in station.reference_magnetometers]
    placed = station.model_copy(update={"reference_magnetometers": moved})
    rig = open_rig(placed, clock=clock)  # every device connected and made safe first
    try:
        source.prepare(rig.field_source)
        if on_rig is not None:
            on_rig(rig)
        reader = ReferenceReader(rig, moved[[r.name for r in moved].index(ref_config.name)],
                                 calibrations[ref_config.name])
        readings = drive(rig, source, reader, source.commissioning_design(current_a, repeats))
    finally:
        rig.close()  # safe: coils at 0 A, chamber at its safe setpoint
    moment = commissioning_file.utc_text(now or dt.datetime.now(dt.UTC))
    section = source.commissioning_with_place(section, readings, position, moment, setting_records(readings),
                                              ref_config.position_tolerance_mm)
    data = existing.record.model_dump(exclude={"content_sha256"}, exclude_none=True)
    data[source.commissioning_section] = section
    commissioning_file.save(yaml.safe_load(yaml.safe_dump(_plain(data))), target)
    return target


def _existing(target: Path, station, station_path, ref_config):
    """The file of the reference's own place, at the centre, of this station and reference as it is now."""
    if not target.is_file():
        raise ConfigError(f"rig commission: --position: {target} not found: commission the station with the "
                          "reference at its own place first (without --position)")
    com = commissioning_file.read(target)
    record = com.record
    ref = record.reference_magnetometer
    if record.station != station.name or ref.name != ref_config.name:
        raise ConfigError(f"rig commission: --position: {target} was made for station {record.station!r} "
                          f"with {ref.name}, not {station.name!r} with {ref_config.name}")
    cal = commissioning_file.file_path(station_path, ref_config.calibration)
    if sha256_file(cal) != ref.calibration_sha256:
        raise ConfigError(f"rig commission: --position: the calibration of {ref.name} ({cal}) has changed "
                          f"since {target} was written: commission the station again without --position")
    if np.any(np.asarray(ref.position_mm, float) != 0):
        raise ConfigError(f"rig commission: --position: {target} was measured at {_fmt(ref.position_mm)} mm, "
                          "not the centre: the places are fitted against the centre's matrix")
    return com


def _plain(value):
    """Tuples as lists, numpy numbers as floats: what the YAML dump and the seal take."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _fmt(v) -> str:
    return "(" + ", ".join(f"{float(x):g}" for x in v) + ")"
