"""Station and plan files: strict pydantic models (unknown keys rejected), loaded once and passed down.

    campaign = load_campaign("configs/plans/demo.yaml", station_path=None)
    campaign.plan, campaign.station          # validated models
    campaign.plan_text, campaign.station_text, campaign.plan_path, campaign.station_path

Station (what is on the bench):
    name; sim (the simulated world, used by devices whose transport is `{kind: sim}`);
    chamber {type, transport, unit, limits}; field_source {kind: coils | turntable, ...};
    duts [{name, type, transport, options, temp_source}];
    temperature_sensors [{name, type, transport, beside}].
Simulation is explicit: a device is simulated exactly when its transport is `{kind: sim}`
(`device.simulated`), and `Station.simulated_devices()` is what a session records. Nothing falls back to
a simulator on failure. `Station.sim_ambient_nt()`, `sim_site_field_nt()`, `sim_dut_truths()` give the
simulated world's truth with its defaults applied.

Plan (what to do): name; station (path relative to the plan file, optional; the CLI overrides it);
mode (only `step_and_dwell` today: each point is collected at a stable temperature; every sample still
carries its own temperature so a later `continuous_ramp` mode can reuse the store and the fits);
temperatures {steps | range, ramp_c_per_min, stability}; fields (see rig/fieldsets.py);
samples_per_point, settle_s, set_reset; fit {models, robust}; outputs {dir}.

Every error is a one-line ConfigError naming the file, the key path and the line.
"""

from __future__ import annotations

import datetime as dt
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, Tag, model_validator

from calib.models import MODELS as CALIBRATION_MODELS
from rig.errors import ConfigError
from rig.yamlload import KeyPathError, load_model, read_text

CONFIGS_DIR = Path(__file__).resolve().parent.parent / "configs"
DEFAULT_STATION = CONFIGS_DIR / "stations" / "sim.yaml"

TYPICAL_FIELD_NT = (19_136.0, 891.0, 45_594.0)  # WMM at 52 N 5 E, 2026: used when nothing is stated
Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]
PositiveFloat = Annotated[float, Field(gt=0)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


# --- transports ---------------------------------------------------------------------------------------
class ModbusTcp(Strict):
    kind: Literal["modbus_tcp"]
    host: str
    port: int = Field(502, ge=1, le=65535)
    timeout_s: PositiveFloat = 1.0


class ModbusRtu(Strict):
    kind: Literal["modbus_rtu"]
    port: str
    baudrate: int = Field(9600, gt=0)
    parity: Literal["N", "E", "O"] = "N"
    timeout_s: PositiveFloat = 1.0


class I2c(Strict):
    kind: Literal["i2c"]
    bus: int = Field(ge=0)
    address: int = Field(ge=0x03, le=0x77)


class Serial(Strict):
    kind: Literal["serial"]
    port: str
    baudrate: int = Field(115200, gt=0)
    timeout_s: PositiveFloat = 0.5


class Sim(Strict):
    """Simulated device: the same driver talks its protocol to a simulator of `sim:`'s world."""

    kind: Literal["sim"]


ModbusTransport = Annotated[ModbusTcp | ModbusRtu | Sim, Field(discriminator="kind")]
MagTransport = Annotated[I2c | Serial | Sim, Field(discriminator="kind")]
I2cTransport = Annotated[I2c | Sim, Field(discriminator="kind")]


class Device(Strict):
    @property
    def simulated(self) -> bool:
        return self.transport.kind == "sim"  # type: ignore[attr-defined]


# --- chamber ------------------------------------------------------------------------------------------
class ChamberLimits(Strict):
    min_setpoint_c: float
    max_setpoint_c: float
    max_ramp_c_per_min: PositiveFloat
    safe_setpoint_c: float = 25.0

    @model_validator(mode="after")
    def _ordered(self):
        if self.min_setpoint_c >= self.max_setpoint_c:
            raise KeyPathError(("max_setpoint_c",), "must be above min_setpoint_c")
        if not self.min_setpoint_c <= self.safe_setpoint_c <= self.max_setpoint_c:
            raise KeyPathError(("safe_setpoint_c",), "must lie between min_setpoint_c and max_setpoint_c")
        return self


class Chamber(Device):
    name: str = "chamber"
    type: Literal["watlow_f4t", "watlow_f4"]
    transport: ModbusTransport
    unit: int = Field(1, ge=0, le=247, description="Modbus device id")
    limits: ChamberLimits


# --- field sources ------------------------------------------------------------------------------------
class Coils(Device):
    """Three-axis coil system. `ambient_nt` is the field with the coils off, in the lab frame; "measure"
    means the engine measures it at the start of the campaign (with a DUT or a reference magnetometer)."""

    kind: Literal["coils"]
    name: str = "coils"
    transport: ModbusTransport
    unit: int = Field(1, ge=0, le=247)
    max_current_a: PositiveFloat
    coil_constants_nt_per_a: Mat3
    ambient_nt: Vec3 | Literal["measure"]
    ambient_max_nt: PositiveFloat = Field(
        70_000.0, description="bound on |ambient| used to check currents while ambient is 'measure'"
    )

    @model_validator(mode="after")
    def _invertible(self):
        c = np.asarray(self.coil_constants_nt_per_a, float)
        if np.linalg.cond(c) > 1e6:
            raise KeyPathError(("coil_constants_nt_per_a",), "matrix is singular (coil axes not independent)")
        return self

    @property
    def constants(self) -> np.ndarray:
        return np.asarray(self.coil_constants_nt_per_a, float)


class SiteFromReference(Strict):
    reference_magnetometer: str


class SiteFromModel(Strict):
    model: Literal["wmm", "igrf"] = "wmm"
    lat_deg: float = Field(ge=-90, le=90)
    lon_deg: float = Field(ge=-180, le=360)
    alt_km: float = 0.0
    date: dt.date


class SiteFromVector(Strict):
    vector_nt: Vec3 = Field(description="north, east, down")


def _site_kind(value: Any) -> str | None:
    if isinstance(value, dict):
        for key, tag in (("reference_magnetometer", "reference"), ("vector_nt", "vector"),
                         ("lat_deg", "model"), ("model", "model")):
            if key in value:
                return tag
    elif isinstance(value, BaseModel):
        return {SiteFromReference: "reference", SiteFromVector: "vector", SiteFromModel: "model"}[type(value)]
    return None


SiteField = Annotated[
    Annotated[SiteFromReference, Tag("reference")]
    | Annotated[SiteFromModel, Tag("model")]
    | Annotated[SiteFromVector, Tag("vector")],
    Discriminator(
        _site_kind,
        custom_error_type="site_field",
        custom_error_message="give one of reference_magnetometer, vector_nt, or model with lat_deg/lon_deg",
    ),
]


class Turntable(Device):
    """Two-axis table. Home pose (az = el = 0): table x north, y east, z down, so the site field (NED)
    is the table-frame field at home. Sensor-frame field = R^T B_site, R = Rz(az) @ Ry(el)."""

    kind: Literal["turntable"]
    name: str = "turntable"
    transport: ModbusTransport
    unit: int = Field(1, ge=0, le=247)
    az_limits_deg: tuple[float, float] = (-360.0, 360.0)
    el_limits_deg: tuple[float, float] = (-180.0, 180.0)
    rate_deg_s: PositiveFloat = 10.0
    site_field: SiteField

    @model_validator(mode="after")
    def _limits(self):
        for key in ("az_limits_deg", "el_limits_deg"):
            lo, hi = getattr(self, key)
            if lo >= hi:
                raise KeyPathError((key,), "lower limit must be below the upper limit")
        return self


FieldSource = Annotated[Coils | Turntable, Field(discriminator="kind")]


# --- magnetometers and temperature sensors --------------------------------------------------------------
DUT_OPTIONS: dict[str, set[str]] = {
    "mmc5983ma": {"bandwidth_hz", "set_reset"},
    "hmc5883l": {"gain", "rate_hz", "averaging"},
    "hmc5983": {"gain", "rate_hz", "averaging"},
    "serialmag": {"rate_hz", "set_reset"},
}
DUT_HAS_TEMPERATURE = {"mmc5983ma", "hmc5983"}  # the HMR2300-style serial protocol has none
MMC_MEASURE_S = {100: 0.008, 200: 0.004, 400: 0.002, 800: 0.0005}  # datasheet, by bandwidth
MMC_BANDWIDTH_CODE = {100: 0, 200: 1, 400: 2, 800: 3}  # BW[1:0] of Internal Control 1
HMC_RATES_HZ = (0.75, 1.5, 3.0, 7.5, 15.0, 30.0, 75.0, 220.0)  # by DO code; 220 Hz on the HMC5983 only
SERIALMAG_RATES_HZ = (10, 20, 25, 30, 40, 50, 60, 100, 123, 154)


class DutOptions(Strict):
    bandwidth_hz: Literal[100, 200, 400, 800] | None = None
    set_reset: bool | None = None
    gain: int | None = Field(None, ge=0, le=7)
    rate_hz: PositiveFloat | None = None
    averaging: Literal[1, 2, 4, 8] | None = None


class Dut(Device):
    name: str
    type: Literal["mmc5983ma", "hmc5883l", "hmc5983", "serialmag"]
    transport: MagTransport
    options: DutOptions = DutOptions()
    temp_source: str = Field(description='a temperature sensor\'s name, or "self" (the chip\'s own sensor)')

    @model_validator(mode="after")
    def _options_fit_type(self):
        given = self.options.model_dump(exclude_none=True)
        for key in given:
            if key not in DUT_OPTIONS[self.type]:
                allowed = ", ".join(sorted(DUT_OPTIONS[self.type]))
                raise KeyPathError(("options", key), f"not an option of {self.type} (allowed: {allowed})")
        if self.temp_source == "self" and self.type not in DUT_HAS_TEMPERATURE:
            raise KeyPathError(("temp_source",), f"{self.type} has no temperature sensor; name a TMP117")
        rate = self.options.rate_hz
        rates = SERIALMAG_RATES_HZ if self.type == "serialmag" else HMC_RATES_HZ[:-1]
        rates += (220.0,) if self.type == "hmc5983" else ()
        if rate is not None and rate not in rates:
            raise KeyPathError(("options", "rate_hz"),
                               f"{self.type} runs at one of {', '.join(f'{r:g}' for r in rates)} Hz")
        return self

    def driver_options(self, set_reset: bool = True) -> dict:
        """Keyword arguments for the DUT's driver class. `set_reset=False` (the plan's `set_reset: off`)
        turns SET/RESET off even where the DUT's own option leaves it on (its default)."""
        o = self.options
        use_sr = set_reset and o.set_reset is not False
        if self.type == "mmc5983ma":
            return {"bandwidth": MMC_BANDWIDTH_CODE[o.bandwidth_hz or 100], "set_reset": use_sr}
        if self.type == "serialmag":
            return {"rate_hz": int(o.rate_hz or 20), "set_reset": "pulse" if use_sr else "off"}
        return {
            "variant": self.type.upper(),
            "gain": 1 if o.gain is None else o.gain,
            "averaging": o.averaging or 8,
            "output_rate_code": HMC_RATES_HZ.index(o.rate_hz or 15.0),
        }

    def sample_time_s(self, set_reset_pair: bool) -> float:
        """Estimated time for one reading (for duration estimates; the drivers set the real pace)."""
        if self.type == "mmc5983ma":
            one = MMC_MEASURE_S[self.options.bandwidth_hz or 100] + 0.002  # + bus transfer
            return 2 * (one + 0.001) if set_reset_pair else one
        rate = self.options.rate_hz or (15.0 if self.type.startswith("hmc") else 20.0)
        return 1.0 / rate


class TemperatureSensor(Device):
    name: str
    type: Literal["tmp117"]
    transport: I2cTransport
    beside: str = Field(description="the DUT this sensor is mounted next to")


# --- simulated world ------------------------------------------------------------------------------------
class TruthSpec(Strict):
    """Explicit calibration errors of a simulated DUT (absolute-tau T24 convention, see MODELS.md)."""

    S: Mat3
    K: Mat3 = ((0, 0, 0), (0, 0, 0), (0, 0, 0))
    b_nt: Vec3 = (0, 0, 0)
    kb_nt_per_c: Vec3 = (0, 0, 0)
    bridge_offset_nt: Vec3 = (0, 0, 0)
    bridge_offset_tc_nt_per_c: Vec3 = (0, 0, 0)


class SimDut(Strict):
    truth: Literal["random"] | TruthSpec = "random"
    noise_nt: float = Field(20.0, ge=0)
    thermal_lag_s: PositiveFloat = 600.0


class SimWorld(Strict):
    """Truth of the simulated world; use `Station.sim_*` for the values with their defaults applied."""

    seed: int = 0
    ambient_nt: Vec3 | None = Field(None, description="default: the coils' ambient_nt, when given")
    site_field_nt: Vec3 | None = Field(None, description="default: the turntable's site field")
    air_c: float = 22.0
    duts: dict[str, SimDut] = {}


class Station(Strict):
    name: str
    sim: SimWorld = SimWorld()
    chamber: Chamber
    field_source: FieldSource
    duts: list[Dut] = Field(min_length=1)
    temperature_sensors: list[TemperatureSensor] = []

    @model_validator(mode="after")
    def _references(self):
        seen: set[str] = set()
        for path, dev in self._named_devices():
            if dev.name in seen:
                raise KeyPathError((*path, "name"), f"device name {dev.name!r} is used twice")
            seen.add(dev.name)
        sensors = {s.name for s in self.temperature_sensors}
        duts = {d.name for d in self.duts}
        for i, d in enumerate(self.duts):
            if d.temp_source != "self" and d.temp_source not in sensors:
                known = ", ".join(sorted(sensors)) or "none defined"
                raise KeyPathError(("duts", i, "temp_source"),
                                   f"no temperature sensor {d.temp_source!r} (sensors: {known}; or 'self')")
        for i, s in enumerate(self.temperature_sensors):
            if s.beside not in duts:
                raise KeyPathError(("temperature_sensors", i, "beside"), f"no DUT named {s.beside!r}")
        for name in self.sim.duts:
            if name not in duts:
                raise KeyPathError(("sim", "duts", name), f"no DUT named {name!r} in duts")
        site = getattr(self.field_source, "site_field", None)
        if isinstance(site, SiteFromReference) and site.reference_magnetometer not in duts:
            raise KeyPathError(("field_source", "site_field", "reference_magnetometer"),
                               f"no magnetometer named {site.reference_magnetometer!r} in duts")
        return self

    def _named_devices(self):
        yield ("chamber",), self.chamber
        yield ("field_source",), self.field_source
        for i, d in enumerate(self.duts):
            yield ("duts", i), d
        for i, s in enumerate(self.temperature_sensors):
            yield ("temperature_sensors", i), s

    def devices(self) -> list[Device]:
        return [dev for _, dev in self._named_devices()]

    def simulated_devices(self) -> dict[str, bool]:
        """{device name: simulated?} - recorded in every session."""
        return {dev.name: dev.simulated for dev in self.devices()}

    # --- the simulated world, defaults applied ------------------------------------------------------
    def sim_ambient_nt(self) -> np.ndarray:
        """True ambient field (lab frame): sim.ambient_nt, else the coils' stated ambient, else a
        typical mid-latitude field."""
        if self.sim.ambient_nt is not None:
            return np.asarray(self.sim.ambient_nt, float)
        stated = getattr(self.field_source, "ambient_nt", None)
        return np.asarray(TYPICAL_FIELD_NT if stated in (None, "measure") else stated, float)

    def sim_site_field_nt(self) -> np.ndarray:
        """True site field (NED): sim.site_field_nt, else the turntable's stated vector or model."""
        if self.sim.site_field_nt is not None:
            return np.asarray(self.sim.site_field_nt, float)
        if isinstance(self.field_source, Turntable):
            from rig.reference import station_site_field_nt

            stated = station_site_field_nt(self.field_source)
            if stated is not None:
                return stated
        return np.asarray(TYPICAL_FIELD_NT, float)

    def sim_dut_truths(self) -> dict:
        """{DUT name: drivers.sim.world.DutTruth} for the simulated DUTs. A random truth is drawn from
        default_rng([seed, position in duts]), so changing one DUT leaves the others' truths alone."""
        from drivers.sim.world import DutTruth

        out = {}
        for i, dut in enumerate(self.duts):
            if not dut.simulated:
                continue
            spec = self.sim.duts.get(dut.name, SimDut())
            if spec.truth == "random":
                rng = np.random.default_rng([self.sim.seed, i])
                out[dut.name] = DutTruth.random(rng, noise_nt=spec.noise_nt, thermal_lag_s=spec.thermal_lag_s)
            else:
                t = spec.truth
                out[dut.name] = DutTruth(
                    S=np.asarray(t.S, float), K=np.asarray(t.K, float), b_nt=np.asarray(t.b_nt, float),
                    kb_nt_per_c=np.asarray(t.kb_nt_per_c, float),
                    bridge_offset_nt=np.asarray(t.bridge_offset_nt, float),
                    bridge_offset_tc_nt_per_c=np.asarray(t.bridge_offset_tc_nt_per_c, float),
                    noise_nt=spec.noise_nt, thermal_lag_s=spec.thermal_lag_s,
                )
        return out

    def dut(self, name: str) -> Dut:
        for d in self.duts:
            if d.name == name:
                return d
        raise ConfigError(f"station {self.name}: no DUT named {name!r}")


# --- plan -----------------------------------------------------------------------------------------------
class Stability(Strict):
    """When a temperature step counts as stable, judged on each DUT's own temperature: within band_c of
    the setpoint, changing slower than rate_c_per_min, both for dwell_s; give up after max_wait_s."""

    band_c: PositiveFloat = 0.5
    rate_c_per_min: PositiveFloat = 0.1
    dwell_s: float = Field(300.0, ge=0)
    max_wait_s: PositiveFloat = 3 * 3600.0


def _number_to_step(value: Any) -> Any:
    return {"setpoint_c": value} if isinstance(value, int | float) and not isinstance(value, bool) else value


def _yaml_off(value: Any) -> Any:
    """YAML reads a bare `off` as false."""
    return "off" if value is False else value


class TempStep(Strict):
    setpoint_c: float
    ramp_c_per_min: PositiveFloat | None = None
    stability: Stability | None = Field(None, description="keys given here override the plan's stability")


class TempRange(Strict):
    start_c: float
    stop_c: float
    step_c: float

    @model_validator(mode="after")
    def _direction(self):
        if self.step_c == 0 or (self.stop_c - self.start_c) * self.step_c < 0:
            raise KeyPathError(("step_c",), "must be non-zero and point from start_c towards stop_c")
        return self

    def setpoints(self) -> list[float]:
        n = int(np.floor((self.stop_c - self.start_c) / self.step_c + 1e-9)) + 1
        return [round(self.start_c + i * self.step_c, 6) for i in range(n)]


class Temperatures(Strict):
    steps: list[Annotated[TempStep, BeforeValidator(_number_to_step)]] | None = None
    range: TempRange | None = None
    ramp_c_per_min: PositiveFloat = 2.0
    stability: Stability = Stability()

    @model_validator(mode="after")
    def _one_source(self):
        if (self.steps is None) == (self.range is None):
            raise KeyPathError(("steps",), "give either steps (a list of setpoints) or range, not both")
        if self.steps is not None and not self.steps:
            raise KeyPathError(("steps",), "needs at least one setpoint")
        return self

    def step_list(self) -> list[TempStep]:
        if self.steps is not None:
            return list(self.steps)
        return [TempStep(setpoint_c=t) for t in self.range.setpoints()]  # type: ignore[union-attr]

    def stability_for(self, step: TempStep) -> Stability:
        if step.stability is None:
            return self.stability
        return self.stability.model_copy(update=step.stability.model_dump(exclude_unset=True))


class _Magnitudes(Strict):
    magnitude_nt: PositiveFloat | None = None
    magnitudes_nt: list[PositiveFloat] | None = None

    def magnitude_list(self) -> list[float]:
        if self.magnitudes_nt:
            return list(self.magnitudes_nt)
        return [self.magnitude_nt or 50_000.0]


class Cube24Fields(_Magnitudes):
    """The 24 rotations of the cube applied to one reference direction (see rig/fieldsets.py)."""

    kind: Literal["cube24"]


class FibonacciFields(_Magnitudes):
    kind: Literal["fibonacci"]
    n: int = Field(ge=4, le=10_000)


class DirectionFields(_Magnitudes):
    kind: Literal["directions"]
    directions: list[Vec3] = Field(min_length=1)


class VectorFields(Strict):
    kind: Literal["vectors"]
    vectors_nt: list[Vec3] = Field(min_length=1)


class GridOrientations(Strict):
    """Turntable: every azimuth at every elevation (the default is 16 of the cube's 24 rotations, all
    that a two-axis table can reach)."""

    kind: Literal["grid"]
    az_deg: list[float] = Field([-90.0, 0.0, 90.0, 180.0], min_length=1)
    el_deg: list[float] = Field([-90.0, 0.0, 90.0, 180.0], min_length=1)


class ListOrientations(Strict):
    kind: Literal["orientations"]
    angles_deg: list[tuple[float, float]] = Field(min_length=1, description="[az, el] pairs")


FieldSet = Annotated[
    Cube24Fields | FibonacciFields | DirectionFields | VectorFields | GridOrientations | ListOrientations,
    Field(discriminator="kind"),
]
COIL_FIELD_KINDS = {"cube24", "fibonacci", "directions", "vectors"}
TABLE_FIELD_KINDS = {"grid", "orientations"}


class Fit(Strict):
    models: list[Literal[CALIBRATION_MODELS]] = Field(["t24"], min_length=1)  # calib's model registry
    robust: bool = False


class Outputs(Strict):
    dir: str = "sessions"


class Plan(Strict):
    name: str
    station: str | None = Field(None, description="station file, relative to the plan file")
    mode: Literal["step_and_dwell"] = "step_and_dwell"
    temperatures: Temperatures
    fields: FieldSet
    samples_per_point: int = Field(ge=1)
    settle_s: float = Field(1.0, ge=0, description="wait after a field change before sampling")
    set_reset: Annotated[Literal["pair", "off"], BeforeValidator(_yaml_off)] = Field(
        "pair", description="pair: SET and RESET reading per sample (offset removed); off: plain reading"
    )
    fit: Fit = Fit()
    outputs: Outputs = Outputs()


# --- loading ----------------------------------------------------------------------------------------------
def load_station(path: str | Path) -> Station:
    return load_model(Station, path)


def load_plan(path: str | Path) -> Plan:
    return load_model(Plan, path)


@dataclass(frozen=True)
class Campaign:
    """A plan and the station it runs on, with the exact texts (recorded in the session)."""

    plan: Plan
    station: Station
    plan_path: Path
    station_path: Path
    plan_text: str
    station_text: str


def resolve_station_path(plan: Plan, plan_path: str | Path, station_path: str | Path | None) -> Path:
    """The CLI's --station wins; then the plan's `station:` (relative to the plan file); then the
    simulated default station."""
    if station_path is not None:
        return Path(station_path)
    if plan.station is not None:
        candidate = Path(plan.station)
        if not candidate.is_absolute():
            candidate = Path(os.path.normpath(Path(plan_path).parent / candidate))
        return candidate
    return DEFAULT_STATION


def load_campaign(plan_path: str | Path, station_path: str | Path | None = None) -> Campaign:
    plan_text = read_text(plan_path)
    plan = load_model(Plan, plan_path, plan_text)
    resolved = resolve_station_path(plan, plan_path, station_path)
    station_text = read_text(resolved)
    station = load_model(Station, resolved, station_text)
    return Campaign(plan, station, Path(plan_path), resolved, plan_text, station_text)
