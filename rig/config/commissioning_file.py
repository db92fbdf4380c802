"""Commissioning files: what `rig commission` measured of a station's field source, and the checks a
station's `field_source: {commissioning: FILE}` must pass before the rig trusts it.

    commissioning = load_for_station(station, station_path, station_text)   # None without one
    station = apply(station, commissioning)      # the field source now uses the measured matrix / axes

The file (YAML, `<station>.commissioning.yaml`) states the station, the date, the reference magnetometer
(identity, its calibration file's sha256, its position), the fitted coil matrix and ambient (or the
table's axes) with their covariance, the residuals, linearity, hysteresis and drift, and every setting
it was measured at; with `rig commission --thermal` also what planning needs (`thermal:`, optional, so an
older file still loads): the chamber's real rate and overshoot, each DUT position's lag, offset and noise,
and the pace of a point on the station's transports (rig/commission/thermal.py). `content_sha256` seals
all of it: a file edited after it was written is refused, as are one of another station, one older than
the field source's `max_age_days`, one whose reference calibration has changed since, a singular matrix
and a covariance that is not positive definite. Each refusal is one line naming the file, key and line.
"""

from __future__ import annotations

import datetime as dt
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from pydantic import Field

from calib.io.atomic import atomic_write
from calib.io.digest import sha256_file, sha256_text
from rig.core.configbase import Strict
from rig.core.errors import ConfigError
from rig.core.numbers import NT_VEC, FiniteFloat, Vec3
from rig.core.yamlload import KeyPath, load_model, locate_in_text, read_text
from rig.fieldsources import kind_class

FORMAT_NAME = "magrig-commissioning"
FORMAT_VERSION = 1


class ReferenceRecord(Strict):
    name: str
    type: str
    identity: dict = {}
    calibration: str
    calibration_sha256: str
    position_mm: Vec3 = (0.0, 0.0, 0.0)


class SettingRecord(Strict):
    setting: list[FiniteFloat]  # currents (A) or table angles [az, el] (deg)
    mean_nt: Vec3
    se_nt: Vec3
    n: int
    readback: list[FiniteFloat] | None = None  # what the device reported (coil read-back currents, A)


class CurrentReadback(Strict):
    """The coil current source's read-back against the commanded currents, per coil: I_rb = (1 + g) I + o."""

    gain_ppm: Vec3
    offset_ma: Vec3
    std_errors_gain_ppm: Vec3
    std_errors_offset_ma: Vec3


class PlaceRecord(Strict):
    """The coil matrix as measured with the reference at one more place (`rig commission --position`)."""

    position_mm: Vec3
    created_utc: str
    matrix_nt_per_a: tuple[NT_VEC, NT_VEC, NT_VEC] = Field(description="as measured there (not carried)")
    ambient_nt: NT_VEC
    covariance: list[list[FiniteFloat]] = Field(description="12x12: the matrix row by row, then the ambient")
    residual_rms_nt: Vec3
    settings: list[SettingRecord]


class LoopsRecord(Strict):
    """Each loop off its drawing, fitted to the matrices at every place (rig/fieldsources/coils/loopfit.py):
    [axis][loop + side, - side][shift x, y, z mm, tilt deg, turns ppm], their 30x30 covariance, and the
    quantities the places leave unidentified (their tolerance stays)."""

    deviations: list[list[list[FiniteFloat]]]
    covariance: list[list[FiniteFloat]]
    reference_offset_mm: Vec3
    unidentified: list[str]
    chi2: FiniteFloat
    dof: int


class OtherReferenceRecord(Strict):
    """Another reference read at 0 A beside the commissioning's own (rig/commission/otherrefs.py): its
    reading less that one's, with the covariance of both readings and both calibrations."""

    name: str
    position_mm: Vec3
    difference_nt: Vec3
    covariance: list[list[FiniteFloat]]


class GradientRecord(Strict):
    """The lab field's gradient fitted to the ambient at every place and other reference
    (rig/fieldsources/coils/gradientfit.py): G (nT/m), the 5x5 covariance of its independent components
    (Gxx, Gyy, Gxy, Gxz, Gyz: it is symmetric and traceless), the components the places leave at the
    stated bound, and the stated bound it started from."""

    nt_per_m: tuple[Vec3, Vec3, Vec3]
    covariance: list[list[FiniteFloat]]
    unidentified: list[str]
    chi2: FiniteFloat
    dof: int
    places: int
    prior_nt_per_m: FiniteFloat | None = None


class CoilsRecord(Strict):
    matrix_nt_per_a: tuple[NT_VEC, NT_VEC, NT_VEC]
    ambient_nt: NT_VEC
    covariance: list[list[FiniteFloat]] = Field(description="12x12: the matrix row by row, then the ambient")
    std_errors_matrix_nt_per_a: tuple[Vec3, Vec3, Vec3]
    std_errors_ambient_nt: Vec3
    residual_rms_nt: Vec3
    nonlinearity_ppm: Vec3
    hysteresis_nt: FiniteFloat
    drift_nt: FiniteFloat
    current_a: FiniteFloat
    repeats: int
    current_readback: CurrentReadback | None = None  # files from before it was measured have none
    fitted_to: Literal["commanded", "readback"] = Field(
        "commanded", description="the currents the matrix and ambient were fitted against (older files: "
        "the commanded ones)")
    places: list[PlaceRecord] = Field(default_factory=list, description="further places of the reference")
    loops: LoopsRecord | None = None  # fitted once there are places off the centre
    other_references: list[OtherReferenceRecord] = Field(
        default_factory=list, description="the station's other reference magnetometers, read at 0 A")
    gradient: GradientRecord | None = None  # fitted to the ambient at every place and other reference


class TableRecord(Strict):
    params: dict[str, FiniteFloat]
    covariance: list[list[FiniteFloat]] = Field(description="7x7 in the order of `params`")
    std_errors: dict[str, FiniteFloat]
    residual_rms_nt: FiniteFloat
    drift_nt: FiniteFloat
    repeats: int


class ThermalDut(Strict):
    """One DUT position: its temperature's first-order lag behind the air, where it settles relative to
    the air, the fit's residual, and its noise per axis at a fixed field (one reading as `set_reset`)."""

    lag_s: FiniteFloat
    lag_se_s: FiniteFloat
    offset_c: FiniteFloat
    residual_c: FiniteFloat
    temp_source: str
    noise_nt: Vec3


class ThermalRecord(Strict):
    """What `rig commission --thermal` measured for planning (rig/commission/thermal.py)."""

    start_air_c: FiniteFloat
    step_c: tuple[FiniteFloat, FiniteFloat] = Field(description="the set point before and after the step")
    commanded_rate_c_per_min: FiniteFloat
    rate_c_per_min: FiniteFloat = Field(description="the air's real pace over the middle of the step")
    overshoot_c: FiniteFloat
    duration_s: FiniteFloat
    set_reset: Literal["pair", "off"]
    sample_s: FiniteFloat = Field(description="one sample of every DUT, the sensors and the read-back")
    move_s: FiniteFloat = Field(description="a field-source move and its settling, beyond the stated time")
    chamber_read_s: FiniteFloat
    moves: int
    duts: dict[str, ThermalDut]


class CommissioningFile(Strict):
    format: Literal["magrig-commissioning"]
    format_version: Literal[1]
    kind: Literal["coils", "turntable"]
    station: str
    created_utc: str
    software_version: str
    reference_magnetometer: ReferenceRecord
    coils: CoilsRecord | None = None
    table: TableRecord | None = None
    thermal: ThermalRecord | None = None
    settings: list[SettingRecord]
    content_sha256: str


@dataclass
class Commissioning:
    """A commissioning file that passed every check, as the rig uses it."""

    path: Path
    text: str
    record: CommissioningFile

    @property
    def kind(self) -> str:
        return self.record.kind

    @property
    def matrix_nt_per_a(self) -> np.ndarray:
        return np.asarray(self.record.coils.matrix_nt_per_a, float)

    @property
    def section(self) -> CoilsRecord | TableRecord:
        """What was measured: the `coils:` or the `table:` section (a checked file has one of them)."""
        return self.record.coils if self.record.coils is not None else self.record.table

    @property
    def thermal(self) -> ThermalRecord | None:
        """What `rig commission --thermal` measured for planning (None in a file without it)."""
        return self.record.thermal

    @property
    def covariance(self) -> np.ndarray:
        return np.asarray(self.section.covariance, float)

    @property
    def table_params(self) -> np.ndarray:
        from calib.commissioning.tablefit import PARAM_NAMES

        return np.array([self.record.table.params[n] for n in PARAM_NAMES], float)

    @property
    def created(self) -> dt.datetime:
        return parse_utc(self.record.created_utc)

    def age_days(self, now: dt.datetime | None = None) -> float:
        now = now or dt.datetime.now(dt.UTC)
        return (now - self.created).total_seconds() / 86_400.0

    def residual_rms_nt(self) -> list[float]:
        value = self.section.residual_rms_nt
        return list(value) if isinstance(value, tuple | list) else [value]

    def summary(self, max_age_days: float | None = None) -> str:
        """One line for `rig check`: the file, its age, its residual and its reference."""
        ref = self.record.reference_magnetometer
        rms = ", ".join(f"{v:.2f}" for v in self.residual_rms_nt())
        limit = "" if max_age_days is None else f" (max_age_days {max_age_days:g})"
        return (f"commissioning {self.path}: written {self.record.created_utc}, {self.age_days():.1f} days "
                f"old{limit}; residual rms ({rms}) nT; reference {ref.name} ({ref.type})")

    def as_record(self) -> dict:
        """What a session records of it (a resume uses exactly this)."""
        return {"path": str(self.path), "sha256": sha256_text(self.text), "text": self.text}


def parse_utc(text: str) -> dt.datetime:
    return dt.datetime.strptime(text, "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=dt.UTC)


def utc_text(moment: dt.datetime) -> str:
    return moment.astimezone(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def content_digest(data: dict) -> str:
    """sha256 of everything but the seal, in a canonical form (key order and YAML layout do not count)."""
    body = {k: v for k, v in data.items() if k != "content_sha256"}
    return sha256_text(json.dumps(body, sort_keys=True, separators=(",", ":")))


class _PlainDumper(yaml.SafeDumper):
    """Every value written out where it stands: no `&anchor`/`*alias` (the loader refuses them)."""

    def ignore_aliases(self, data) -> bool:
        return True


def save(data: dict, path: Path) -> None:
    """Seal and write atomically: the file appears whole or not at all."""
    sealed = {**data, "content_sha256": content_digest(data)}
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as f:
        yaml.dump(sealed, f, Dumper=_PlainDumper, sort_keys=False, default_flow_style=None, width=120)


def file_path(station_path: str | Path, name: str) -> Path:
    path = Path(name)
    return path if path.is_absolute() else Path(station_path).parent / path


def read(path: Path, text: str | None = None) -> Commissioning:
    """Parse and check the file on its own (format, seal, a usable matrix or axes); ConfigError naming
    the file, the key and its line."""
    text = read_text(path) if text is None else text
    record = load_model(CommissioningFile, path, text)

    def refuse(key: KeyPath, what: str) -> ConfigError:
        return ConfigError(locate_in_text(str(path), text, key, what))

    data = yaml.safe_load(text)
    if content_digest(data) != record.content_sha256:
        raise refuse(("content_sha256",), "the file was edited after `rig commission` wrote it: commission "
                     "the station again")
    try:
        parse_utc(record.created_utc)
    except ValueError:
        raise refuse(("created_utc",),
                     f"{record.created_utc!r} is not a UTC time like 2026-01-31T12:00:00Z") from None
    kind = kind_class(record.kind)  # the field source's registry entry answers for its section
    key = kind.commissioning_section
    section = getattr(record, key)
    if section is None:
        raise refuse((key,), f"a {record.kind} commissioning needs its `{key}:` section")
    problem = kind.commissioning_section_problem(section)
    if problem is not None:
        raise refuse((key, *problem[0]), problem[1])
    size = kind.commissioning_covariance_size
    _check_covariance(section.covariance, size, (key, "covariance"), refuse)
    for i, place in enumerate(getattr(section, "places", [])):
        _check_covariance(place.covariance, size, (key, "places", i, "covariance"), refuse)
    loops = getattr(section, "loops", None)
    if loops is not None:
        _check_covariance(loops.covariance, 30, (key, "loops", "covariance"), refuse)
    for i, other in enumerate(getattr(section, "other_references", [])):
        _check_covariance(other.covariance, 3, (key, "other_references", i, "covariance"), refuse)
    gradient = getattr(section, "gradient", None)
    if gradient is not None:
        _check_covariance(gradient.covariance, 5, (key, "gradient", "covariance"), refuse)
    return Commissioning(Path(path), text, record)


def _check_covariance(matrix, size: int, key: KeyPath, refuse) -> None:
    cov = np.asarray(matrix, float)
    if cov.shape != (size, size):
        raise refuse(key, f"must be {size}x{size}, got {'x'.join(map(str, cov.shape))}")
    d = np.sqrt(np.abs(np.diag(cov)))  # symmetric to rounding on the scale of its own variances
    if np.any(np.abs(cov - cov.T) > 1e-9 * np.outer(d, d)) or np.linalg.eigvalsh(cov + cov.T)[0] <= 0:
        raise refuse(key, "is not positive definite (not a covariance)")


def load_for_station(station, station_path: str | Path, station_text: str, *,
                     now: dt.datetime | None = None) -> Commissioning | None:
    """The station's commissioning file, read and checked against the station and its reference."""
    source = station.field_source
    name = source.commissioning
    if name is None:
        return None

    def refuse_station(key: str, what: str) -> ConfigError:
        return ConfigError(locate_in_text(str(station_path), station_text, ("field_source", key), what))

    path = file_path(station_path, name)
    if not path.is_file():
        raise refuse_station("commissioning", f"{path}: file not found (write it with `rig commission "
                             f"{station_path} --out {path.parent}`)")
    com = read(path)

    def refuse(key: KeyPath, what: str) -> ConfigError:
        return ConfigError(locate_in_text(str(path), com.text, key, what))

    record = com.record
    if record.station != station.name:
        raise refuse(("station",), f"made for station {record.station!r}, not {station.name!r}")
    if getattr(record, source.commissioning_section) is None:
        raise refuse(("kind",), f"commissions {record.kind}; station {station.name} has {source.described}")
    age = com.age_days(now)
    if age > source.max_age_days:
        raise refuse(("created_utc",), f"written {age:.0f} days ago, older than field_source.max_age_days "
                     f"{source.max_age_days:g}: commission the station again")
    _check_reference(station, station_path, record.reference_magnetometer, refuse)
    return com


def _check_reference(station, station_path, ref: ReferenceRecord, refuse) -> None:
    """The reference it was measured with is still the station's, with the same calibration file."""
    refs = {r.name: r for r in station.reference_magnetometers}
    current = refs.get(ref.name)
    if current is None:
        raise refuse(("reference_magnetometer", "name"),
                     f"measured with reference magnetometer {ref.name!r}, which the station no longer has")
    cal_path = file_path(station_path, current.calibration)
    try:
        digest = sha256_file(cal_path)
    except OSError:
        digest = None
    if digest != ref.calibration_sha256:
        raise refuse(("reference_magnetometer", "calibration_sha256"),
                     f"the calibration of {ref.name} ({cal_path}) has changed since commissioning: "
                     "commission the station again")


def apply(station, commissioning: Commissioning | None):
    """The station with its field source using the commissioned matrix or axes (unchanged without)."""
    if commissioning is None:
        return station
    return station.model_copy(update={"field_source": station.field_source.with_commissioning(commissioning)})


def from_record(data: dict) -> Commissioning:
    """A commissioning as a session recorded it (its seal still checked)."""
    return read(Path(data["path"]), data["text"])

