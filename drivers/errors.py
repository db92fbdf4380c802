"""The drivers' errors. Every one names the device and the operation; drivers import nothing from rig."""

from __future__ import annotations


class DriverError(Exception):
    """Base of every error the drivers raise on purpose."""


class OptionError(DriverError):
    """A driver was given an option its device does not have (bad gain code, unknown rate...)."""


class LimitError(DriverError):
    """A command would exceed a station limit; raised before anything is written to the hardware."""


class DeviceError(DriverError):
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
