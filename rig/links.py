"""Open the link a device's driver is built on, from the station's transport settings.

    link = open_link(device_config, device_config.transport, clock)

Modbus TCP/RTU -> a ModbusTransport (retries, reconnects, raw-frame log); I2C -> an I2cLink on
/dev/i2c-N; serial -> a SerialLink (the driver opens the port). Simulated devices get the same kinds of
link from rig/simstation.py (a Modbus server on 127.0.0.1, a pty, a simulated I2C bus).
"""

from __future__ import annotations

from drivers.clock import Clock
from drivers.registry import I2cLink, SerialLink
from drivers.transports.modbus import ModbusTransport

MODBUS_TRIES = 3


def _modbus_tcp(dev_cfg, t, clock: Clock) -> ModbusTransport:
    return ModbusTransport(host=t.host, port=t.port, timeout_s=t.timeout_s, name=dev_cfg.name,
                           unit=dev_cfg.unit, clock=clock, tries=MODBUS_TRIES)


def _modbus_rtu(dev_cfg, t, clock: Clock) -> ModbusTransport:
    return ModbusTransport(serial_port=t.port, baudrate=t.baudrate, parity=t.parity, timeout_s=t.timeout_s,
                           name=dev_cfg.name, unit=dev_cfg.unit, clock=clock, tries=MODBUS_TRIES)


def _i2c(dev_cfg, t, clock: Clock) -> I2cLink:
    from drivers.transports.i2c import open_smbus

    return I2cLink(open_smbus(t.bus), t.address)


def _serial(dev_cfg, t, clock: Clock) -> SerialLink:
    return SerialLink(t.port, t.baudrate, t.timeout_s)


OPENERS = {"modbus_tcp": _modbus_tcp, "modbus_rtu": _modbus_rtu, "i2c": _i2c, "serial": _serial}


def open_link(dev_cfg, transport, clock: Clock):
    """The link for a real transport (`kind` other than sim). Opening a real I2C bus may fail
    (DeviceNotFound naming the bus); the others open when the driver connects."""
    return OPENERS[transport.kind](dev_cfg, transport, clock)
