"""calib's own errors: calib stands alone (pure numpy), so it imports nothing from rig or drivers."""

from __future__ import annotations


class CalibError(Exception):
    """Base of every error calib raises on purpose."""


class DataError(CalibError):
    """Input data is unusable. The message names the file and the row, column or field."""


class FitError(CalibError):
    """A fit cannot be made or trusted (singular design, too few rows); names the parameter group.
    `axis` names the axis ("x", "y", "z") when the trouble is one axis's."""

    def __init__(self, message: str, *, axis: str | None = None):
        super().__init__(message)
        self.axis = axis
