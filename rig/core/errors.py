"""One exception family for the user: the CLI prints `str(err)` of any of `ERRORS` as one line, and a
traceback only with --debug. calib and drivers keep their own bases (they import nothing from rig);
rig re-exports them so rig code has one place to import errors from."""

from __future__ import annotations

from calib.errors import CalibError, DataError, FitError
from drivers.errors import (
    DeviceError,
    DeviceFault,
    DeviceNotFound,
    DeviceTimeout,
    DriverError,
    LimitError,
    OptionError,
    ProtocolError,
)


class MagrigError(Exception):
    """Base of the errors rig itself raises on purpose."""


class ConfigError(MagrigError):
    """A station, plan or option is wrong. The message names the file and key path (and line if known)."""


class SessionError(MagrigError):
    """A session file is missing, damaged, not a session, or cannot be resumed."""


# Everything the project raises on purpose: caught as one line by the CLI, the engine and the reports.
ERRORS = (MagrigError, DriverError, CalibError)

__all__ = [
    "ERRORS", "CalibError", "ConfigError", "DataError", "DeviceError", "DeviceFault", "DeviceNotFound",
    "DeviceTimeout", "DriverError", "FitError", "LimitError", "MagrigError", "OptionError", "ProtocolError",
    "SessionError",
]
