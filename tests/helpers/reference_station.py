"""configs/stations/sim-commissioned.yaml as test material: a copy in a folder of the test's own, its
reference calibration beside it, optionally changed, and commissioning files written without hardware."""

from __future__ import annotations

import copy
import datetime as dt
from pathlib import Path

import numpy as np
import yaml

from calib.io.digest import sha256_file
from rig.config import CONFIGS_DIR, commissioning_file

STATION = CONFIGS_DIR / "stations" / "sim-commissioned.yaml"
REFERENCE_CAL = CONFIGS_DIR / "stations" / "sim-reference-cal-certified.yaml"  # the file the station names


def station_data() -> dict:
    return yaml.safe_load(STATION.read_text())


def write_station(folder: Path, change=None, *, commissioned: bool = False) -> Path:
    """The shipped station in `folder` (its reference calibration copied beside it); `change(data)` edits
    it first; without `commissioned` it names no commissioning file."""
    data = copy.deepcopy(station_data())
    (folder / REFERENCE_CAL.name).write_text(REFERENCE_CAL.read_text())
    if not commissioned:
        data["field_source"].pop("commissioning")
    if change is not None:
        change(data)
    path = folder / "station.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def commissioning_data(station_path: Path, *, matrix=None, covariance=None, station: str | None = None,
                       created: dt.datetime | None = None) -> dict:
    """A coils commissioning of the station in `station_path`, as `rig commission` writes it (unsealed)."""
    data = yaml.safe_load(station_path.read_text())
    ref = data["reference_magnetometers"][0]
    matrix = np.asarray(matrix if matrix is not None else data["sim"]["coil_constants_nt_per_a"], float)
    cov = np.eye(12) * 0.02 if covariance is None else np.asarray(covariance, float)
    created = created or dt.datetime.now(dt.UTC)
    return {
        "format": commissioning_file.FORMAT_NAME, "format_version": commissioning_file.FORMAT_VERSION,
        "kind": "coils",
        "station": station or data["name"], "created_utc": commissioning_file.utc_text(created),
        "software_version": "test",
        "reference_magnetometer": {
            "name": ref["name"], "type": ref["type"], "identity": {"model": "MMC5983MA"},
            "calibration": ref["calibration"],
            "calibration_sha256": sha256_file(station_path.parent / ref["calibration"]),
            "position_mm": [0.0, 0.0, 0.0]},
        "coils": {
            "matrix_nt_per_a": matrix.tolist(), "ambient_nt": data["sim"]["ambient_nt"],
            "covariance": cov.tolist(), "std_errors_matrix_nt_per_a": [[0.14] * 3] * 3,
            "std_errors_ambient_nt": [0.08] * 3, "residual_rms_nt": [0.7, 0.75, 0.86],
            "nonlinearity_ppm": [20.0, 20.0, 20.0], "hysteresis_nt": 2.9, "drift_nt": 2.9, "current_a": 1.2,
            "repeats": 2},
        "settings": [],
    }


def commissioned_station(folder: Path, **kwargs) -> tuple[Path, Path]:
    """(station path, commissioning path): the station naming a sealed commissioning file beside it."""
    station = write_station(folder, commissioned=True)
    path = folder / "sim-commissioned.commissioning.yaml"
    commissioning_file.save(commissioning_data(station, **kwargs), path)
    return station, path
