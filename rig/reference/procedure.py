"""`rig commission STATION.yaml --out DIR`: measure the field source against the station's reference
magnetometer, and write `DIR/<station>.commissioning.yaml` (rig/reference/commissioning_file.py).

Coils: with the reference at the centre (or anywhere, when the coils' geometry carries its readings to
the centre), the coils are driven through a designed set of currents, repeated `repeats` times:
    0; each coil +I/2, +I, +I/2, 0, -I/2, -I, -I/2, 0 (up and down: hysteresis; two levels: linearity);
    each pair of coils at 0.7 I in the four sign combinations; all three at I/2 in the eight;
and the 3x3 matrix and the ambient are fitted with their covariance (calib/coilfit.py). The zero setting,
visited again and again, shows the drift; each level approached from both sides, the hysteresis.
Turntable: the reference on the table is read at every azimuth (45 deg apart) x elevation (-90..90,
45 apart) within the table's limits, home first and last, and the table's axes are fitted
(calib/tablefit.py).

Every device is made safe first and again at the end, whatever happens (error, Ctrl-C, SIGTERM). A
faulty reference (no reply, a saturated reading), a coil that does not respond and a field that is not
linear in its current each end it with one line naming the device and the axis; nothing is written then.
"""

from __future__ import annotations

import datetime as dt
import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.coilfit import fit_coil_matrix
from calib.digest import sha256_file
from calib.errors import FitError
from calib.tablefit import PARAM_NAMES, fit_table_axes
from rig import __version__
from rig.config import Station
from rig.core.errors import ConfigError, DeviceError, DeviceFault
from rig.core.paths import inside
from rig.core.yamlload import load_model, locate_in_text, read_text
from rig.devices.build import open_rig
from rig.reference import commissioning_file
from rig.reference.sitefield import FieldMeasurement, ReferenceReader, load_reference_calibrations, settle_at

AXES = "xyz"
FIELD_PER_AXIS_NT = 60_000.0  # drive each coil to about this: the fields a campaign uses
CURRENT_SHARE = 0.8  # of max_current_a, at most
MAX_NONLINEARITY = 2e-3  # an air-core coil is linear to far better; more means a fault near the coils
MIN_RESPONSE_SHARE = 0.1  # a coil giving less than this share of its declared field is not connected
SETTLE_S = 0.5
TABLE_AZ_STEP_DEG = 45.0
TABLE_EL_DEG = (-90.0, -45.0, 0.0, 45.0, 90.0)


@dataclass(frozen=True)
class Reading:
    setting: tuple[float, ...]
    what: str  # the coil or table axis being driven, for messages
    measured: FieldMeasurement


def commission(station_path: str | Path, out_dir: str | Path, *, repeats: int = 2,
               current_a: float | None = None, clock=None, on_rig=None,
               now: dt.datetime | None = None) -> Path:
    """Measure, fit and write the station's commissioning file; returns its path."""
    text = read_text(station_path)
    station = load_model(Station, station_path, text)
    source = station.field_source
    ref_config = _reference_of(station, station_path, text)
    calibrations = load_reference_calibrations(station, station_path, text)
    target = inside(out_dir, f"{station.name}.commissioning.yaml")
    design = (_coil_design(station, current_a, repeats) if source.kind == "coils"
              else _table_design(station, repeats))
    rig = open_rig(station, clock=clock)  # every device connected and made safe first
    try:
        source.prepare(rig.field_source)
        if on_rig is not None:
            on_rig(rig)
        reader = ReferenceReader(rig, ref_config, calibrations[ref_config.name])
        identity = rig.built.devices[ref_config.name].describe()
        readings = []
        for setting, what in design:
            try:
                settle_at(rig, source, setting, SETTLE_S)
                readings.append(Reading(setting, what, reader.read_mean(f"commission {what}",
                                                                        flagged_is_fault=True)))
            except DeviceError as exc:  # say what was being driven when the device failed
                if exc.operation.startswith("commission"):
                    raise
                raise type(exc)(exc.device, f"commission {what}: {exc.operation}", exc.detail) from None
    finally:
        rig.close()  # safe: coils at 0 A, table stopped, chamber at its safe setpoint
    fitted = (_fit_coils(station, ref_config, readings) if source.kind == "coils"
              else _fit_table(readings))
    fitted[source.kind if source.kind == "coils" else "table"]["repeats"] = repeats
    moment = now or dt.datetime.now(dt.UTC)
    data = {
        "format": commissioning_file.FORMAT_NAME, "format_version": commissioning_file.FORMAT_VERSION,
        "kind": source.kind, "station": station.name, "created_utc": commissioning_file.utc_text(moment),
        "software_version": __version__,
        "reference_magnetometer": {
            "name": ref_config.name, "type": ref_config.type, "identity": _plain(identity),
            "calibration": ref_config.calibration,
            "calibration_sha256": sha256_file(commissioning_file.file_path(station_path, ref_config.calibration)),
            "position_mm": [float(v) for v in (ref_config.position_mm or (0.0, 0.0, 0.0))],
        },
        **fitted,
        "settings": [{"setting": [float(v) for v in r.setting], "mean_nt": _floats(r.measured.vector_nt),
                      "se_nt": _floats(r.measured.std_error_nt), "n": r.measured.n} for r in readings],
    }
    commissioning_file.save(data, target)
    return target


def _reference_of(station, station_path, text):
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
    position = np.asarray(ref.position_mm or (0.0, 0.0, 0.0), float)
    if source.kind == "coils" and np.any(position != 0) and source.geometry is None:
        index = list(refs).index(name)
        raise ConfigError(locate_in_text(
            str(station_path), text, ("reference_magnetometers", index, "position_mm"),
            f"{name} is not at the centre and field_source has no geometry to carry its readings there"))
    return ref


def _coil_design(station, current_a: float | None, repeats: int) -> list[tuple[tuple[float, ...], str]]:
    source = station.field_source
    level = current_a
    if level is None:
        level = CURRENT_SHARE * source.max_current_a
        if source.coil_constants_nt_per_a is not None:
            columns = np.linalg.norm(source.declared_constants, axis=0)
            level = min(level, FIELD_PER_AXIS_NT / float(np.max(columns)))
    if not 0 < level <= source.max_current_a:
        raise ConfigError(f"rig commission: --current {level:g} A is outside 0 .. field_source.max_current_a "
                          f"{source.max_current_a:g} A")
    one: list[tuple[tuple[float, ...], str]] = [((0.0, 0.0, 0.0), "coils at 0 A")]
    for j in range(3):
        for share in (0.5, 1.0, 0.5, 0.0, -0.5, -1.0, -0.5, 0.0):
            setting = [0.0, 0.0, 0.0]
            setting[j] = share * level
            one.append((tuple(setting), f"coil {AXES[j]} at {share * level:+.3f} A"))
    for j, k in itertools.combinations(range(3), 2):
        for sj, sk in itertools.product((1.0, -1.0), repeat=2):
            setting = [0.0, 0.0, 0.0]
            setting[j], setting[k] = 0.7 * sj * level, 0.7 * sk * level
            one.append((tuple(setting), f"coils {AXES[j]}{AXES[k]} at {_fmt_a(setting)} A"))
    for signs in itertools.product((1.0, -1.0), repeat=3):
        setting = [0.5 * s * level for s in signs]
        one.append((tuple(setting), f"coils xyz at {_fmt_a(setting)} A"))
    return one * repeats


def _table_design(station, repeats: int) -> list[tuple[tuple[float, ...], str]]:
    source = station.field_source
    (az_lo, az_hi), (el_lo, el_hi) = source.az_limits_deg, source.el_limits_deg
    azimuths = [a for a in np.arange(0.0, 360.0, TABLE_AZ_STEP_DEG) if az_lo <= a <= az_hi]
    elevations = [e for e in TABLE_EL_DEG if el_lo <= e <= el_hi]
    home: tuple[tuple[float, ...], str] = ((0.0, 0.0), "table at home")
    one = [home] + [((float(a), float(e)), f"table at az {a:g} el {e:g} deg")
                    for e in elevations for a in azimuths] + [home]
    return one * repeats


def _arrays(readings: list[Reading]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(settings, mean readings, their standard errors), one row per reading."""
    return (np.array([r.setting for r in readings]), np.array([r.measured.vector_nt for r in readings]),
            np.array([r.measured.std_error_nt for r in readings]))


def _fit_coils(station, ref_config, readings: list[Reading]) -> dict:
    source = station.field_source
    currents, means, se = _arrays(readings)
    try:
        fit = fit_coil_matrix(currents, means, se)
    except FitError as exc:
        axis = next((a for a in AXES if f"coil {a} " in str(exc)), "xyz")
        raise DeviceFault(source.name, f"commission coil {axis}", str(exc)) from None
    _check_coils(source, fit, currents)
    matrix = fit.matrix_nt_per_a
    position = np.asarray(ref_config.position_mm or (0.0, 0.0, 0.0), float)
    if np.any(position != 0):  # measured where the reference sits: carried to the centre
        matrix = _centre_matrix(source.geometry, matrix, position)
    se_matrix, se_ambient = fit.std_errors()
    return {"coils": {
        "matrix_nt_per_a": _rows(matrix), "ambient_nt": _floats(fit.ambient_nt),
        "covariance": _rows(fit.covariance),
        "std_errors_matrix_nt_per_a": _rows(se_matrix), "std_errors_ambient_nt": _floats(se_ambient),
        "residual_rms_nt": _floats(fit.residual_rms_nt), "nonlinearity_ppm": _floats(1e6 * fit.nonlinearity),
        "hysteresis_nt": _hysteresis_nt(readings), "drift_nt": _drift_nt(readings),
        "current_a": float(np.max(np.abs(currents))),
    }}


def _check_coils(source, fit, currents: np.ndarray) -> None:
    """Each coil responds as declared (within a factor) and linearly."""
    declared = source.declared_constants
    for j in range(3):
        column = float(np.linalg.norm(fit.matrix_nt_per_a[:, j]))
        if declared is not None:
            expected = float(np.linalg.norm(declared[:, j]))
            if column < MIN_RESPONSE_SHARE * expected:
                raise DeviceFault(source.name, f"commission coil {AXES[j]}",
                                  f"the field changes by {column:.4g} nT/A, {column / expected:.1%} of the "
                                  f"declared {expected:.4g} nT/A: the coil does not respond")
        if fit.nonlinearity[j] > MAX_NONLINEARITY:
            top = float(np.max(np.abs(currents[:, j])))
            raise DeviceFault(source.name, f"commission coil {AXES[j]}",
                              f"the field is not linear in the current: {fit.nonlinearity[j]:.2%} off at "
                              f"{top:.3g} A (a saturating reference, iron near the coils, or the supply)")


def _centre_matrix(geometry, measured: np.ndarray, position_mm: np.ndarray) -> np.ndarray:
    """The centre matrix whose field at `position_mm` is `measured` (a few fixed-point steps: the map
    from centre to position is the identity to within the field's non-uniformity)."""
    centre = measured.copy()
    for _ in range(20):
        step = measured - geometry.matrices_at(centre, [position_mm])[0]
        centre = centre + step
        if np.max(np.abs(step)) < 1e-9 * np.max(np.abs(measured)):
            break
    return centre


def _fit_table(readings: list[Reading]) -> dict:
    angles, means, se = _arrays(readings)
    try:
        fit = fit_table_axes(angles, means, se)
    except FitError as exc:
        raise DeviceFault("turntable", "commission the table's axes", str(exc)) from None
    return {"table": {
        "params": fit.as_dict(), "covariance": _rows(fit.covariance),
        "std_errors": {n: float(v) for n, v in zip(PARAM_NAMES, fit.std_errors, strict=True)},
        "residual_rms_nt": float(np.sqrt(np.mean(fit.residuals_nt**2))), "drift_nt": _drift_nt(readings),
    }}


def _hysteresis_nt(readings: list[Reading]) -> float:
    """The largest difference between readings at one current reached from above and from below."""
    worst = 0.0
    for i in range(1, len(readings) - 1):
        here = np.asarray(readings[i].setting)
        for k in range(i + 1, len(readings)):
            if np.array_equal(readings[k].setting, here) and np.any(here != 0):
                before_i = np.abs(readings[i - 1].setting).sum()
                before_k = np.abs(readings[k - 1].setting).sum()
                if before_i != before_k:  # approached from a smaller and from a larger current
                    gap = np.linalg.norm(readings[i].measured.vector_nt - readings[k].measured.vector_nt)
                    worst = max(worst, float(gap))
                break
    return worst


def _drift_nt(readings: list[Reading]) -> float:
    """How far the readings at the rest setting (coils at 0 A, table at home) wandered."""
    rest = [r.measured.vector_nt for r in readings if not np.any(r.setting)]
    if len(rest) < 2:
        return 0.0
    rest = np.array(rest)
    return float(np.max(np.linalg.norm(rest - rest[0], axis=1)))


def _fmt_a(setting) -> str:
    return "(" + ", ".join(f"{v:+.3f}" for v in setting) + ")"


def _floats(v) -> list[float]:
    return [float(x) for x in np.asarray(v, float).ravel()]


def _rows(m) -> list[list[float]]:
    return [[float(x) for x in row] for row in np.asarray(m, float)]


def _plain(d: dict) -> dict:
    """A device's identity as plain YAML-able values."""
    return json.loads(json.dumps(d, default=str))
