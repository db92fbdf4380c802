"""Station and plan files: strict pydantic models (unknown keys rejected), loaded once and passed down.

    campaign = read_campaign("configs/plans/demo.yaml", station_path=None)   # the files as they are
    campaign.plan, campaign.station          # validated models
    campaign.plan_text, campaign.station_text, campaign.plan_path, campaign.station_path

The models live beside this file: station.py (what is on the bench, built from the device registry),
plan.py (what to do), sim.py (the simulated world a station states); the shared pieces (transports, the
device base) in rig/core/configbase.py, field sources in rig/fieldsources/. Every error is a one-line
ConfigError naming the file, the key path and the line.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from rig.config.fields import (
    Cube24Fields,
    DirectionFields,
    FibonacciFields,
    FieldSet,
    GridOrientations,
    ListOrientations,
    VectorFields,
)
from rig.config.plan import Fit, Outputs, Plan
from rig.config.sim import SimDut, SimWorld, TruthSpec
from rig.config.station import (
    Chamber,
    ChamberConfig,
    Dut,
    DutConfig,
    Station,
    TemperatureSensor,
    TemperatureSensorConfig,
)
from rig.config.temperatures import (
    AssumedDut,
    DesignedLeg,
    DesignedTemperatures,
    RampTemperatures,
    SequentialTemperatures,
    Stability,
    Temperatures,
    TempRange,
    TempStep,
)
from rig.core.configbase import I2c, ModbusRtu, ModbusTcp, Serial, Sim, Strict
from rig.core.yamlload import load_model, read_text
from rig.fieldsources import Coils, FieldSource, SiteFromModel, SiteFromReference, SiteFromVector, Turntable

CONFIGS_DIR = Path(__file__).resolve().parent.parent.parent / "configs"
DEFAULT_STATION = CONFIGS_DIR / "stations" / "sim.yaml"


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


def read_campaign(plan_path: str | Path, station_path: str | Path | None = None) -> Campaign:
    """The plan and its station as their files state them. A run, a check or a design uses
    rig.config.loading.load_campaign, which also checks and applies the station's commissioning file."""
    plan_text = read_text(plan_path)
    plan = load_model(Plan, plan_path, plan_text)
    resolved = resolve_station_path(plan, plan_path, station_path)
    station_text = read_text(resolved)
    station = load_model(Station, resolved, station_text)
    return Campaign(plan, station, Path(plan_path), resolved, plan_text, station_text)


__all__ = [
    "CONFIGS_DIR", "DEFAULT_STATION", "AssumedDut", "Campaign", "Chamber", "ChamberConfig", "Coils",
    "Cube24Fields", "DesignedLeg", "DesignedTemperatures", "DirectionFields", "Dut", "DutConfig",
    "FibonacciFields", "FieldSet", "FieldSource", "Fit", "GridOrientations", "I2c", "ListOrientations",
    "ModbusRtu", "ModbusTcp", "Outputs", "Plan", "RampTemperatures", "SequentialTemperatures", "Serial",
    "Sim",
    "SimDut", "SimWorld", "SiteFromModel", "SiteFromReference", "SiteFromVector", "Stability", "Station",
    "Strict", "TempRange", "TempStep", "TemperatureSensor", "TemperatureSensorConfig", "Temperatures",
    "Turntable", "TruthSpec", "VectorFields", "load_plan", "load_station", "read_campaign",
    "resolve_station_path",
]
