"""One exception family. The CLI prints `str(err)` as one line; a traceback only with --debug."""

from __future__ import annotations


class MagrigError(Exception):
    """Base of every error the project raises on purpose."""


class ConfigError(MagrigError):
    """A station, plan or option is wrong. The message names the file and key path (and line if known)."""


class LimitError(MagrigError):
    """A command would exceed a station limit; raised before anything is written to the hardware."""


class DataError(MagrigError):
    """Input data is unusable. The message names the file and the row, column or field."""


class FitError(MagrigError):
    """A fit cannot be made or trusted (singular design, too few rows); names the parameter group."""


class SessionError(MagrigError):
    """A session file is missing, damaged, not a session, or cannot be resumed."""


class DeviceError(MagrigError):
    """A device failed. Always names the device and the operation that failed."""

    def __init__(self, device: str, operation: str, detail: str):
        self.device = device
        self.operation = operation
        self.detail = detail
        super().__init__(f"{device}: {operation}: {detail}")


class DeviceTimeout(DeviceError):
    """No (complete) reply within the timeout, after the retries."""


class ProtocolError(DeviceError):
    """A reply arrived but is malformed: garbled frame, bad checksum, wrong id, exception reply."""


class DeviceNotFound(DeviceError):
    """Nothing answers at the address / port (I2C NACK, port missing, connection refused)."""


class DeviceFault(DeviceError):
    """The device itself reports a fault (chamber alarm, coil compliance fault, turntable fault)."""
