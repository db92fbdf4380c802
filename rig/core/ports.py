r"""Serial port names as a station or `rig devices scan --port` gives them:

- a device path: /dev/ttyUSB0, /dev/serial/by-id/usb-FTDI_..., /dev/cu.usbserial-1420 (anything with a /);
- a Windows port: COM7, com7, or \\.\COM12 (the form Windows itself needs from COM10 on; pyserial opens
  both); in YAML write it plain or in single quotes (in double quotes a backslash starts an escape);
- a pyserial URL: socket://host:port, rfc2217://host:port, loop://.

`port_key(port)` is one key per physical port, so devices naming COM7 and \\.\com7 share one line.
"""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import AfterValidator

WINDOWS_PORT = re.compile(r"(?:\\\\\.\\)?(COM[1-9][0-9]{0,2})", re.IGNORECASE)
URL = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*://\S*")
MAX_PORT_CHARS = 256


def check_port(port: str) -> str:
    """`port` unchanged when it names a serial port in one of the forms above; ValueError (one line)
    otherwise."""
    if not port or len(port) > MAX_PORT_CHARS or port != port.strip() or "\x00" in port:
        raise ValueError(f"{port[:40]!r} is not a serial port name")
    if "/" in port or WINDOWS_PORT.fullmatch(port) or URL.fullmatch(port):
        return port
    raise ValueError(f"{port!r} is not a serial port: give a device path (/dev/ttyUSB0, "
                     r"/dev/serial/by-id/...), a Windows port (COM7, \\.\COM12) or a pyserial URL "
                     "(socket://host:port)")


def port_key(port: str) -> str:
    """The same key for every spelling of one port: COM7, com7 and \\\\.\\COM7 -> "COM7"; others as given."""
    match = WINDOWS_PORT.fullmatch(port)
    return match.group(1).upper() if match else port


SerialPort = Annotated[str, AfterValidator(check_port)]
