"""What every field source's commissioning shares: a reading of the reference magnetometer at one
setting of the field source, and the figures taken from repeated settings (rig/commission/procedure.py
drives the settings a field source designs; its kind fits them)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Reading:
    setting: tuple[float, ...]  # coil currents (A) or table angles (deg)
    what: str  # the coil or table axis being driven, for messages
    measured: Any  # rig.reference.sitefield.FieldMeasurement: vector_nt, std_error_nt, n
    readback: tuple[float, ...] | None = None  # what the device reported of its setting (coil currents)


def arrays(readings: list[Reading]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(settings, mean readings, their standard errors), one row per reading."""
    return (np.array([r.setting for r in readings]), np.array([r.measured.vector_nt for r in readings]),
            np.array([r.measured.std_error_nt for r in readings]))


def drift_nt(readings: list[Reading]) -> float:
    """How far the readings at the rest setting (coils at 0 A, table at home) wandered."""
    rest = [r.measured.vector_nt for r in readings if not np.any(r.setting)]
    if len(rest) < 2:
        return 0.0
    rest = np.array(rest)
    return float(np.max(np.linalg.norm(rest - rest[0], axis=1)))


def floats(v) -> list[float]:
    return [float(x) for x in np.asarray(v, float).ravel()]


def rows(m) -> list[list[float]]:
    return [[float(x) for x in row] for row in np.asarray(m, float)]
