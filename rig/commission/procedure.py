"""`rig commission STATION.yaml --out DIR`: measure the field source against the station's reference
magnetometer, and write `DIR/<station>.commissioning.yaml` (rig/config/commissioning_file.py).

The field source's kind designs the settings and fits what they show (coils: the 3x3 matrix and the
ambient with their covariance, linearity, hysteresis and drift, rig/fieldsources/coils/commissioning.py;
a turntable: its axes, rig/fieldsources/turntable/commissioning.py); this procedure drives the settings,
reads the reference at each and writes the sealed file.

With `thermal=True` it then measures what planning needs (rig/commission/thermal.py: the pace of a point,
each DUT's noise, a step of the chamber's set point with the air and each DUT followed) into the file's
`thermal:` section.

Every device is made safe first and again at the end, whatever happens (error, Ctrl-C, SIGTERM): the coils
at 0 A or the table stopped, the chamber at its safe set point. A
faulty reference (no reply, a saturated reading), a coil that does not respond and a field that is not
linear in its current each end it with one line naming the device and the axis; nothing is written then.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

from calib.io.digest import sha256_file
from rig import __version__
from rig.commission.otherrefs import other_ambients
from rig.config import Station, commissioning_file
from rig.core.errors import ConfigError, DeviceError
from rig.core.paths import inside
from rig.core.yamlload import load_model, locate_in_text, read_text
from rig.devices.build import open_rig
from rig.fieldsources.commissioning import Reading, floats
from rig.reference.sitefield import (
    COMMISSION_SETTLE_S,
    ReferenceReader,
    load_reference_calibrations,
    readback_mean,
    settle_at,
)


def commission(station_path: str | Path, out_dir: str | Path, *, repeats: int = 2,
               current_a: float | None = None, clock=None, on_rig=None,
               now: dt.datetime | None = None, thermal: bool = False,
               thermal_step_c: float | None = None) -> Path:
    """Measure, fit and write the station's commissioning file (with `thermal`, its thermal section too);
    returns its path."""
    _, station, ref_config, calibrations, target = commissioning_inputs(station_path, out_dir)
    source = station.field_source
    design = source.commissioning_design(current_a, repeats)
    if thermal:
        from rig.commission.thermal import THERMAL_STEP_C, measure_thermal

        step_c = THERMAL_STEP_C if thermal_step_c is None else thermal_step_c
    thermal_section = None
    rig = open_rig(station, clock=clock)  # every device connected and made safe first
    try:
        start_air_c = rig.chamber.read().air_c if thermal else None  # where a campaign's air starts
        source.prepare(rig.field_source)
        if on_rig is not None:
            on_rig(rig)
        reader = ReferenceReader(rig, ref_config, calibrations[ref_config.name])
        identity = rig.built.devices[ref_config.name].describe()
        readings = drive(rig, source, reader, design)
        # the station's other reference magnetometers show the lab field's gradient (coils)
        others = other_ambients(rig, station, ref_config, calibrations) if source.measures_gradient else []
        if thermal:
            thermal_section = measure_thermal(rig, station, step_c=step_c, start_air_c=start_air_c)
    finally:
        rig.close()  # safe: coils at 0 A, table stopped, chamber at its safe setpoint
    section = source.fit_commissioning(readings, ref_config.position_mm)
    if others:
        section = source.commissioning_with_others(section, others, ref_config.position_mm)
    fitted = {source.commissioning_section: {**section, "repeats": repeats}}
    if thermal_section is not None:
        fitted["thermal"] = _plain(thermal_section)
    moment = now or dt.datetime.now(dt.UTC)
    data = {
        "format": commissioning_file.FORMAT_NAME, "format_version": commissioning_file.FORMAT_VERSION,
        "kind": source.kind, "station": station.name, "created_utc": commissioning_file.utc_text(moment),
        "software_version": __version__,
        "reference_magnetometer": {
            "name": ref_config.name, "type": ref_config.type, "identity": _plain(identity),
            "calibration": ref_config.calibration,
            "calibration_sha256": sha256_file(commissioning_file.file_path(station_path,
                                                                           ref_config.calibration)),
            "position_mm": [float(v) for v in (ref_config.position_mm or (0.0, 0.0, 0.0))],
        },
        **fitted,
        "settings": setting_records(readings),
    }
    commissioning_file.save(data, target)
    return target


def drive(rig, source, reader, design) -> list[Reading]:
    """Each setting of the design in turn, settled: the reference's mean reading and the read-back there."""
    readings = []
    for setting, what in design:
        try:
            settle_at(rig, source, setting, COMMISSION_SETTLE_S)
            measured = reader.read_mean(f"commission {what}", flagged_is_fault=True)
            readback = readback_mean(rig, source)
            readings.append(Reading(setting, what, measured, None if readback is None else readback[0]))
        except DeviceError as exc:  # say what was being driven when the device failed
            if exc.operation.startswith("commission"):
                raise
            raise type(exc)(exc.device, f"commission {what}: {exc.operation}", exc.detail) from None
    return readings


def setting_records(readings: list[Reading]) -> list[dict]:
    """The file's record of every setting: commanded, the reference's mean and standard error, read-back."""
    return [{"setting": [float(v) for v in r.setting], "mean_nt": floats(r.measured.vector_nt),
             "se_nt": floats(r.measured.std_error_nt), "n": r.measured.n,
             **({} if r.readback is None else {"readback": floats(r.readback)})} for r in readings]


def commissioning_inputs(station_path: str | Path, out_dir: str | Path):
    """(station text, station, its reference magnetometer, the references' calibrations, the commissioning
    file's path in out_dir), each checked."""
    text = read_text(station_path)
    station = load_model(Station, station_path, text)
    ref_config = reference_of(station, station_path, text)
    calibrations = load_reference_calibrations(station, station_path, text)
    return text, station, ref_config, calibrations, inside(out_dir, f"{station.name}.commissioning.yaml")


def reference_of(station, station_path, text):
    """The reference magnetometer that commissions the field source, where it can."""
    refs = {r.name: r for r in station.reference_magnetometers}
    source = station.field_source
    name = (getattr(source, "reference_magnetometer", None)
            or getattr(getattr(source, "site_field", None), "reference_magnetometer", None)
            or (next(iter(refs)) if len(refs) == 1 else None))
    if name is None or name not in refs:
        what = ("the station has no reference magnetometer: add the calibrated one under "
                "reference_magnetometers" if not refs else
                f"name the reference magnetometer that commissions it (one of {', '.join(refs)})")
        raise ConfigError(locate_in_text(str(station_path), text, ("field_source",), what))
    ref = refs[name]
    problem = source.commissioning_reference_problem(ref.position_mm)
    if problem is not None:
        index = list(refs).index(name)
        raise ConfigError(locate_in_text(
            str(station_path), text, ("reference_magnetometers", index, "position_mm"), f"{name} {problem}"))
    return ref


def _plain(d: dict) -> dict:
    """A device's identity as plain YAML-able values."""
    return json.loads(json.dumps(d, default=str))
